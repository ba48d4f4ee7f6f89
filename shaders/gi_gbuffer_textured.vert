#version 450
#extension GL_GOOGLE_include_directive : require
// G-buffer pass of a scene with base color textures: see include/gi_gbuffer_textured_vertex.glsl.
#include "include/gi_gbuffer_textured_vertex.glsl"
