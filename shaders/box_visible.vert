#version 450
// The marking pass of the box oracle (`oracle-box`, against the exact ID pass's depth) and of
// the box flags (against the depth drawn so far): one instance per box record draws the box's
// faces that face the eye, at most one per axis, two triangles each (18 vertices: vertex
// 6 * s + k is corner k of the slot-s face), corners made from the vertex index
// (render/box_oracle.rs). A slot whose two faces both face away (the eye between their planes)
// draws nothing; back faces are culled by the pipeline as well.

struct ObjectBox {
    vec4 lo; // xyz: minimum corner; w: the index of the word a passing fragment marks (bits)
    vec4 hi; // xyz: maximum corner; w: the gate's index (bits), NO_GATE for none
};

layout(std430, set = 0, binding = 0) readonly buffer Boxes {
    ObjectBox boxes[];
};

// Gates: a box whose record names one is drawn only where that word is non-zero (the box
// flags: a part's boxes under its node's flag, as a conditional block on it would draw them);
// otherwise its vertices leave the clip volume.
layout(std430, set = 0, binding = 2) readonly buffer Gates {
    uint gates[];
};
const uint NO_GATE = 0xffffffffu;

layout(push_constant) uniform Push {
    mat4 view_proj;
    // xyz: the eye, w = 1; an orthographic view: the direction toward the eye, w = 0.
    vec4 eye;
} pc;

layout(location = 0) flat out uint v_object;

// Corner (x | y << 1 | z << 2) of each of the 12 triangles of a box, counter-clockwise seen
// from outside, face by face (-z, +z, -y, +y, -x, +x): coherent-ash's BOX_FACES, so these
// boxes cover the pixels its query boxes do.
const uint CORNERS[36] = uint[36](
    0, 2, 1, 1, 2, 3, // -z
    4, 5, 6, 5, 7, 6, // +z
    0, 1, 4, 1, 5, 4, // -y
    2, 6, 3, 3, 6, 7, // +y
    0, 4, 2, 2, 4, 6, // -x
    1, 3, 5, 3, 7, 5  // +x
);

// A position outside the clip volume (beyond the far plane): the triangle is clipped away.
const vec4 OUTSIDE = vec4(0.0, 0.0, 2.0, 1.0);

void main() {
    ObjectBox b = boxes[gl_InstanceIndex];
    v_object = floatBitsToUint(b.lo.w);
    uint gate = floatBitsToUint(b.hi.w);
    if (gate != NO_GATE && gates[gate] == 0u) {
        gl_Position = OUTSIDE;
        return;
    }
    // Slot 0: the z faces, 1: y, 2: x.
    uint slot = uint(gl_VertexIndex) / 6u;
    int axis = 2 - int(slot);
    float e = pc.eye[axis];
    bool perspective = pc.eye.w != 0.0;
    bool below = perspective ? e < b.lo[axis] : e < 0.0;
    bool above = perspective ? e > b.hi[axis] : e > 0.0;
    if (!below && !above) {
        gl_Position = OUTSIDE;
        return;
    }
    uint face = 2u * slot + (above ? 1u : 0u);
    uint c = CORNERS[face * 6u + uint(gl_VertexIndex) % 6u];
    vec3 p = vec3((c & 1u) != 0u ? b.hi.x : b.lo.x,
                  (c & 2u) != 0u ? b.hi.y : b.lo.y,
                  (c & 4u) != 0u ? b.hi.z : b.lo.z);
    gl_Position = pc.view_proj * vec4(p, 1.0);
}
