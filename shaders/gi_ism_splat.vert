#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_shader_viewport_layer_array : require
// Imperfect shadow maps: every surface point is splatted into the paraboloid map of one VPL
// (point i belongs to slot i mod n), all maps in one layered pass (or in chunks of layers). A point is drawn as one small
// triangle (three vertices) that covers the texel it falls in, so no point-size state is needed.
// Depth is len / far as in gi_shadow.vert; points behind the VPL's hemisphere are dropped.

layout(std430, set = 0, binding = 0) readonly buffer Points { vec4 points[]; };
struct Slot { vec4 position_layer; vec4 normal; };
layout(std430, set = 0, binding = 1) readonly buffer Slots { Slot slots[]; };

#include "include/gi_raster_push.glsl"

#include "include/paraboloid.glsl"

// Corners of a triangle around a texel centre, in texels: it contains the circle of radius
// 0.58 texels, so the centre of the texel the point falls in is always covered.
const vec2 CORNERS[3] = vec2[3](vec2(-1.0, -0.58), vec2(1.0, -0.58), vec2(0.0, 1.16));

void main() {
    int point = gl_VertexIndex / 3;
    int corner = gl_VertexIndex - point * 3;
    int count = max(int(pc.eye.w), 1);
    Slot s = slots[int(pc.params.x) + point % count];
    // This rendering spans layers params.w .. params.w + eye.x of the array (chunks when the
    // array has more layers than maxFramebufferLayers): other layers' points are dropped.
    int layer = int(s.position_layer.w) - int(pc.params.w);
    if (layer < 0 || layer >= int(pc.eye.x)) {
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
        return;
    }
    gl_Layer = layer;
    vec3 n = normalize(s.normal.xyz);
    vec3 t, b;
    basis(n, t, b);
    vec3 d = points[point].xyz - s.position_layer.xyz;
    vec3 l = vec3(dot(d, t), dot(d, b), dot(d, n));
    float len = length(l);
    float far = pc.params.y;
    if (l.z < 1e-4 * far) {
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
        return;
    }
    vec2 p = l.xy / max(len + l.z, 1e-9);
    float texel = 2.0 / pc.params.z;
    gl_Position = vec4(p + CORNERS[corner] * texel, len / far, 1.0);
}
