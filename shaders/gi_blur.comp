#version 450
#extension GL_GOOGLE_include_directive : require
// Geometry-aware 4x4 blur of the interleaved half-resolution irradiance: a 4x4 window holds
// each of the 16 VPL classes once; neighbours on another surface (normal or plane differ) are
// skipped, and the mean of the rest times 16 estimates the sum over all VPLs.
layout(local_size_x = 8, local_size_y = 8) in;

#include "include/gi_shading.glsl"

void main() {
    ivec2 hx = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = imageSize(indirect);
    if (hx.x >= size.x || hx.y >= size.y) {
        return;
    }
    vec4 p4 = imageLoad(half_position, hx);
    if (p4.w < 0.5) {
        imageStore(blurred, hx, vec4(0.0));
        return;
    }
    vec3 n = imageLoad(half_normal, hx).xyz;
    vec3 sum = vec3(0.0);
    float weight = 0.0;
    for (int dy = -2; dy <= 1; dy++) {
        for (int dx = -2; dx <= 1; dx++) {
            ivec2 q = hx + ivec2(dx, dy);
            if (q.x < 0 || q.y < 0 || q.x >= size.x || q.y >= size.y) {
                continue;
            }
            if (!same_surface(p4.xyz, n, imageLoad(half_position, q), imageLoad(half_normal, q).xyz)) {
                continue;
            }
            sum += imageLoad(indirect, q).rgb;
            weight += 1.0;
        }
    }
    imageStore(blurred, hx, vec4(sum * (16.0 / max(weight, 1.0)), 1.0));
}
