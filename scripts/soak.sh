#!/usr/bin/env bash
# Soak: walks FRAMES frames (default 10000) of the city's street path (scale 0.1, 160x90, 40
# moving cars), each pose rendered by every culling algorithm that needs no preprocessing (vfc,
# stop-and-wait, chc, chcpp, oracle, nohc, hiz) and by chcpp in the predicated mode (one and
# two frames in flight) and the next-frame mode with two frames in flight, under strict
# validation (core, synchronization, best practices), and reports the validation messages
# (must be 0), RSS and the GPU allocator's usage at the start (after a 10-pose warm-up) and the
# end (must be flat within 1%). Release build of the test `reliability::soak_long` in
# tests/gpu/reliability.rs; the test suite runs 500 frames.
set -euo pipefail
cd "$(dirname "$0")/.."
export PATH="$HOME/.cargo/bin:$PATH"
export COHERENT_DEVICE="${COHERENT_DEVICE:-llvmpipe}"
export COHERENT_SOAK_FRAMES="${1:-10000}"
mkdir -p out
cargo test --release --test gpu reliability::soak_long -- --ignored --nocapture --test-threads 1 \
    2>&1 | tee out/soak.log | grep -E 'soak: |test result|panicked|FAILED'
