#version 450
// Hi-Z depth pyramid, one level: each texel of dst is the farthest (max) depth of its 2x2 block
// in src (the depth buffer for level 0, the previous level otherwise). dst is half of src,
// rounded up, so at odd sizes the last block is clamped to the edge: no src texel is lost.
layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 0) uniform sampler2D src;
layout(set = 0, binding = 1, r32f) uniform writeonly image2D dst;

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 dsize = imageSize(dst);
    if (p.x >= dsize.x || p.y >= dsize.y) {
        return;
    }
    ivec2 last = textureSize(src, 0) - 1;
    ivec2 a = min(p * 2, last);
    ivec2 b = min(p * 2 + 1, last);
    float d = max(max(texelFetch(src, a, 0).r, texelFetch(src, ivec2(b.x, a.y), 0).r),
                  max(texelFetch(src, ivec2(a.x, b.y), 0).r, texelFetch(src, b, 0).r));
    imageStore(dst, p, vec4(d));
}
