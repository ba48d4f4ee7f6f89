#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_shader_viewport_layer_array : require
// The exact variant of gi_shadow.vert, for devices without shaderClipDistance.
// Layered paraboloid shadow maps (incremental instant radiosity): one instance per shadow slot
// (a VPL, or the spotlight), each writing its own layer of one 2D-array depth image via gl_Layer.
// Vertices are pulled from a storage buffer of world-space triangles (non-indexed draw), so each
// vertex can see its whole triangle and cull triangles entirely behind the hemisphere.
//
// Projection: in the slot's frame (tangent, bitangent, normal), a point at offset l with length
// len maps to p = l.xy / (len + l.z), the unit disk for the hemisphere l.z >= 0 (Brabec et al.'s
// paraboloid map); depth = len / far, linear in distance. The map is non-linear: the rasterizer
// interpolates straight edges and linear depth in paraboloid space, while the true images of long
// edges are curves. Scenes here are made of moderately sized triangles, so we accept the error and
// cover it with the depth bias of the lookup (`visibility` in include/gi_shading.glsl), rather
// than tessellating.
// Triangles entirely behind the base plane (l.z < 0) are culled; straddling ones are clipped to
// the plane in the shader (each vertex sees its whole triangle).

#include "include/gi_shadow_vertex.glsl"

void main() {
    shadow_vertex();
}
