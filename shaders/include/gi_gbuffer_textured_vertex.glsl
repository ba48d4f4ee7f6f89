// The vertex stage of the textured G-buffer (gi_gbuffer_textured.vert and, with MASKED,
// gi_gbuffer_textured_masked.vert): gi_gbuffer.vert plus each vertex's texture data
// (coordinates, image, sampler bits, color without the texture) for
// include/gi_gbuffer_textured.glsl, and with MASKED its mask data as gi_gbuffer_masked.vert.
#include "include/gi_vertices.glsl"

#include "include/gi_raster_push.glsl"

// Per GPU vertex two vec4: (u, v, image or -1, sampler bits) and (color, 0).
layout(std430, set = 0, binding = 4) readonly buffer TextureVertices { vec4 tex_verts[]; };
#ifdef MASKED
// Per GPU vertex: u, v, alpha over cutoff, mask image (-1: none).
layout(std430, set = 0, binding = 2) readonly buffer MaskVertices { vec4 mask_verts[]; };
#endif

layout(location = 0) out vec3 v_position;
layout(location = 1) out vec3 v_normal;
layout(location = 2) out vec3 v_albedo;
layout(location = 3) out vec2 v_uv;
layout(location = 4) flat out int v_image;
layout(location = 5) flat out uint v_flags;
layout(location = 6) out vec3 v_color;
#ifdef MASKED
layout(location = 7) out vec3 v_mask;
layout(location = 8) flat out int v_mask_image;
#endif

void main() {
    GiVertex v = verts[gl_VertexIndex];
    gl_Position = pc.view_proj * vec4(v.position.xyz, 1.0);
    v_position = v.position.xyz;
    v_normal = v.normal.xyz;
    v_albedo = v.albedo.rgb;
    vec4 t = tex_verts[2 * gl_VertexIndex];
    v_uv = t.xy;
    v_image = int(t.z);
    v_flags = uint(t.w);
    v_color = tex_verts[2 * gl_VertexIndex + 1].rgb;
#ifdef MASKED
    vec4 m = mask_verts[gl_VertexIndex];
    v_mask = m.xyz;
    v_mask_image = int(m.w);
#endif
}
