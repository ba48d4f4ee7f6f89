#version 450
// Hi-Z GPU culling, one phase. Each invocation tests one object's world box against the
// frustum and the depth pyramid and appends an indexed indirect draw for it when it may be
// visible.
//   phase 1: objects visible last frame (flag bit 0), tested against the pyramid left by the
//            previous frame (when there is one); drawn ones get flag bit 1.
//   phase 2: every object, tested against the pyramid of this frame's phase-1 depth; drawn
//            when visible and not drawn in phase 1. Writes the visibility flags of next frame.
// The test is conservative: boxes that cross the near plane are visible, and a box is culled
// only when its nearest depth is farther than the farthest depth of every pyramid texel under
// its screen rectangle.
layout(local_size_x = 64) in;

struct ObjectBounds {
    vec4 bmin;
    vec4 bmax;
    uvec4 draw; // index count, first index, vertex offset (as int), unused
};
struct DrawCommand {
    uint index_count;
    uint instance_count;
    uint first_index;
    int vertex_offset;
    uint first_instance;
};

layout(std430, set = 0, binding = 0) readonly buffer Bounds { ObjectBounds objects[]; };
layout(std430, set = 0, binding = 1) buffer Flags { uint flags[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Draws { DrawCommand draws[]; };
// count[p - 1]: draws of phase p; triangles[p - 1]: their triangles (report only).
layout(std430, set = 0, binding = 3) buffer Counters { uint count[2]; uint triangles[2]; };
layout(set = 0, binding = 4) uniform sampler2D pyramid;

layout(push_constant) uniform Push {
    mat4 view_proj;
    // object count, phase (1 or 2), pyramid levels (0: no pyramid to test against), most
    // texels per side read for one box
    uvec4 info;
    // width, height, depth margin, unused
    vec4 screen;
} pc;

const uint VISIBLE = 1u;
const uint DRAWN_EARLY = 2u;

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

void append(uint phase, uint i) {
    uvec4 d = objects[i].draw;
    uint slot = atomicAdd(count[phase - 1u], 1u);
    atomicAdd(triangles[phase - 1u], d.x / 3u);
    draws[(phase - 1u) * pc.info.x + slot] = DrawCommand(d.x, 1u, d.y, int(d.z), i);
}

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.info.x || objects[i].draw.x == 0u) {
        return;
    }
    uint phase = pc.info.y;
    uint f = flags[i];
    if (phase == 1u) {
        if ((f & VISIBLE) != 0u && classify(objects[i].bmin.xyz, objects[i].bmax.xyz) == 1u) {
            append(1u, i);
            flags[i] = VISIBLE | DRAWN_EARLY;
        }
        return;
    }
    bool visible = classify(objects[i].bmin.xyz, objects[i].bmax.xyz) == 1u;
    if (visible && (f & DRAWN_EARLY) == 0u) {
        append(2u, i);
    }
    flags[i] = visible ? VISIBLE : 0u;
}
