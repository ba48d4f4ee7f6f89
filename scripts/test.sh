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
cargo clippy --all-targets -- -D warnings
cargo test --all-targets
cargo test --doc
cargo doc --no-deps --quiet
