// The resources of the GI compute passes (gi_gather.comp, gi_resolve.comp: one descriptor set
// layout and one push block for both) and their paraboloid shadow lookup.

layout(set = 0, binding = 0, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_normal;
layout(set = 0, binding = 2, rgba8) uniform readonly image2D g_albedo;
struct GpuVpl { vec4 position_layer; vec4 normal; vec4 flux; };
layout(std430, set = 0, binding = 3) readonly buffer Vpls { GpuVpl vpls[]; };
layout(set = 0, binding = 4) uniform sampler2DArray shadow_maps;
layout(set = 0, binding = 5, rgba32f) uniform image2D indirect;
layout(set = 0, binding = 6, rgba8) uniform writeonly image2D out_color;

layout(push_constant) uniform Push {
    vec4 spot_pos;   // xyz, w: spot layer
    vec4 spot_dir;   // xyz, w: far distance of the shadow maps
    vec4 spot_power; // rgb, w: output mode (0 full, 1 indirect only, 2 direct only)
    vec4 gather;     // x: first VPL, y: VPL count, z: accumulate, w: distance clamp
    vec4 misc;       // x: constant shadow bias, y: exposure, z: normal offset, w: blur plane threshold
} pc;

const float PI = 3.14159265;

#include "include/paraboloid.glsl"

// Paraboloid shadow lookup of offset d from a slot with normal n in `layer`. Bias: a constant
// (pc.misc.x) plus 2% of the distance, which grows like the paraboloid texel footprint (about
// 2 / resolution radians) and covers the straight-edge error of the non-linear projection.
float visibility(float layer, vec3 n, vec3 d) {
    vec3 t, b;
    basis(n, t, b);
    vec3 l = vec3(dot(d, t), dot(d, b), dot(d, n));
    float len = length(l);
    vec2 p = l.xy / max(len + l.z, 1e-9);
    vec2 uv = vec2(0.5 + 0.5 * p.x, 0.5 - 0.5 * p.y);
    float stored = textureLod(shadow_maps, vec3(uv, layer), 0.0).r * pc.spot_dir.w;
    return len - pc.misc.x - 0.02 * len <= stored ? 1.0 : 0.0;
}
