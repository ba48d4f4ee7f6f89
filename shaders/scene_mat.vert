#version 450
#extension GL_GOOGLE_include_directive : require
// Forward pass for scenes with materials: as scene.vert, plus texture coordinates and a vertex
// color (multiplied into the object's base color factor).
layout(location = 0) in vec3 in_position;
layout(location = 1) in vec3 in_normal;
layout(location = 2) in vec2 in_uv;
layout(location = 3) in vec4 in_color;

#include "include/scene_objects.glsl"

#include "include/scene_push.glsl"

layout(location = 0) out vec3 v_normal;
layout(location = 1) out vec4 v_color;
layout(location = 2) flat out uint v_object;
layout(location = 3) out vec2 v_uv;

void main() {
    ObjectData o = objects[gl_InstanceIndex];
    vec4 world = o.model * vec4(in_position, 1.0);
    gl_Position = pc.view_proj * world;
    v_normal = mat3(o.normal_matrix) * in_normal;
    v_color = o.color * in_color;
    v_object = uint(gl_InstanceIndex);
    v_uv = in_uv;
}
