// The layered paraboloid shadow-map vertex (gi_shadow.vert, and gi_shadow_masked.vert for
// scenes with alpha masks); see gi_shadow.vert for the projection and its clipping.
#include "include/gi_vertices.glsl"
struct Slot { vec4 position_layer; vec4 normal; };
layout(std430, set = 0, binding = 1) readonly buffer Slots { Slot slots[]; };

#include "include/gi_raster_push.glsl"

#include "include/paraboloid.glsl"

#ifdef SHADOW_CLIP_DISTANCE
// The fast variant (devices with shaderClipDistance): each vertex reads only its own position and
// the fixed-function clipper cuts triangles at the base plane. The paraboloid division goes into
// w: clip position (l.x, l.y, depth * w, len + l.z), so x/w, y/w is the map position and z/w the
// linear depth len/far, exactly as in the exact variant for every vertex in front of the plane.
// gl_ClipDistance[0] = l.z - eps drops what lies behind it. Where an edge crosses the plane the
// clipper interpolates clip coordinates linearly, so the new corner's w is the interpolated len
// (at least the true distance, by the triangle inequality) and it lands slightly inside the rim
// instead of on it: only directions at grazing angles to the VPL's surface, whose light the
// cosine at the VPL scales to nearly zero, lose a sliver of occluder. w stays positive in front
// of the plane (len + l.z > 0 there), so the division never flips.
// Fetching one vertex instead of three and dropping the in-shader clipping is what makes the
// pass cheaper on lavapipe, whose single vertex thread is this pass's bottleneck.
out gl_PerVertex {
    vec4 gl_Position;
    float gl_ClipDistance[1];
};
#ifdef SHADOW_VERTEX_INPUT
// The indexed pass (gi_shadow_indexed.vert): the position arrives as an attribute.
layout(location = 0) in vec3 a_position;
#endif

vec3 shadow_vertex() {
    Slot s = slots[int(pc.params.x) + gl_InstanceIndex];
    gl_Layer = int(s.position_layer.w);
    vec3 n = normalize(s.normal.xyz);
    vec3 t, b;
    basis(n, t, b);
#ifdef SHADOW_VERTEX_INPUT
    vec3 d = a_position - s.position_layer.xyz;
#else
    vec3 d = verts[gl_VertexIndex].position.xyz - s.position_layer.xyz;
#endif
    vec3 l = vec3(dot(d, t), dot(d, b), dot(d, n));
    float far = pc.params.y;
    float len = length(l);
    float w = len + l.z;
    gl_Position = vec4(l.xy, (len / far) * w, w);
    // Same margin as the exact variant: triangles coplanar with the VPL's own surface go.
    gl_ClipDistance[0] = l.z - 1e-4 * far;
    int own = gl_VertexIndex - (gl_VertexIndex / 3) * 3;
    return vec3(own == 0, own == 1, own == 2);
}
#else
// Sets gl_Layer and gl_Position of vertex gl_VertexIndex of instance gl_InstanceIndex; returns
// the vertex's place as weights of its triangle's corners (for gi_shadow_masked.vert).
vec3 shadow_vertex() {
    Slot s = slots[int(pc.params.x) + gl_InstanceIndex];
    gl_Layer = int(s.position_layer.w);
    vec3 origin = s.position_layer.xyz;
    vec3 n = normalize(s.normal.xyz);
    vec3 t, b;
    basis(n, t, b);
    int tri = gl_VertexIndex / 3;
    int own = gl_VertexIndex - tri * 3;
    vec3 l[3];
    for (int i = 0; i < 3; i++) {
        vec3 d = verts[tri * 3 + i].position.xyz - origin;
        l[i] = vec3(dot(d, t), dot(d, b), dot(d, n));
    }
    float far = pc.params.y;
    // Triangles with no corner clearly in front of the base plane are culled. The margin also
    // drops triangles coplanar with the VPL's own surface, whose corners would otherwise land
    // on the rim and span the whole disk at a tiny depth.
    float eps = 1e-4 * far;
    if (l[0].z < eps && l[1].z < eps && l[2].z < eps) {
        // Degenerate and outside the clip volume: the whole triangle is dropped.
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
        return vec3(1.0, 0.0, 0.0);
    }
    vec3 p = l[own];
    vec3 own_w = vec3(own == 0, own == 1, own == 2);
    vec3 weights = own_w;
    if (p.z < eps) {
        // A corner behind the base plane slides along its edges onto the plane: exact when one
        // corner is in front (the clipped triangle), and the midpoint of the two crossings when
        // two are (the clipped quad loses two slivers; triangles are short, see geometry.rs).
        vec3 sum = vec3(0.0);
        vec3 sum_w = vec3(0.0);
        float count = 0.0;
        for (int i = 0; i < 3; i++) {
            if (i != own && l[i].z >= eps) {
                float f = (eps - p.z) / (l[i].z - p.z);
                sum += mix(p, l[i], f);
                sum_w += mix(own_w, vec3(i == 0, i == 1, i == 2), f);
                count += 1.0;
            }
        }
        p = count > 0.0 ? sum / count : vec3(p.xy, eps);
        weights = count > 0.0 ? sum_w / count : own_w;
    }
    float len = length(p);
    gl_Position = vec4(p.xy / max(len + p.z, 1e-9), len / far, 1.0);
    return weights;
}
#endif
