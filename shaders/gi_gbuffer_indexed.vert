#version 450
#extension GL_GOOGLE_include_directive : require
// The indexed G-buffer pass: the same vertex as gi_gbuffer.vert, read as vertex attributes of an
// indexed draw (identical corners share an index, so each is shaded once per vertex cache).

#include "include/gi_raster_push.glsl"

layout(location = 0) in vec3 a_position;
layout(location = 1) in vec3 a_normal;
layout(location = 2) in vec3 a_albedo;

layout(location = 0) out vec3 v_position;
layout(location = 1) out vec3 v_normal;
layout(location = 2) out vec3 v_albedo;

void main() {
    gl_Position = pc.view_proj * vec4(a_position, 1.0);
    v_position = a_position;
    v_normal = a_normal;
    v_albedo = a_albedo;
}
