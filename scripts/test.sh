#!/usr/bin/env bash
# The test command: formatting, lints, then every test under the Khronos validation layer on
# lavapipe (no GPU needed). Installs what it needs first.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export PATH="$HOME/.cargo/bin:$PATH"
# Use lavapipe unless the caller chose a device.
export COHERENT_DEVICE="${COHERENT_DEVICE:-llvmpipe}"
# A one-off build gains nothing from incremental compilation, whose caches take gigabytes.
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"
cargo fmt --all -- --check
cargo clippy --workspace --all-targets -- -D warnings
# The culling core's tests need no Vulkan driver at all.
VK_ICD_FILENAMES=/nonexistent cargo test -p coherent-cull
# Every test in a process of its own (the validation layer is not safe with devices made and
# used in several threads of one process: scripts/run_tests.sh says why).
bash scripts/run_tests.sh --workspace --all-targets
cargo test --workspace --doc
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --quiet
