// A box's screen rectangle and nearest depth, shared by the Hi-Z test (hiz_test.glsl) and the
// predicated mode's part test (part_test.comp). The including shader declares, before the
// include, the push block `pc` with `mat4 view_proj` and `vec4 screen` (width, height, depth
// margin, pixel-centre margin: negative for none).

// Every corner lies outside one clip plane: the box is outside the frustum.
const uint BOX_OUTSIDE = 0u;
// A corner lies behind the near plane (or at the eye): the box may cover any pixel.
const uint BOX_NEAR = 1u;
// The box lies in front of the near plane but its rectangle misses the screen, or (with a
// pixel-centre margin) holds no pixel centre: it can cover no sample.
const uint BOX_OFF_SCREEN = 2u;
// The box's fragments lie within pixels [plo, phi] (inclusive) at depth `nearest` or farther.
const uint BOX_ON_SCREEN = 3u;

// Projects the 8 corners. A fragment's pixel centre lies in the corners' rectangle, so its
// pixel lies in [floor(lo), floor(hi)]; depth is monotonic in view depth in front of the near
// plane, so no point of the box is nearer than its nearest corner.
uint project_box(vec3 bmin, vec3 bmax, out ivec2 plo, out ivec2 phi, out float nearest) {
    vec2 lo = vec2(1e30);
    vec2 hi = vec2(-1e30);
    nearest = 1e30;
    plo = ivec2(0);
    phi = ivec2(-1);
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
        return BOX_OUTSIDE;
    }
    if (crosses_near) {
        return BOX_NEAR;
    }
    if (hi.x < 0.0 || hi.y < 0.0 || lo.x > pc.screen.x || lo.y > pc.screen.y) {
        return BOX_OFF_SCREEN;
    }
    ivec2 size = ivec2(pc.screen.xy);
    plo = clamp(ivec2(floor(lo)), ivec2(0), size - 1);
    phi = clamp(ivec2(floor(hi)), ivec2(0), size - 1);
    if (pc.screen.w >= 0.0) {
        // One sample a pixel, at its centre (i + 0.5): a fragment's centre lies in the
        // rectangle grown by the margin (the rasterizer's sub-pixel snapping), so only the
        // pixels whose centres do can be covered, and a box holding none covers nothing.
        ivec2 first = max(ivec2(ceil(lo - pc.screen.w - 0.5)), ivec2(0));
        ivec2 last = min(ivec2(floor(hi + pc.screen.w - 0.5)), size - 1);
        if (any(greaterThan(first, last))) {
            return BOX_OFF_SCREEN;
        }
        plo = first;
        phi = last;
    }
    return BOX_ON_SCREEN;
}
