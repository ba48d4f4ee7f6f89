#version 450
// coherent-ash's occlusion-query geometry: world-space box corners (8 per box, indexed), depth
// test only: no fragment shader, no color or depth writes. Its SPIR-V is shipped inside
// crates/coherent-ash/spirv/ (a test of the root package fails when it is stale).
layout(location = 0) in vec3 in_position;

layout(push_constant) uniform QueryPush {
    mat4 view_proj;
} pc;

void main() {
    gl_Position = pc.view_proj * vec4(in_position, 1.0);
}
