#version 450
#extension GL_GOOGLE_include_directive : require
// G-buffer of a scene with alpha masks: gi_gbuffer.frag's outputs where the mask keeps the
// fragment (see include/gi_mask.glsl); masked-out texels are discarded, so the camera sees
// what is behind them.
layout(location = 0) in vec3 v_position;
layout(location = 1) in vec3 v_normal;
layout(location = 2) in vec3 v_albedo;
layout(location = 3) in vec3 v_mask;
layout(location = 4) flat in int v_image;

#include "include/gi_raster_push.glsl"
#include "include/gi_mask.glsl"
#include "include/gi_gbuffer_out.glsl"

void main() {
    if (!mask_keeps(v_mask, v_image)) {
        discard;
    }
    write_gbuffer(v_position, v_normal, v_albedo);
}
