#version 450
// Indirect light from VPLs with 4x4 interleaved sampling: the pixel at (x, y) gathers only the
// VPLs whose index i satisfies i % 16 == (x % 4) + 4 * (y % 4), so each pixel pays for N/16 VPLs;
// gi_resolve.comp reconstructs the full sum with a geometry-aware 4x4 blur.
// Output: irradiance (without the receiver's albedo) from this chunk of VPLs, optionally
// accumulated onto the previous chunk's.
layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 0, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_normal;
layout(set = 0, binding = 2, rgba8) uniform readonly image2D g_albedo;
struct GpuVpl { vec4 position_layer; vec4 normal; vec4 flux; };
layout(std430, set = 0, binding = 3) readonly buffer Vpls { GpuVpl vpls[]; };
layout(set = 0, binding = 4) uniform sampler2DArray shadow_maps;
layout(set = 0, binding = 5, rgba32f) uniform image2D indirect;
layout(set = 0, binding = 6, rgba8) uniform writeonly image2D out_color;

layout(push_constant) uniform Push {
    vec4 spot_pos;   // xyz, w: spot layer
    vec4 spot_dir;   // xyz, w: far distance of the shadow maps
    vec4 spot_power; // rgb, w: output mode (0 full, 1 indirect only, 2 direct only)
    vec4 gather;     // x: first VPL, y: VPL count, z: accumulate, w: distance clamp
    vec4 misc;       // x: constant shadow bias, y: exposure, z: normal offset, w: blur plane threshold
} pc;

const float PI = 3.14159265;

void basis(vec3 n, out vec3 t, out vec3 b) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float k = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * k, -s * n.x);
    b = vec3(k, s + n.y * n.y * a, -n.y);
}

// Paraboloid shadow lookup of offset d from a slot with normal n in `layer`. Bias: a constant
// (pc.misc.x) plus 2% of the distance, which grows like the paraboloid texel footprint (about
// 2 / resolution radians) and covers the straight-edge error of the non-linear projection.
float visibility(float layer, vec3 n, vec3 d) {
    vec3 t, b;
    basis(n, t, b);
    vec3 l = vec3(dot(d, t), dot(d, b), dot(d, n));
    float len = length(l);
    vec2 p = l.xy / max(len + l.z, 1e-9);
    vec2 uv = vec2(0.5 + 0.5 * p.x, 0.5 - 0.5 * p.y);
    float stored = textureLod(shadow_maps, vec3(uv, layer), 0.0).r * pc.spot_dir.w;
    return len - pc.misc.x - 0.02 * len <= stored ? 1.0 : 0.0;
}

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = imageSize(g_position);
    if (px.x >= size.x || px.y >= size.y) {
        return;
    }
    vec4 p4 = imageLoad(g_position, px);
    vec3 sum = vec3(0.0);
    if (p4.w > 0.5) {
        vec3 n = imageLoad(g_normal, px).xyz;
        // Receiver offset along its normal against self-shadowing (part of the documented bias).
        vec3 p = p4.xyz + n * pc.misc.z;
        int cls = (px.x & 3) + 4 * (px.y & 3);
        int first = int(pc.gather.x);
        int end = first + int(pc.gather.y);
        int start = first + ((cls - first % 16) + 16) % 16;
        // Geometry-term clamp: 1/d^2 is bounded by 1/clamp^2, which removes the bright spots next
        // to VPLs at the cost of some energy (bias) within `clamp` of each VPL.
        float c2 = pc.gather.w * pc.gather.w;
        for (int i = start; i < end; i += 16) {
            GpuVpl v = vpls[i];
            vec3 d = p - v.position_layer.xyz;
            float dist2 = max(dot(d, d), 1e-12);
            vec3 w = d * inversesqrt(dist2);
            float cy = dot(v.normal.xyz, w);
            float cp = -dot(n, w);
            if (cy <= 0.0 || cp <= 0.0) {
                continue;
            }
            float vis = visibility(v.position_layer.w, v.normal.xyz, d);
            // A VPL is a diffuse emitter: intensity flux/pi * cos.
            sum += v.flux.rgb * (vis * cy * cp / (PI * max(dist2, c2)));
        }
    }
    if (pc.gather.z > 0.5) {
        sum += imageLoad(indirect, px).rgb;
    }
    imageStore(indirect, px, vec4(sum, 1.0));
}
