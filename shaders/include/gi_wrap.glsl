// Texture wrap modes of the GI shaders' own texture reads (include/gi_mask.glsl,
// include/gi_texture.glsl): 0 repeat, 1 mirrored repeat, 2 clamp to edge.
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

#endif
