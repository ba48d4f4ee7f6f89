#version 450
#extension GL_GOOGLE_include_directive : require
// Resolve at full resolution: geometry-aware upsample of the blurred half-resolution indirect
// irradiance (bilinear weights over the four nearest half-resolution samples, keeping only those
// on the pixel's surface; if none is, any on it in the 3x3 around, else the pixel's own block),
// direct light from the spotlight with its paraboloid shadow map, receiver albedo, Reinhard tone
// mapping and gamma 2.2 into RGBA8.
layout(local_size_x = 8, local_size_y = 8) in;

#include "include/gi_shading.glsl"

// The blurred irradiance at pixel px (position p, normal n).
vec3 upsample(ivec2 px, vec3 p, vec3 n) {
    ivec2 half_size = imageSize(blurred);
    // Half-resolution sample i covers pixels 2i and 2i+1: its centre is at pixel 2i + 0.5.
    vec2 f = (vec2(px) - 0.5) * 0.5;
    ivec2 base = ivec2(floor(f));
    vec2 t = f - vec2(base);
    vec3 sum = vec3(0.0);
    float weight = 0.0;
    for (int k = 0; k < 4; k++) {
        ivec2 o = ivec2(k & 1, k >> 1);
        ivec2 q = clamp(base + o, ivec2(0), half_size - 1);
        if (!same_surface(p, n, imageLoad(half_position, q), imageLoad(half_normal, q).xyz)) {
            continue;
        }
        float w = (o.x == 1 ? t.x : 1.0 - t.x) * (o.y == 1 ? t.y : 1.0 - t.y) + 1e-3;
        sum += w * imageLoad(blurred, q).rgb;
        weight += w;
    }
    if (weight > 0.0) {
        return sum / weight;
    }
    ivec2 own = min(px / 2, half_size - 1);
    for (int dy = -1; dy <= 1; dy++) {
        for (int dx = -1; dx <= 1; dx++) {
            ivec2 q = clamp(own + ivec2(dx, dy), ivec2(0), half_size - 1);
            if (same_surface(p, n, imageLoad(half_position, q), imageLoad(half_normal, q).xyz)) {
                sum += imageLoad(blurred, q).rgb;
                weight += 1.0;
            }
        }
    }
    return weight > 0.0 ? sum / weight : imageLoad(blurred, own).rgb;
}

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

    vec3 e_indirect = mode != 2 ? upsample(px, p, n) : vec3(0.0);

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
