#version 450
#extension GL_GOOGLE_include_directive : require
// G-buffer of a scene with base color textures and alpha masks: see
// include/gi_gbuffer_textured.glsl.
#define MASKED
#include "include/gi_gbuffer_textured.glsl"
