#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_shader_viewport_layer_array : require
// The indexed layered paraboloid shadow pass: the same projection and clipping as
// gi_shadow.vert, with the position read as a vertex attribute of an indexed draw (corners at the
// same position share a vertex, so the vertex stage runs once per vertex, not per corner).

#define SHADOW_CLIP_DISTANCE
#define SHADOW_VERTEX_INPUT
#include "include/gi_shadow_vertex.glsl"

void main() {
    shadow_vertex();
}
