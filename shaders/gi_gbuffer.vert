#version 450
#extension GL_GOOGLE_include_directive : require
// G-buffer pass: world-space triangles pulled from a storage buffer (non-indexed draw).
#include "include/gi_vertices.glsl"

#include "include/gi_raster_push.glsl"

layout(location = 0) out vec3 v_position;
layout(location = 1) out vec3 v_normal;
layout(location = 2) out vec3 v_albedo;

void main() {
    GiVertex v = verts[gl_VertexIndex];
    gl_Position = pc.view_proj * vec4(v.position.xyz, 1.0);
    v_position = v.position.xyz;
    v_normal = v.normal.xyz;
    v_albedo = v.albedo.rgb;
}
