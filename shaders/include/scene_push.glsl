// The push block of the forward pass (scene.vert, scene.frag); coherent-ash's query boxes
// (query_box.vert) read view_proj at offset 0 of it.
layout(push_constant) uniform Push {
    mat4 view_proj;
    vec4 sun_dir;
} pc;
