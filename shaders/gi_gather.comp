#version 450
#extension GL_GOOGLE_include_directive : require
// Indirect light from VPLs with 4x4 interleaved sampling: the pixel at (x, y) gathers only the
// VPLs whose index i satisfies i % 16 == (x % 4) + 4 * (y % 4), so each pixel pays for N/16 VPLs;
// gi_resolve.comp reconstructs the full sum with a geometry-aware 4x4 blur.
// Output: irradiance (without the receiver's albedo) from this chunk of VPLs, optionally
// accumulated onto the previous chunk's.
layout(local_size_x = 8, local_size_y = 8) in;

#include "include/gi_shading.glsl"

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
