// Paraboloid (hemisphere) maps around a normal: the frame they are taken in. Shared by the
// shadow-map pass (gi_shadow.vert) and the lookups (gi_gather.comp, gi_resolve.comp), which must
// agree on it exactly.

// Duff et al. 2017 branchless orthonormal basis (t, b, n) around the unit vector n.
void basis(vec3 n, out vec3 t, out vec3 b) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float k = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * k, -s * n.x);
    b = vec3(k, s + n.y * n.y * a, -n.y);
}
