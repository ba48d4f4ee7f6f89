// The material of scenes with textures (scene_mat*.frag, id_masked.frag): base color factor x
// vertex color (v_color) x base color texture (set 0, binding 1; sRGB, so it reads linear).
// With MASKED defined, fragments whose alpha is below the cutoff (push sun_dir.w) are discarded.
layout(location = 0) in vec3 v_normal;
layout(location = 1) in vec4 v_color;
layout(location = 2) flat in uint v_object;
layout(location = 3) in vec2 v_uv;

layout(set = 0, binding = 1) uniform sampler2D base_color;

#include "include/scene_push.glsl"
#include "include/scene_objects.glsl"

// The unit normal towards the viewer's side: flipped on back faces, which only the two-sided
// pipelines (glTF doubleSided) draw.
vec3 facing_normal() {
    vec3 n = normalize(v_normal);
    return gl_FrontFacing ? n : -n;
}

// The color the forward pass shows for `base` on a side facing `n`: Lambert from the light
// towards sun_dir plus a sky term (as scene.frag), or `base` as it is for an unlit material;
// gamma 2.2.
vec3 shaded(vec3 base, vec3 n) {
    vec3 c = base;
    if (objects[v_object].params.x < 0.5) {
        float lambert = max(dot(n, normalize(pc.sun_dir.xyz)), 0.0);
        float sky = 0.5 + 0.5 * n.y;
        c = base * (0.75 * lambert + 0.25 * sky + 0.05);
    }
    return pow(clamp(c, 0.0, 1.0), vec3(1.0 / 2.2));
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
