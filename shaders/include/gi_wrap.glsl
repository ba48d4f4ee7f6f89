// Texture wrap modes and the texels a read takes, for the GI shaders' own texture reads
// (include/gi_mask.glsl, include/gi_texture.glsl): 0 repeat, 1 mirrored repeat, 2 clamp to
// edge.
#ifndef GI_WRAP_GLSL
#define GI_WRAP_GLSL

// Wrap mode (0 repeat, 1 mirrored repeat, 2 clamp) applied to a coordinate, into [0, 1].
float wrap_coord(float t, uint mode) {
    if (mode == 0u) {
        return t - floor(t);
    }
    if (mode == 1u) {
        float m = mod(t, 2.0);
        return m > 1.0 ? 2.0 - m : m;
    }
    return clamp(t, 0.0, 1.0);
}

// Wrap mode applied to texel index i of an axis of n texels, for i in -1..=n (the two texels
// a bilinear read takes around a wrapped coordinate): selects, no integer division (which a
// CPU driver runs lane by lane). Equal to the general rule there (src/scene/material.rs,
// sample_texels).
int wrap_index(int i, int n, uint mode) {
    if (mode == 0u) {
        return i < 0 ? n - 1 : (i >= n ? 0 : i);
    }
    return clamp(i, 0, n - 1);
}

// The texel of a level of width x height texels nearest to `uv`, wrapped by modes wu, wv.
ivec2 nearest_texel(vec2 uv, int width, int height, uint wu, uint wv) {
    float u = wrap_coord(uv.x, wu) * float(width);
    float v = wrap_coord(uv.y, wv) * float(height);
    return ivec2(min(int(u), width - 1), min(int(v), height - 1));
}

// The four texels a bilinear read of `uv` takes from a level of width x height texels,
// wrapped by modes wu, wv: columns x0 (.x) and x1 (.z), rows y0 (.y) and y1 (.w); `t` is the
// weight of x1 and of y1. The same rule as src/scene/material.rs (sample_texels).
ivec4 bilinear_texels(vec2 uv, int width, int height, uint wu, uint wv, out vec2 t) {
    vec2 f = vec2(wrap_coord(uv.x, wu) * float(width), wrap_coord(uv.y, wv) * float(height)) - 0.5;
    vec2 f0 = floor(f);
    t = f - f0;
    return ivec4(
        wrap_index(int(f0.x), width, wu),
        wrap_index(int(f0.y), height, wv),
        wrap_index(int(f0.x) + 1, width, wu),
        wrap_index(int(f0.y) + 1, height, wv));
}

#endif
