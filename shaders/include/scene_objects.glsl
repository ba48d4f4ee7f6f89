// The forward pass's per-object data (src/render/upload.rs, object_data): a storage buffer
// indexed by the object (a draw's firstInstance), read by scene.vert, scene_mat.vert and the
// material fragment shaders.
struct ObjectData {
    mat4 model;
    mat4 normal_matrix;
    // The base color factor.
    vec4 color;
    // x: 1 when the material is unlit (KHR_materials_unlit), else 0; yzw unused.
    vec4 params;
};
layout(std430, set = 0, binding = 0) readonly buffer Objects { ObjectData objects[]; };
