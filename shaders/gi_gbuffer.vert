#version 450
// G-buffer pass: world-space triangles pulled from a storage buffer (non-indexed draw).
struct GiVertex { vec4 position; vec4 normal; vec4 albedo; };
layout(std430, set = 0, binding = 0) readonly buffer Vertices { GiVertex verts[]; };

layout(push_constant) uniform Push {
    mat4 view_proj;
    vec4 eye;
    vec4 params;
} pc;

layout(location = 0) out vec3 v_position;
layout(location = 1) out vec3 v_normal;
layout(location = 2) out vec3 v_albedo;

void main() {
    GiVertex v = verts[gl_VertexIndex];
    gl_Position = pc.view_proj * vec4(v.position.xyz, 1.0);
    v_position = v.position.xyz;
    v_normal = v.normal.xyz;
    v_albedo = v.albedo.rgb;
}
