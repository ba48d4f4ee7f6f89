#version 450
#extension GL_GOOGLE_include_directive : require
// The ID pass for alpha-masked materials: the same discard as scene_mat_masked.frag, then the
// object index + 1.
#define MASKED
#include "include/scene_material.glsl"

layout(location = 0) out uint out_id;

void main() {
    material_color();
    out_id = v_object + 1u;
}
