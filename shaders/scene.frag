#version 450
#extension GL_GOOGLE_include_directive : require
// Lambert from one directional light plus ambient, per-object base color, gamma 2.2 output.
layout(location = 0) in vec3 v_normal;
layout(location = 1) in vec4 v_color;
layout(location = 2) flat in uint v_object;

#include "include/scene_push.glsl"

layout(location = 0) out vec4 out_color;

void main() {
    vec3 n = normalize(v_normal);
    float lambert = max(dot(n, normalize(pc.sun_dir.xyz)), 0.0);
    float sky = 0.5 + 0.5 * n.y;
    vec3 c = v_color.rgb * (0.75 * lambert + 0.25 * sky + 0.05);
    out_color = vec4(pow(clamp(c, 0.0, 1.0), vec3(1.0 / 2.2)), 1.0);
}
