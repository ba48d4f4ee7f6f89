#version 450
#extension GL_GOOGLE_include_directive : require
// G-buffer pass of a scene with alpha masks: gi_gbuffer.vert plus each vertex's mask data
// (texture coordinates, alpha over the cutoff, its triangle's mask image) for
// gi_gbuffer_masked.frag.
#include "include/gi_vertices.glsl"

#include "include/gi_raster_push.glsl"

// Per GPU vertex: u, v, alpha over cutoff, mask image (-1: none).
layout(std430, set = 0, binding = 2) readonly buffer MaskVertices { vec4 mask_verts[]; };

layout(location = 0) out vec3 v_position;
layout(location = 1) out vec3 v_normal;
layout(location = 2) out vec3 v_albedo;
layout(location = 3) out vec3 v_mask;
layout(location = 4) flat out int v_image;

void main() {
    GiVertex v = verts[gl_VertexIndex];
    gl_Position = pc.view_proj * vec4(v.position.xyz, 1.0);
    v_position = v.position.xyz;
    v_normal = v.normal.xyz;
    v_albedo = v.albedo.rgb;
    vec4 m = mask_verts[gl_VertexIndex];
    v_mask = m.xyz;
    v_image = int(m.w);
}
