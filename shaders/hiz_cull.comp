#version 450
#extension GL_GOOGLE_include_directive : require
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
    // its group (the objects that bind what it binds): the first command slot of the group in
    // a phase's stretch, the counter of the group's phase-1 draws, of its phase-2 draws, unused
    uvec4 group;
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
// triangles[p - 1]: the triangles of phase p's draws (report only); count[c]: the draws of one
// group in one phase (ObjectBounds.group.yz name them).
layout(std430, set = 0, binding = 3) buffer Counters { uint triangles[2]; uint spare[2]; uint count[]; };
layout(set = 0, binding = 4) uniform sampler2D pyramid;

layout(push_constant) uniform Push {
    mat4 view_proj;
    // object count, phase (1 or 2), pyramid levels (0: no pyramid to test against), most
    // texels per side read for one box
    uvec4 info;
    // width, height, depth margin, pixel-centre margin (negative: no pixel-centre test)
    vec4 screen;
} pc;

const uint VISIBLE = 1u;
const uint DRAWN_EARLY = 2u;

#include "include/hiz_test.glsl"

void append(uint phase, uint i) {
    uvec4 d = objects[i].draw;
    uvec4 g = objects[i].group;
    uint slot = atomicAdd(count[phase == 1u ? g.y : g.z], 1u);
    atomicAdd(triangles[phase - 1u], d.x / 3u);
    draws[(phase - 1u) * pc.info.x + g.x + slot] = DrawCommand(d.x, 1u, d.y, int(d.z), i);
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
