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
    float u = wrap_coord(uv.x, wu) * float(width);
    float v = wrap_coord(uv.y, wv) * float(height);
    if ((flags & 16u) == 0u) {
        return texel(base, width, min(int(u), width - 1), min(int(v), height - 1));
    }
    vec2 f = vec2(u, v) - 0.5;
    vec2 f0 = floor(f);
    vec2 frac_ = f - f0;
    int x0 = wrap_index(int(f0.x), width, wu);
    int x1 = wrap_index(int(f0.x) + 1, width, wu);
    int y0 = wrap_index(int(f0.y), height, wv);
    int y1 = wrap_index(int(f0.y) + 1, height, wv);
    float top = mix(texel(base, width, x0, y0), texel(base, width, x1, y0), frac_.x);
    float bottom = mix(texel(base, width, x0, y1), texel(base, width, x1, y1), frac_.x);
    return mix(top, bottom, frac_.y);
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
