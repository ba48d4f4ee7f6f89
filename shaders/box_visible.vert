#version 450
// The marking pass of the box oracle (`oracle-box`, against the exact ID pass's depth) and of
// the box flags (against the depth drawn so far): one instance per box record draws the 12
// triangles of the box, an indexed draw of its 8 corners (the index is the corner, x | y << 1 |
// z << 2; render/box_oracle.rs BOX_INDICES), so each corner is shaded once; the pipeline culls
// the back faces (render/box_oracle.rs).

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
} pc;

layout(location = 0) flat out uint v_object;

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
    uint c = uint(gl_VertexIndex);
    vec3 p = vec3((c & 1u) != 0u ? b.hi.x : b.lo.x,
                  (c & 2u) != 0u ? b.hi.y : b.lo.y,
                  (c & 4u) != 0u ? b.hi.z : b.lo.z);
    gl_Position = pc.view_proj * vec4(p, 1.0);
}
