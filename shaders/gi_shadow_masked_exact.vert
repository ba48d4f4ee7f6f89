#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_shader_viewport_layer_array : require
// The exact variant of gi_shadow_masked.vert, for devices without shaderClipDistance.
// The layered paraboloid shadow maps of a scene with alpha masks (glTF MASK): the same vertex as
// gi_shadow.vert, plus each vertex's mask data (texture coordinates, alpha over the cutoff, and
// its triangle's mask image), interpolated at the vertex's place in its (clipped) triangle for
// gi_shadow_masked.frag.

#include "include/gi_shadow_vertex.glsl"

// Per GPU vertex: u, v, alpha over cutoff, mask image (-1: none).
layout(std430, set = 0, binding = 2) readonly buffer MaskVertices { vec4 mask_verts[]; };

layout(location = 0) out vec3 v_mask;
layout(location = 1) flat out int v_image;

void main() {
    vec3 w = shadow_vertex();
    int first = (gl_VertexIndex / 3) * 3;
    vec4 a = mask_verts[first];
    vec4 b = mask_verts[first + 1];
    vec4 c = mask_verts[first + 2];
    v_mask = a.xyz * w.x + b.xyz * w.y + c.xyz * w.z;
    v_image = int(a.w);
}
