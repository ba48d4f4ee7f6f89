#version 450
// The box oracle's pass (`oracle-box`): one instance per candidate object draws the 12
// triangles of its bounding box, corners made from the vertex index, against the exact ID
// pass's depth (render/box_oracle.rs).

struct ObjectBox {
    vec4 lo; // xyz: minimum corner; w: the object's index (bits)
    vec4 hi; // xyz: maximum corner
};

layout(std430, set = 0, binding = 0) readonly buffer Boxes {
    ObjectBox boxes[];
};

layout(push_constant) uniform Push {
    mat4 view_proj;
} pc;

layout(location = 0) flat out uint v_object;

// Corner (x | y << 1 | z << 2) of each of the 12 triangles of a box, counter-clockwise seen
// from outside: coherent-ash's BOX_FACES, so these boxes cover the pixels its query boxes do.
const uint CORNERS[36] = uint[36](
    0, 2, 1, 1, 2, 3, // -z
    4, 5, 6, 5, 7, 6, // +z
    0, 1, 4, 1, 5, 4, // -y
    2, 6, 3, 3, 6, 7, // +y
    0, 4, 2, 2, 4, 6, // -x
    1, 3, 5, 3, 7, 5  // +x
);

void main() {
    ObjectBox b = boxes[gl_InstanceIndex];
    uint c = CORNERS[gl_VertexIndex];
    vec3 p = vec3((c & 1u) != 0u ? b.hi.x : b.lo.x,
                  (c & 2u) != 0u ? b.hi.y : b.lo.y,
                  (c & 4u) != 0u ? b.hi.z : b.lo.z);
    v_object = floatBitsToUint(b.lo.w);
    gl_Position = pc.view_proj * vec4(p, 1.0);
}
