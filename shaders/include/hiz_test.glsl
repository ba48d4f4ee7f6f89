// The conservative Hi-Z box test of hiz_cull.comp. The including shader declares, before the
// include: the push block `pc` with `mat4 view_proj`, `uvec4 info` (z: pyramid levels, 0 for
// none; w: most texels per side read for one box) and `vec4 screen` (width, height, depth
// margin); and `sampler2D pyramid`, the farthest-depth pyramid (hiz_reduce.comp).

#include "include/box_project.glsl"

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
    ivec2 plo;
    ivec2 phi;
    float nearest;
    uint c = project_box(bmin, bmax, plo, phi, nearest);
    if (c == BOX_OUTSIDE) {
        return 0u;
    }
    if (c == BOX_NEAR || pc.info.z == 0u) {
        return 1u;
    }
    if (c == BOX_OFF_SCREEN) {
        return 0u;
    }
    return nearest - pc.screen.z > farthest_depth(plo, phi) ? 2u : 1u;
}
