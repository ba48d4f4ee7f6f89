// The G-buffer's outputs (gi_gbuffer.frag, gi_gbuffer_masked.frag): world position (w = 1 where
// covered), normal facing the camera (pc.eye), albedo.
layout(location = 0) out vec4 out_position;
layout(location = 1) out vec4 out_normal;
layout(location = 2) out vec4 out_albedo;

void write_gbuffer(vec3 position, vec3 normal, vec3 albedo) {
    vec3 n = normalize(normal);
    if (dot(n, pc.eye.xyz - position) < 0.0) {
        n = -n;
    }
    out_position = vec4(position, 1.0);
    out_normal = vec4(n, 0.0);
    out_albedo = vec4(albedo, 1.0);
}
