// Alpha masks in the GI raster passes (gi_shadow_masked.frag, gi_gbuffer_masked.frag): the
// material's alpha at a fragment is its corners' alpha over the cutoff (interpolated) times the
// texture's alpha, read from level 0 with its sampler's wrap modes and magnification filter
// (nearest or bilinear), as the CPU does (MaskImage::sample in src/scene/mask.rs), so the ray
// caster, the ISM points and the raster passes agree on the holes.

// Four words per image (first texel word, width, height, flags: wrap u bits 0-1, wrap v bits
// 2-3, linear bit 4), then the alpha bytes, four to a word.
layout(std430, set = 0, binding = 3) readonly buffer MaskWords { uint words[]; };

#include "include/gi_wrap.glsl"

float texel(uint base, int width, int x, int y) {
    uint i = uint(y * width + x);
    return float((words[base + i / 4u] >> (8u * (i % 4u))) & 255u) / 255.0;
}

float mask_alpha(int image, vec2 uv) {
    uint h = uint(image) * 4u;
    uint base = words[h];
    int width = int(words[h + 1u]);
    int height = int(words[h + 2u]);
    uint flags = words[h + 3u];
    uint wu = flags & 3u;
    uint wv = (flags >> 2) & 3u;
    if ((flags & 16u) == 0u) {
        ivec2 p = nearest_texel(uv, width, height, wu, wv);
        return texel(base, width, p.x, p.y);
    }
    vec2 t;
    ivec4 q = bilinear_texels(uv, width, height, wu, wv, t);
    float top = mix(texel(base, width, q.x, q.y), texel(base, width, q.z, q.y), t.x);
    float bottom = mix(texel(base, width, q.x, q.w), texel(base, width, q.z, q.w), t.x);
    return mix(top, bottom, t.y);
}

// Whether the fragment with mask data `m` (u, v, alpha over cutoff) of image `image` (-1:
// none) is kept.
bool mask_keeps(vec3 m, int image) {
    float alpha = m.z;
    if (image >= 0) {
        alpha *= mask_alpha(image, m.xy);
    }
    // KEEP in src/scene/mask.rs: interpolating three equal corner values may lose an ulp.
    return alpha >= 1.0 - 1e-4;
}
