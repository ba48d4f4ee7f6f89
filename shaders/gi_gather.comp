#version 450
#extension GL_GOOGLE_include_directive : require
// Indirect light from VPLs at half resolution with 4x4 interleaved sampling. Each invocation is
// one half-resolution sample: it takes the G-buffer of the first covered pixel of its 2x2 block
// (and copies it to half_position / half_normal for the blur and the upsample). The VPL buffer
// is indexed by shadow layer, and the sample at (x, y) gathers only the VPLs whose chunk-local
// layer l satisfies l % 16 == (x % 4) + 4 * (y % 4), so each sample pays for N/16 VPLs and a VPL
// keeps its class for life (no flicker when others come and go); entries of free layers are
// empty (normal.w 0). gi_blur.comp reconstructs the full sum with a geometry-aware 4x4 blur.
// Output: irradiance (without the receiver's albedo) from this chunk of VPLs, optionally
// accumulated onto the previous chunk's.
layout(local_size_x = 8, local_size_y = 8) in;

#include "include/gi_shading.glsl"

void main() {
    ivec2 hx = ivec2(gl_GlobalInvocationID.xy);
    ivec2 half_size = imageSize(indirect);
    if (hx.x >= half_size.x || hx.y >= half_size.y) {
        return;
    }
    ivec2 size = imageSize(g_position);
    ivec2 px = min(2 * hx, size - 1);
    vec4 p4 = imageLoad(g_position, px);
    for (int k = 1; k < 4 && p4.w < 0.5; k++) {
        px = min(2 * hx + ivec2(k & 1, k >> 1), size - 1);
        p4 = imageLoad(g_position, px);
    }
    vec3 n = imageLoad(g_normal, px).xyz;
    bool first_chunk = pc.gather.z < 0.5;
    if (first_chunk) {
        imageStore(half_position, hx, p4);
        imageStore(half_normal, hx, vec4(n, 0.0));
    }
    vec3 sum = vec3(0.0);
    if (p4.w > 0.5) {
        // Receiver offset along its normal against self-shadowing (part of the documented bias).
        vec3 p = p4.xyz + n * pc.misc.z;
        int cls = (hx.x & 3) + 4 * (hx.y & 3);
        int first = int(pc.gather.x);
        int end = first + int(pc.gather.y);
        // Geometry-term clamp: 1/d^2 is bounded by 1/clamp^2, which removes the bright spots next
        // to VPLs at the cost of some energy (bias) within `clamp` of each VPL.
        float c2 = pc.gather.w * pc.gather.w;
        for (int i = first + cls; i < end; i += 16) {
            GpuVpl v = vpls[i];
            if (v.normal.w < 0.5) {
                continue;
            }
            vec3 d = p - v.position_layer.xyz;
            float dist2 = max(dot(d, d), 1e-12);
            vec3 w = d * inversesqrt(dist2);
            float cy = dot(v.normal.xyz, w);
            float cp = -dot(n, w);
            if (cy <= 0.0 || cp <= 0.0) {
                continue;
            }
            float vis = v.flux.w > 0.5 ? visibility_ism(v.position_layer.w, v.normal.xyz, d)
                                       : visibility(v.position_layer.w, v.normal.xyz, d);
            // A VPL is a diffuse emitter: intensity flux/pi * cos.
            sum += v.flux.rgb * (vis * cy * cp / (PI * max(dist2, c2)));
        }
    }
    if (!first_chunk) {
        sum += imageLoad(indirect, hx).rgb;
    }
    imageStore(indirect, hx, vec4(sum, 1.0));
}
