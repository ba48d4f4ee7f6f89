// Base color textures in the GI's G-buffer (gi_gbuffer_textured*.frag): the albedo of a
// fragment is its corners' color without the texture (interpolated) times the texture, read
// from the level where a texel covers about a pixel (the nearest level, when the sampler uses
// mip levels) with the sampler's wrap modes and filter. The images are packed by
// src/gi/textures.rs (pack_images), their texels already decoded from sRGB to linear, so they
// are filtered in linear space as a sampler of an sRGB image filters them.
#include "include/gi_wrap.glsl"

// Four words per image (first word of its first level, width and height of that level, number
// of levels), then the levels one after the other from the largest, a word per texel (RGBA8,
// linear).
layout(std430, set = 0, binding = 5) readonly buffer TextureWords { uint tex_words[]; };

vec3 tex_texel(uint base, int width, int x, int y) {
    return unpackUnorm4x8(tex_words[base + uint(y * width + x)]).rgb;
}

// Level (base, width, height) at `uv`: nearest texel, or bilinear with `linear`.
vec3 tex_level(uint base, int width, int height, vec2 uv, uint wu, uint wv, bool linear) {
    if (!linear) {
        ivec2 p = nearest_texel(uv, width, height, wu, wv);
        return tex_texel(base, width, p.x, p.y);
    }
    vec2 t;
    ivec4 q = bilinear_texels(uv, width, height, wu, wv, t);
    vec3 top = mix(tex_texel(base, width, q.x, q.y), tex_texel(base, width, q.z, q.y), t.x);
    vec3 bottom = mix(tex_texel(base, width, q.x, q.w), tex_texel(base, width, q.z, q.w), t.x);
    return mix(top, bottom, t.y);
}

// The linear color of image `image` at `uv`, whose screen derivatives are `uv_dx` and `uv_dy`;
// `flags`: wrap u (bits 0-1), wrap v (bits 2-3), linear magnification (bit 4), linear
// minification (bit 5), mip levels used (bit 6), linear between levels (bit 7: the two levels
// around the footprint blended, else the nearest one).
vec3 texture_albedo(int image, vec2 uv, uint flags, vec2 uv_dx, vec2 uv_dy) {
    uint h = uint(image) * 4u;
    uint base = tex_words[h];
    int width = int(tex_words[h + 1u]);
    int height = int(tex_words[h + 2u]);
    int levels = int(tex_words[h + 3u]);
    vec2 size = vec2(width, height);
    vec2 dx = uv_dx * size;
    vec2 dy = uv_dy * size;
    // log2 of the texels a pixel spans along its longer screen axis.
    float lod = 0.5 * log2(max(max(dot(dx, dx), dot(dy, dy)), 1e-20));
    bool minified = lod > 0.0;
    uint wu = flags & 3u;
    uint wv = (flags >> 2) & 3u;
    bool linear = minified ? (flags & 32u) != 0u : (flags & 16u) != 0u;
    if (!minified || (flags & 64u) == 0u) {
        return tex_level(base, width, height, uv, wu, wv, linear);
    }
    bool blend = (flags & 128u) != 0u;
    float at = clamp(blend ? lod : lod + 0.5, 0.0, float(levels - 1));
    int level = int(at);
    for (int l = 0; l < level; l++) {
        base += uint(width * height);
        width = max(width / 2, 1);
        height = max(height / 2, 1);
    }
    vec3 c = tex_level(base, width, height, uv, wu, wv, linear);
    float t = at - float(level);
    if (blend && t > 0.0) {
        uint next = base + uint(width * height);
        vec3 d = tex_level(next, max(width / 2, 1), max(height / 2, 1), uv, wu, wv, linear);
        c = mix(c, d, t);
    }
    return c;
}
