#version 450
// Hi-Z depth pyramid, one level: each texel of dst is the farthest (max) depth of its 2x2 block
// in src (the depth buffer for level 0, the previous level otherwise). dst's valid region is
// half of src's, rounded up, so at odd sizes the last block is clamped to the edge: no src
// texel is lost, and padding texels are never read.
layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 0) uniform sampler2D src;
layout(set = 0, binding = 1, r32f) uniform writeonly image2D dst;
// Valid regions (texels) of src and dst: the image is padded to powers of two.
layout(push_constant) uniform Push {
    ivec2 src_valid;
    ivec2 dst_valid;
} pc;

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (p.x >= pc.dst_valid.x || p.y >= pc.dst_valid.y) {
        return;
    }
    ivec2 last = pc.src_valid - 1;
    ivec2 a = min(p * 2, last);
    ivec2 b = min(p * 2 + 1, last);
    float d = max(max(texelFetch(src, a, 0).r, texelFetch(src, ivec2(b.x, a.y), 0).r),
                  max(texelFetch(src, ivec2(a.x, b.y), 0).r, texelFetch(src, b, 0).r));
    imageStore(dst, p, vec4(d));
}
