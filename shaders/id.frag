#version 450
// The oracle's ID pass: writes object index + 1 (0 is background).
layout(location = 2) flat in uint v_object;
layout(location = 0) out uint out_id;

void main() {
    out_id = v_object + 1u;
}
