#version 450
#extension GL_GOOGLE_include_directive : require
// The predicated mode's part tests (the built-in renderer): each workgroup decides 64 parts of
// split nodes, one per invocation, and scans the depth under the boxes of those parts that
// need it together, one part after another. A part's predicate is 1 when its node's query
// counted a sample and one of its boxes may be visible against the depth drawn so far in this
// frame, else 0. A box may be visible when it reaches the near plane, when its screen
// rectangle covers more than info.z pixels (not read: the scan's cost stays bounded), or when
// one depth texel in its rectangle lies at or behind its nearest depth less a margin. The test
// is conservative (include/box_project.glsl), so a part that owns a pixel of the final image
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
layout(set = 0, binding = 4) uniform sampler2D depth;

layout(push_constant) uniform Push {
    mat4 view_proj;
    // parts in this dispatch, first part, most pixels read for one box, unused
    uvec4 info;
    // width, height, depth margin, pixel-centre margin (negative: no pixel-centre test)
    vec4 screen;
} pc;

#include "include/box_project.glsl"

// Rows of 8x8 texel blocks the workgroup reads between two checks of `found`.
const uint CHUNK_ROWS = 4u;

// Set when an invocation read a texel at or behind the box (0 -> 1 only).
shared uint found;
// Parts of this workgroup whose boxes must be scanned, and how many.
shared uint to_scan[64];
shared uint scans;

// Whether a depth texel in [lo, hi] lies at or behind `limit`, read by the whole workgroup in
// blocks of 8x8 texels, one per invocation. Called in uniform control flow (every value it
// depends on is the same in the whole workgroup): the scan stops for all invocations at the
// first chunk of block rows in which one of them found such a texel.
bool any_behind(ivec2 lo, ivec2 hi, float limit) {
    ivec2 lane = ivec2(int(gl_LocalInvocationIndex & 7u), int(gl_LocalInvocationIndex >> 3));
    if (gl_LocalInvocationIndex == 0u) {
        found = 0u;
    }
    barrier();
    for (int y0 = lo.y; y0 <= hi.y; y0 += 8 * int(CHUNK_ROWS)) {
        bool hit = false;
        int y_end = min(hi.y, y0 + 8 * int(CHUNK_ROWS) - 1);
        for (int y = y0 + lane.y; y <= y_end; y += 8) {
            for (int x = lo.x + lane.x; x <= hi.x; x += 8) {
                hit = hit || texelFetch(depth, ivec2(x, y), 0).r >= limit;
            }
        }
        if (hit) {
            found = 1u;
        }
        barrier();
        bool stop = found != 0u;
        barrier();
        if (stop) {
            return true;
        }
    }
    return false;
}

void main() {
    if (gl_LocalInvocationIndex == 0u) {
        scans = 0u;
    }
    barrier();
    // Each invocation decides its own part where it can: a hidden node, a box that reaches
    // the near plane or is too large to read, or no box on the screen.
    uint i = pc.info.y + gl_GlobalInvocationID.x;
    if (gl_GlobalInvocationID.x < pc.info.x) {
        Part p = parts[i];
        uint decided = 0u; // 0: hidden, 1: may be visible, 2: to be scanned
        if (node_values[p.node_query] != 0u) {
            for (uint b = p.first_box; b < p.first_box + p.boxes && decided != 1u; b++) {
                ivec2 lo;
                ivec2 hi;
                float nearest;
                uint c = project_box(corners[2u * b].xyz, corners[2u * b + 1u].xyz, lo, hi,
                                     nearest);
                if (c == BOX_NEAR) {
                    decided = 1u;
                } else if (c == BOX_ON_SCREEN) {
                    uint area = uint(hi.x - lo.x + 1) * uint(hi.y - lo.y + 1);
                    decided = area > pc.info.z ? 1u : 2u;
                }
            }
        }
        if (decided == 2u) {
            to_scan[atomicAdd(scans, 1u)] = i;
        } else {
            predicates[i] = decided;
        }
    }
    barrier();
    // The parts left, one after another, by the whole workgroup.
    uint n = scans;
    for (uint s = 0u; s < n; s++) {
        uint j = to_scan[s];
        Part p = parts[j];
        bool visible = false;
        for (uint b = p.first_box; b < p.first_box + p.boxes && !visible; b++) {
            ivec2 lo;
            ivec2 hi;
            float nearest;
            uint c = project_box(corners[2u * b].xyz, corners[2u * b + 1u].xyz, lo, hi, nearest);
            if (c == BOX_ON_SCREEN) {
                visible = any_behind(lo, hi, nearest - pc.screen.z);
            }
        }
        if (gl_LocalInvocationIndex == 0u) {
            predicates[j] = visible ? 1u : 0u;
        }
    }
}
