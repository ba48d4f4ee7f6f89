#!/usr/bin/env bash
# The main job: a walkthrough of the built-in city comparing the culling algorithms side by side.
# Writes out/walk/{frames.csv,summary.json,frametime.png,counts.png}. Extra flags go to `walk`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export PATH="$HOME/.cargo/bin:$PATH"
export COHERENT_DEVICE="${COHERENT_DEVICE:-llvmpipe}"
cargo build --release --quiet
./target/release/coherent walk --scene city --path street --frames 300 --check --out out/walk "$@"
echo "report: out/walk/summary.json, out/walk/frames.csv; plots: out/walk/frametime.png, out/walk/counts.png"
