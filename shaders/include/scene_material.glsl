// The material of scenes with textures (scene_mat*.frag, id_masked.frag): base color factor x
// vertex color (v_color) x base color texture (set 0, binding 1; sRGB, so it reads linear).
// With MASKED defined, fragments whose alpha is below the cutoff (push sun_dir.w) are discarded.
layout(location = 0) in vec3 v_normal;
layout(location = 1) in vec4 v_color;
layout(location = 2) flat in uint v_object;
layout(location = 3) in vec2 v_uv;

layout(set = 0, binding = 1) uniform sampler2D base_color;

#include "include/scene_push.glsl"

// The unit normal towards the viewer's side: flipped on back faces, which only the two-sided
// pipelines (glTF doubleSided) draw.
vec3 facing_normal() {
    vec3 n = normalize(v_normal);
    return gl_FrontFacing ? n : -n;
}

vec4 material_color() {
    vec4 c = v_color * texture(base_color, v_uv);
#ifdef MASKED
    if (c.a < pc.sun_dir.w) {
        discard;
    }
#endif
    return c;
}
