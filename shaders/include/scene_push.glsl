// The push block of the forward pass (scene.vert, scene.frag) and the query boxes (box.vert).
layout(push_constant) uniform Push {
    mat4 view_proj;
    vec4 sun_dir;
} pc;
