#version 450
#extension GL_GOOGLE_include_directive : require
// Alpha masks in the GI shadow maps: masked-out texels are discarded, so they cast no shadow
// (see include/gi_mask.glsl).

layout(location = 0) in vec3 v_mask;
layout(location = 1) flat in int v_image;

#include "include/gi_mask.glsl"

void main() {
    if (!mask_keeps(v_mask, v_image)) {
        discard;
    }
}
