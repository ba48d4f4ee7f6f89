#version 450
#extension GL_GOOGLE_include_directive : require
// The material's color, shaded (lit as scene.frag, or unlit).

#include "include/scene_material.glsl"

layout(location = 0) out vec4 out_color;

void main() {
    vec4 base = material_color();
    out_color = vec4(shaded(base.rgb, facing_normal()), 1.0);
}
