#version 450
// Imperfect shadow maps, hole filling by pull-push (one workgroup per map, the pyramid in shared
// memory): pull averages the covered texels (depth < 1) into coarser levels with a weight
// min(1, sum of child weights); push fills each texel from its parent level in proportion to
// what it lacks: v = w v + (1 - w) v_parent. Texels still empty at the top stay at depth 1.
layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 0) uniform sampler2DArray splats;
layout(set = 0, binding = 1, r32f) uniform writeonly image2DArray maps;

// Levels of a 32x32 pyramid: 32, 16, 8, 4, 2, 1 texels wide, stored one after another.
const int MAX_SIZE = 32;
const int TOTAL = 1365;
shared float value[TOTAL];
shared float weight[TOTAL];

int level_offset(int level) {
    int offset = 0;
    int size = MAX_SIZE;
    for (int l = 0; l < level; l++) {
        offset += size * size;
        size /= 2;
    }
    return offset;
}

void main() {
    int layer = int(gl_WorkGroupID.x);
    int size = textureSize(splats, 0).x;
    int levels = findMSB(size) + 1;
    int lid = int(gl_LocalInvocationIndex);
    int threads = 64;
    // Level 0 from the splats.
    for (int i = lid; i < size * size; i += threads) {
        ivec2 t = ivec2(i % size, i / size);
        float d = texelFetch(splats, ivec3(t, layer), 0).r;
        bool covered = d < 1.0;
        value[i] = covered ? d : 0.0;
        weight[i] = covered ? 1.0 : 0.0;
    }
    barrier();
    // Pull.
    for (int l = 1; l < levels; l++) {
        int s = size >> l;
        int child = level_offset(l - 1);
        int own = level_offset(l);
        for (int i = lid; i < s * s; i += threads) {
            ivec2 t = ivec2(i % s, i / s);
            float sw = 0.0;
            float sv = 0.0;
            for (int k = 0; k < 4; k++) {
                ivec2 c = 2 * t + ivec2(k & 1, k >> 1);
                int ci = child + c.y * (2 * s) + c.x;
                sw += weight[ci];
                sv += weight[ci] * value[ci];
            }
            value[own + i] = sw > 0.0 ? sv / sw : 0.0;
            weight[own + i] = min(sw, 1.0);
        }
        barrier();
    }
    // Push.
    for (int l = levels - 2; l >= 0; l--) {
        int s = size >> l;
        int own = level_offset(l);
        int parent = level_offset(l + 1);
        for (int i = lid; i < s * s; i += threads) {
            ivec2 t = ivec2(i % s, i / s);
            int pi = parent + (t.y / 2) * (s / 2) + t.x / 2;
            float w = weight[own + i];
            float pw = weight[pi];
            value[own + i] = w * value[own + i] + (1.0 - w) * value[pi];
            weight[own + i] = w + (1.0 - w) * pw;
        }
        barrier();
    }
    for (int i = lid; i < size * size; i += threads) {
        ivec2 t = ivec2(i % size, i / size);
        float d = weight[i] > 0.0 ? value[i] : 1.0;
        imageStore(maps, ivec3(t, layer), vec4(d));
    }
}
