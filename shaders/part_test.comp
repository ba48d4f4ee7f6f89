#version 450
#extension GL_GOOGLE_include_directive : require
// The predicated mode's part tests (the built-in renderer): each invocation decides one part of
// a split node. Its predicate is 1 when its node's query counted a sample and one of its boxes
// may be visible against the pyramid of the depth drawn so far in this frame, else 0. The
// test is conservative (include/hiz_test.glsl), so a part that owns a pixel of the final image
// is never 0: the depth it is tested against only gets nearer as the frame goes on.
layout(local_size_x = 64) in;

struct Part {
    uint first_box;
    uint boxes;
    uint node_query; // the split node's query: its 32-bit value is node_values[node_query]
    uint unused;
};

layout(std430, set = 0, binding = 0) readonly buffer Parts { Part parts[]; };
// Two vec4 per box: min, max (w unused).
layout(std430, set = 0, binding = 1) readonly buffer Boxes { vec4 corners[]; };
layout(std430, set = 0, binding = 2) readonly buffer NodeValues { uint node_values[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Predicates { uint predicates[]; };
layout(set = 0, binding = 4) uniform sampler2D pyramid;

layout(push_constant) uniform Push {
    mat4 view_proj;
    // parts in this dispatch, first part, pyramid levels, most texels per side read for one box
    uvec4 info;
    // width, height, depth margin, unused
    vec4 screen;
} pc;

#include "include/hiz_test.glsl"

void main() {
    if (gl_GlobalInvocationID.x >= pc.info.x) {
        return;
    }
    uint i = pc.info.y + gl_GlobalInvocationID.x;
    Part p = parts[i];
    uint visible = 0u;
    if (node_values[p.node_query] != 0u) {
        for (uint b = p.first_box; b < p.first_box + p.boxes && visible == 0u; b++) {
            if (classify(corners[2u * b].xyz, corners[2u * b + 1u].xyz) == 1u) {
                visible = 1u;
            }
        }
    }
    predicates[i] = visible;
}
