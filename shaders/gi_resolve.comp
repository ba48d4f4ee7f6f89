#version 450
#extension GL_GOOGLE_include_directive : require
// Resolve: geometry-aware 4x4 blur of the interleaved indirect irradiance (a 4x4 window holds
// each of the 16 VPL classes once; neighbours whose normal or plane differ are skipped), direct
// light from the spotlight with its paraboloid shadow map, receiver albedo, Reinhard tone mapping
// and gamma 2.2 into RGBA8.
layout(local_size_x = 8, local_size_y = 8) in;

#include "include/gi_shading.glsl"

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = imageSize(g_position);
    if (px.x >= size.x || px.y >= size.y) {
        return;
    }
    vec4 p4 = imageLoad(g_position, px);
    if (p4.w < 0.5) {
        imageStore(out_color, px, vec4(0.0, 0.0, 0.0, 1.0));
        return;
    }
    vec3 p = p4.xyz;
    vec3 n = imageLoad(g_normal, px).xyz;
    vec3 albedo = imageLoad(g_albedo, px).rgb;
    int mode = int(pc.spot_power.w);

    vec3 e_indirect = vec3(0.0);
    if (mode != 2) {
        float weight = 0.0;
        for (int dy = -2; dy <= 1; dy++) {
            for (int dx = -2; dx <= 1; dx++) {
                ivec2 q = px + ivec2(dx, dy);
                if (q.x < 0 || q.y < 0 || q.x >= size.x || q.y >= size.y) {
                    continue;
                }
                vec4 q4 = imageLoad(g_position, q);
                if (q4.w < 0.5) {
                    continue;
                }
                vec3 nq = imageLoad(g_normal, q).xyz;
                if (dot(n, nq) < 0.9 || abs(dot(q4.xyz - p, n)) > pc.misc.w) {
                    continue;
                }
                e_indirect += imageLoad(indirect, q).rgb;
                weight += 1.0;
            }
        }
        // Each pixel saw 1/16 of the VPLs: the average times 16 estimates the full sum.
        e_indirect *= 16.0 / max(weight, 1.0);
    }

    vec3 e_direct = vec3(0.0);
    if (mode != 1) {
        vec3 d = p + n * pc.misc.z - pc.spot_pos.xyz;
        float dist2 = max(dot(d, d), 1e-12);
        vec3 w = d * inversesqrt(dist2);
        vec3 dir = normalize(pc.spot_dir.xyz);
        float cl = dot(dir, w);
        float cp = -dot(n, w);
        if (cl > 0.0 && cp > 0.0) {
            float vis = visibility(pc.spot_pos.w, dir, d);
            float c2 = pc.gather.w * pc.gather.w;
            e_direct = pc.spot_power.rgb * (vis * cl * cp / (PI * max(dist2, c2)));
        }
    }

    vec3 radiance = albedo / PI * (e_direct + e_indirect) * pc.misc.y;
    vec3 mapped = radiance / (1.0 + radiance);
    imageStore(out_color, px, vec4(pow(mapped, vec3(1.0 / 2.2)), 1.0));
}
