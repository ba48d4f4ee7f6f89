// The resources of the GI compute passes (gi_gather.comp, gi_blur.comp, gi_resolve.comp: one
// descriptor set layout and one push block for all) and their paraboloid shadow lookup.
// The gather and the blur run at half resolution: each half-resolution sample stands for a 2x2
// block of pixels and takes the G-buffer of one of them (the first covered), which the gather
// copies into half_position / half_normal for the blur and the upsample.

layout(set = 0, binding = 0, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_normal;
layout(set = 0, binding = 2, rgba8) uniform readonly image2D g_albedo;
struct GpuVpl { vec4 position_layer; vec4 normal; vec4 flux; };
layout(std430, set = 0, binding = 3) readonly buffer Vpls { GpuVpl vpls[]; };
layout(set = 0, binding = 4) uniform sampler2DArray shadow_maps;
// Half resolution: interleaved irradiance of this sample's VPL class (gather output).
layout(set = 0, binding = 5, rgba32f) uniform image2D indirect;
layout(set = 0, binding = 6, rgba8) uniform writeonly image2D out_color;
// Half resolution: the sample's world position (w = 1 where covered) and normal.
layout(set = 0, binding = 7, rgba32f) uniform image2D half_position;
layout(set = 0, binding = 8, rgba32f) uniform image2D half_normal;
// Half resolution: the blurred irradiance from all VPLs (blur output, resolve input).
layout(set = 0, binding = 9, rgba32f) uniform image2D blurred;

layout(push_constant) uniform Push {
    vec4 spot_pos;   // xyz, w: spot layer
    vec4 spot_dir;   // xyz, w: far distance of the shadow maps
    vec4 spot_power; // rgb, w: output mode (0 full, 1 indirect only, 2 direct only)
    vec4 gather;     // x: first VPL, y: VPL count, z: accumulate, w: distance clamp
    vec4 misc;       // x: constant shadow bias, y: exposure, z: normal offset, w: blur plane threshold
} pc;

const float PI = 3.14159265;

#include "include/paraboloid.glsl"

// Paraboloid shadow lookup of offset d from a slot with normal n in `layer`. Bias: a constant
// (pc.misc.x) plus 2% of the distance, which grows like the paraboloid texel footprint (about
// 2 / resolution radians) and covers the straight-edge error of the non-linear projection.
// One texel fetch (nearest texel, clamped to the map), which is what the nearest-clamp sampler
// returned, without the sampler's filtering and wrapping work.
float visibility(float layer, vec3 n, vec3 d) {
    vec3 t, b;
    basis(n, t, b);
    vec3 l = vec3(dot(d, t), dot(d, b), dot(d, n));
    float len = length(l);
    vec2 p = l.xy / max(len + l.z, 1e-9);
    vec2 uv = vec2(0.5 + 0.5 * p.x, 0.5 - 0.5 * p.y);
    ivec2 size = textureSize(shadow_maps, 0).xy;
    ivec2 texel = clamp(ivec2(uv * vec2(size)), ivec2(0), size - 1);
    float stored = texelFetch(shadow_maps, ivec3(texel, int(layer)), 0).r * pc.spot_dir.w;
    return len - pc.misc.x - 0.02 * len <= stored ? 1.0 : 0.0;
}

// Whether a neighbour sample (position q4 with w = coverage, normal nq) lies on the surface of
// the pixel at p with normal n: similar normal and within the blur's plane distance.
bool same_surface(vec3 p, vec3 n, vec4 q4, vec3 nq) {
    return q4.w > 0.5 && dot(n, nq) >= 0.9 && abs(dot(q4.xyz - p, n)) <= pc.misc.w;
}

// Imperfect shadow maps (ism mode): one coarse hole-filled map per VPL layer.
layout(set = 0, binding = 10) uniform sampler2DArray ism_maps;

// Lookup of offset d from a VPL with normal n in its imperfect shadow map. The maps are coarse
// (32x32 over a hemisphere: about 0.1 rad a texel) and built from points, so the bias is larger:
// twice the constant and 8% of the distance.
float visibility_ism(float layer, vec3 n, vec3 d) {
    vec3 t, b;
    basis(n, t, b);
    vec3 l = vec3(dot(d, t), dot(d, b), dot(d, n));
    float len = length(l);
    vec2 p = l.xy / max(len + l.z, 1e-9);
    vec2 uv = vec2(0.5 + 0.5 * p.x, 0.5 - 0.5 * p.y);
    ivec2 size = textureSize(ism_maps, 0).xy;
    ivec2 texel = clamp(ivec2(uv * vec2(size)), ivec2(0), size - 1);
    float stored = texelFetch(ism_maps, ivec3(texel, int(layer)), 0).r * pc.spot_dir.w;
    return len - 2.0 * pc.misc.x - 0.08 * len <= stored ? 1.0 : 0.0;
}
