#version 450
#extension GL_GOOGLE_include_directive : require
// The predicated mode's part tests (the built-in renderer): each workgroup decides 64 parts of
// split nodes, one per invocation, and scans the depth under the boxes of those parts that
// need it together, one part after another. A part's predicate is 1 when its node's query
// counted a sample and one of its boxes may be visible against the depth drawn so far in this
// frame, else 0. A box may be visible when it reaches the near plane, when its screen
// rectangle covers more than info.z pixels (not read: the scan's cost stays bounded), or when
// the ray through the centre of one pixel in its rectangle enters the box (grown a little for
// rounding) at a depth at or in front of that pixel's depth texel plus a margin: the box's own
// depth per pixel, as a query's rasterized faces test it, not the rectangle at the box's
// nearest depth. A texel nearer than the box's nearest depth (include/box_project.glsl) is
// rejected without the ray. The test is conservative, so a part that owns a pixel of the final
// image is never 0: an object's pixel centre lies on a ray that enters its box no later than at
// the object, and the depth it is tested against only gets nearer as the frame goes on.
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
    // width, height, depth margin, unused
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

// The eye's rays: a pixel centre at NDC (x, y) lies on the segment from the near plane's point
// inv_vp * (x, y, 0, 1) = ray_x * x + ray_y * y + ray_o to the far plane's, that plus ray_far
// (homogeneous; the columns of the inverse of view_proj, set in main).
vec4 ray_x;
vec4 ray_y;
vec4 ray_o;
vec4 ray_far;

// Whether the ray through the centre of pixel `px` enters the box [bmin, bmax] at a depth at
// or in front of `texel` plus the margin. The box is grown by a part in 2^15 of the largest
// coordinate involved, far more than float rounding in the ray, so that a point of the box is
// never missed.
bool ray_reaches(ivec2 px, vec3 bmin, vec3 bmax, float texel) {
    vec2 ndc = vec2((float(px.x) + 0.5) / pc.screen.x * 2.0 - 1.0,
                    1.0 - (float(px.y) + 0.5) / pc.screen.y * 2.0);
    vec4 a = ray_x * ndc.x + ray_y * ndc.y + ray_o;
    vec4 b = a + ray_far;
    if (a.w <= 0.0 || b.w <= 0.0) {
        return true;
    }
    vec3 o = a.xyz / a.w;
    vec3 d = b.xyz / b.w - o;
    vec3 m = max(abs(o), max(abs(bmin), abs(bmax)));
    float grow = max(max(m.x, m.y), m.z) * (1.0 / 32768.0) + 1e-6;
    vec3 inv = vec3(1.0) / mix(d, vec3(1e-30), lessThan(abs(d), vec3(1e-30)));
    vec3 t0 = (bmin - grow - o) * inv;
    vec3 t1 = (bmax + grow - o) * inv;
    vec3 tn = min(t0, t1);
    vec3 tf = max(t0, t1);
    float enter = max(max(max(tn.x, tn.y), tn.z), 0.0);
    float leave = min(min(min(tf.x, tf.y), tf.z), 1.0);
    if (enter > leave) {
        return false;
    }
    // NDC depth along the segment: t * a.w / ((1 - t) * b.w + t * a.w).
    float depth = enter * a.w / ((1.0 - enter) * b.w + enter * a.w);
    return texel >= depth - pc.screen.z;
}

// Whether a depth texel in [lo, hi] lies at or behind `limit` and behind the box there
// (ray_reaches), read by the whole workgroup in blocks of 8x8 texels, one per invocation.
// Called in uniform control flow (every value it depends on is the same in the whole
// workgroup): the scan stops for all invocations at the first chunk of block rows in which one
// of them found such a texel.
bool any_behind(ivec2 lo, ivec2 hi, float limit, vec3 bmin, vec3 bmax) {
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
                if (!hit) {
                    float texel = texelFetch(depth, ivec2(x, y), 0).r;
                    hit = texel >= limit && ray_reaches(ivec2(x, y), bmin, bmax, texel);
                }
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
    mat4 inv_vp = inverse(pc.view_proj);
    ray_x = inv_vp[0];
    ray_y = inv_vp[1];
    ray_far = inv_vp[2];
    ray_o = inv_vp[3];
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
                visible = any_behind(lo, hi, nearest - pc.screen.z, corners[2u * b].xyz,
                                     corners[2u * b + 1u].xyz);
            }
        }
        if (gl_LocalInvocationIndex == 0u) {
            predicates[j] = visible ? 1u : 0u;
        }
    }
}
