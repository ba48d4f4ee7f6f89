#version 450
#extension GL_GOOGLE_include_directive : require
// Lambert as scene.frag over the material's color, with its alpha: blended over what is behind
// (glTF BLEND; the pipeline blends by source alpha and writes no depth).

#include "include/scene_material.glsl"

layout(location = 0) out vec4 out_color;

void main() {
    vec4 base = material_color();
    vec3 n = facing_normal();
    float lambert = max(dot(n, normalize(pc.sun_dir.xyz)), 0.0);
    float sky = 0.5 + 0.5 * n.y;
    vec3 c = base.rgb * (0.75 * lambert + 0.25 * sky + 0.05);
    out_color = vec4(pow(clamp(c, 0.0, 1.0), vec3(1.0 / 2.2)), clamp(base.a, 0.0, 1.0));
}
