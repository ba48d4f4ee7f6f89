#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_shader_viewport_layer_array : require
// Layered paraboloid shadow maps (incremental instant radiosity): one instance per shadow slot
// (a VPL, or the spotlight), each writing its own layer of one 2D-array depth image via gl_Layer.
// Vertices are pulled from a storage buffer of world-space triangles (non-indexed draw), so each
// vertex can see its whole triangle and cull triangles entirely behind the hemisphere.
//
// Projection: in the slot's frame (tangent, bitangent, normal), a point at offset l with length
// len maps to p = l.xy / (len + l.z), the unit disk for the hemisphere l.z >= 0 (Brabec et al.'s
// paraboloid map); depth = len / far, linear in distance. The map is non-linear: the rasterizer
// interpolates straight edges and linear depth in paraboloid space, while the true images of long
// edges are curves. Scenes here are made of moderately sized triangles, so we accept the error and
// cover it with the depth bias of the lookup (`visibility` in include/gi_shading.glsl), rather
// than tessellating.
// Triangles entirely behind the base plane (l.z < 0) are culled; straddling ones are clipped to
// the plane in the shader (each vertex sees its whole triangle).

#include "include/gi_vertices.glsl"
struct Slot { vec4 position_layer; vec4 normal; };
layout(std430, set = 0, binding = 1) readonly buffer Slots { Slot slots[]; };

#include "include/gi_raster_push.glsl"

#include "include/paraboloid.glsl"

void main() {
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
        return;
    }
    vec3 p = l[own];
    if (p.z < eps) {
        // A corner behind the base plane slides along its edges onto the plane: exact when one
        // corner is in front (the clipped triangle), and the midpoint of the two crossings when
        // two are (the clipped quad loses two slivers; triangles are short, see geometry.rs).
        vec3 sum = vec3(0.0);
        float count = 0.0;
        for (int i = 0; i < 3; i++) {
            if (i != own && l[i].z >= eps) {
                float f = (eps - p.z) / (l[i].z - p.z);
                sum += mix(p, l[i], f);
                count += 1.0;
            }
        }
        p = count > 0.0 ? sum / count : vec3(p.xy, eps);
    }
    float len = length(p);
    gl_Position = vec4(p.xy / max(len + p.z, 1e-9), len / far, 1.0);
}
