// The push block of the GI raster passes (G-buffer and shadow maps share it).
layout(push_constant) uniform Push {
    mat4 view_proj; // G-buffer: the camera
    vec4 eye;       // G-buffer: xyz the camera position
    vec4 params;    // shadow maps: x first slot of this draw, y far distance
} pc;
