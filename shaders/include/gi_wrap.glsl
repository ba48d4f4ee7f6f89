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

// Wrap mode applied to a texel index of an axis of n texels.
int wrap_index(int i, int n, uint mode) {
    if (mode == 0u) {
        return ((i % n) + n) % n;
    }
    if (mode == 1u) {
        int m = ((i % (2 * n)) + 2 * n) % (2 * n);
        return m >= n ? 2 * n - 1 - m : m;
    }
    return clamp(i, 0, n - 1);
}

#endif
