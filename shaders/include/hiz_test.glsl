// The conservative Hi-Z box test shared by hiz_cull.comp and part_test.comp. The including
// shader declares, before the include: the push block `pc` with `mat4 view_proj`,
// `uvec4 info` (z: pyramid levels, 0 for none; w: most texels per side read for one box) and
// `vec4 screen` (width, height, depth margin); and `sampler2D pyramid`, the farthest-depth
// pyramid (hiz_reduce.comp).

// Farthest pyramid depth over pixels [lo, hi] (inclusive): the finest level whose texels
// cover the rectangle with at most n x n of them (n = info.w). A texel of level k covers
// 2^(k+1) pixels.
float farthest_depth(ivec2 lo, ivec2 hi) {
    int levels = int(pc.info.z);
    int most = int(pc.info.w) - 1;
    int k = 0;
    while (k < levels - 1) {
        ivec2 span = (hi >> (k + 1)) - (lo >> (k + 1));
        if (span.x <= most && span.y <= most) {
            break;
        }
        k++;
    }
    ivec2 a = lo >> (k + 1);
    ivec2 b = hi >> (k + 1);
    float d = 0.0;
    for (int y = a.y; y <= b.y; y++) {
        for (int x = a.x; x <= b.x; x++) {
            d = max(d, texelFetch(pyramid, ivec2(x, y), k).r);
        }
    }
    return d;
}

// 0: outside the frustum, 1: may be visible, 2: occluded.
uint classify(vec3 bmin, vec3 bmax) {
    vec2 lo = vec2(1e30);
    vec2 hi = vec2(-1e30);
    float nearest = 1e30;
    bool crosses_near = false;
    uint all_out = 63u; // bit per clip plane: every corner so far is outside it
    for (int c = 0; c < 8; c++) {
        vec3 p = vec3((c & 1) != 0 ? bmax.x : bmin.x,
                      (c & 2) != 0 ? bmax.y : bmin.y,
                      (c & 4) != 0 ? bmax.z : bmin.z);
        vec4 clip = pc.view_proj * vec4(p, 1.0);
        uint out_planes = (clip.x < -clip.w ? 1u : 0u) | (clip.x > clip.w ? 2u : 0u) |
                          (clip.y < -clip.w ? 4u : 0u) | (clip.y > clip.w ? 8u : 0u) |
                          (clip.z < 0.0 ? 16u : 0u) | (clip.z > clip.w ? 32u : 0u);
        all_out &= out_planes;
        if (clip.w <= 1e-6 || clip.z < 0.0) {
            crosses_near = true;
            continue;
        }
        vec3 ndc = clip.xyz / clip.w;
        vec2 px = vec2(ndc.x * 0.5 + 0.5, 0.5 - ndc.y * 0.5) * pc.screen.xy;
        lo = min(lo, px);
        hi = max(hi, px);
        nearest = min(nearest, ndc.z);
    }
    if (all_out != 0u) {
        return 0u;
    }
    if (crosses_near || pc.info.z == 0u) {
        return 1u;
    }
    ivec2 size = ivec2(pc.screen.xy);
    if (hi.x < 0.0 || hi.y < 0.0 || lo.x > pc.screen.x || lo.y > pc.screen.y) {
        return 0u;
    }
    ivec2 plo = clamp(ivec2(floor(lo)), ivec2(0), size - 1);
    ivec2 phi = clamp(ivec2(floor(hi)), ivec2(0), size - 1);
    return nearest - pc.screen.z > farthest_depth(plo, phi) ? 2u : 1u;
}
