#version 450
// Occlusion-query geometry: world-space box corners, no fragment shader, no color writes.
layout(location = 0) in vec3 in_position;

layout(push_constant) uniform Push {
    mat4 view_proj;
    vec4 sun_dir;
} pc;

void main() {
    gl_Position = pc.view_proj * vec4(in_position, 1.0);
}
