#version 450
#extension GL_GOOGLE_include_directive : require
// G-buffer: world position (w = 1 where covered), normal facing the camera, albedo.
layout(location = 0) in vec3 v_position;
layout(location = 1) in vec3 v_normal;
layout(location = 2) in vec3 v_albedo;

#include "include/gi_raster_push.glsl"

layout(location = 0) out vec4 out_position;
layout(location = 1) out vec4 out_normal;
layout(location = 2) out vec4 out_albedo;

void main() {
    vec3 n = normalize(v_normal);
    if (dot(n, pc.eye.xyz - v_position) < 0.0) {
        n = -n;
    }
    out_position = vec4(v_position, 1.0);
    out_normal = vec4(n, 0.0);
    out_albedo = vec4(v_albedo, 1.0);
}
