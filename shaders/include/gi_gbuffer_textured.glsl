// The fragment stage of the textured G-buffer (gi_gbuffer_textured.frag and, with MASKED,
// gi_gbuffer_textured_masked.frag): a textured triangle's albedo is its color without the
// texture times the texture at the fragment (include/gi_texture.glsl); an untextured one keeps
// its albedo. With MASKED, masked-out texels are discarded first (include/gi_mask.glsl).
layout(location = 0) in vec3 v_position;
layout(location = 1) in vec3 v_normal;
layout(location = 2) in vec3 v_albedo;
layout(location = 3) in vec2 v_uv;
layout(location = 4) flat in int v_image;
layout(location = 5) flat in uint v_flags;
layout(location = 6) in vec3 v_color;
#ifdef MASKED
layout(location = 7) in vec3 v_mask;
layout(location = 8) flat in int v_mask_image;
#endif

#include "include/gi_raster_push.glsl"
#include "include/gi_texture.glsl"
#ifdef MASKED
#include "include/gi_mask.glsl"
#endif
#include "include/gi_gbuffer_out.glsl"

void main() {
    // Derivatives before any discard, while the whole quad runs.
    vec2 uv_dx = dFdx(v_uv);
    vec2 uv_dy = dFdy(v_uv);
#ifdef MASKED
    if (!mask_keeps(v_mask, v_mask_image)) {
        discard;
    }
#endif
    vec3 albedo = v_albedo;
    if (v_image >= 0) {
        albedo = v_color * texture_albedo(v_image, v_uv, v_flags, uv_dx, uv_dy);
    }
    write_gbuffer(v_position, v_normal, albedo);
}
