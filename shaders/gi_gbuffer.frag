#version 450
#extension GL_GOOGLE_include_directive : require
// G-buffer: world position (w = 1 where covered), normal facing the camera, albedo.
layout(location = 0) in vec3 v_position;
layout(location = 1) in vec3 v_normal;
layout(location = 2) in vec3 v_albedo;

#include "include/gi_raster_push.glsl"
#include "include/gi_gbuffer_out.glsl"

void main() {
    write_gbuffer(v_position, v_normal, v_albedo);
}
