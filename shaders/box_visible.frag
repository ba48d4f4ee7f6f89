#version 450
// The box oracle's pass: a box fragment that passed the depth test (early, before this
// shader runs) marks its object visible. Writes no color.
layout(early_fragment_tests) in;

layout(location = 0) flat in uint v_object;

layout(std430, set = 0, binding = 1) buffer Visible {
    uint visible[];
};

void main() {
    visible[v_object] = 1u;
}
