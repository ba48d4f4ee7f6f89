#version 450
#extension GL_GOOGLE_include_directive : require
// Occlusion-query geometry: world-space box corners, no fragment shader, no color writes.
layout(location = 0) in vec3 in_position;

#include "include/scene_push.glsl"

void main() {
    gl_Position = pc.view_proj * vec4(in_position, 1.0);
}
