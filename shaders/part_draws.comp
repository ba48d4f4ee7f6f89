#version 450
// The predicated mode's gathered draws (the built-in renderer), at a predicate resolve: the
// draw commands of the groups whose predicate holds are copied, in the order the groups were
// handed over, into one list that a single vkCmdDrawIndexedIndirectCount draws; `count`
// receives its length. A group's predicate is a part's (written by part_test.comp just
// before) or a queried node's value (the query's result, copied at the resolve: non-zero
// where it counted a sample, as a conditional block on it reads it). One workgroup walks the
// groups 64 at a time with a prefix sum in shared memory, so the list's order does not depend
// on how invocations are scheduled (the image is the same from run to run).
layout(local_size_x = 64) in;

struct Group {
    uint id;            // the part or query whose predicate decides the group
    uint first_command; // its commands: candidates[first_command ..]
    uint commands;
    uint source;        // 0: predicates[id] (a part); 1: node_values[id] (a query)
};

struct Command {
    uint index_count;
    uint instance_count;
    uint first_index;
    int vertex_offset;
    uint first_instance;
};

layout(std430, set = 0, binding = 0) readonly buffer Groups { Group groups[]; };
layout(std430, set = 0, binding = 1) readonly buffer Predicates { uint predicates[]; };
layout(std430, set = 0, binding = 2) readonly buffer Candidates { Command candidates[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Drawn { Command drawn[]; };
layout(std430, set = 0, binding = 4) writeonly buffer Count { uint count; };
layout(std430, set = 0, binding = 5) readonly buffer NodeValues { uint node_values[]; };

layout(push_constant) uniform Push {
    // first group, groups
    uvec4 info;
} pc;

// Inclusive prefix sums of the commands of one round's 64 groups.
shared uint sums[64];

void main() {
    uint lane = gl_LocalInvocationIndex;
    uint base = 0u;
    for (uint round = 0u; round < pc.info.y; round += 64u) {
        uint i = round + lane;
        Group g = Group(0u, 0u, 0u, 0u);
        uint n = 0u;
        if (i < pc.info.y) {
            g = groups[pc.info.x + i];
            uint value = g.source != 0u ? node_values[g.id] : predicates[g.id];
            n = value != 0u ? g.commands : 0u;
        }
        sums[lane] = n;
        barrier();
        for (uint step = 1u; step < 64u; step <<= 1u) {
            uint add = lane >= step ? sums[lane - step] : 0u;
            barrier();
            sums[lane] += add;
            barrier();
        }
        uint at = base + sums[lane] - n;
        for (uint c = 0u; c < n; c++) {
            drawn[at + c] = candidates[g.first_command + c];
        }
        base += sums[63];
        barrier();
    }
    if (lane == 0u) {
        count = base;
    }
}
