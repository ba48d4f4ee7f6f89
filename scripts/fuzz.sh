#!/usr/bin/env bash
# Fuzzes the glTF/GLB loader (fuzz/fuzz_targets/gltf_loader.rs) with cargo-fuzz for SECONDS
# (default 60), one job. Needs the nightly toolchain (`rustup toolchain install nightly`);
# installs cargo-fuzz if missing. The seed corpus is generated from the loader's test builders
# (tests/fuzz_regressions.rs, COHERENT_FUZZ_SEEDS) plus the regression inputs in
# tests/fuzz_corpus/. Crashes land in fuzz/artifacts/gltf_loader/; minimize one with
#   cargo +nightly fuzz tmin gltf_loader fuzz/artifacts/gltf_loader/crash-...
# and keep the result in tests/fuzz_corpus/ (tests/fuzz_regressions.rs replays every file there).
# CI never runs this: it stays on stable and does not build fuzz/.
set -euo pipefail
cd "$(dirname "$0")/.."
export PATH="$HOME/.cargo/bin:$PATH"
secs="${1:-60}"
if ! rustup toolchain list | grep -q '^nightly'; then
    echo "fuzz.sh: needs the nightly toolchain: rustup toolchain install nightly" >&2
    exit 1
fi
command -v cargo-fuzz >/dev/null || cargo install cargo-fuzz --locked
corpus=fuzz/corpus/gltf_loader
mkdir -p "$corpus"
COHERENT_FUZZ_SEEDS="$PWD/$corpus" cargo test --quiet --test fuzz_regressions seed_corpus_loads
cp tests/fuzz_corpus/* "$corpus/" 2>/dev/null || true
rm -f "$corpus/README.md"
cargo +nightly fuzz build gltf_loader
start=$(date +%s)
set +e
# FUZZ_KEEP_GOING=1: record crashes and go on (libFuzzer's fork mode, one job) instead of
# stopping at the first.
keep_going=()
[ "${FUZZ_KEEP_GOING:-0}" = 1 ] && keep_going=(-fork=1 -ignore_crashes=1)
cargo +nightly fuzz run gltf_loader "$corpus" -- "${keep_going[@]}" \
    -dict=fuzz/gltf.dict -max_total_time="$secs" -timeout=10 -rss_limit_mb=2048 \
    -print_final_stats=1 2>&1 | tee fuzz/last-run.log
status=${PIPESTATUS[0]}
set -e
echo "fuzz.sh: ran $(( $(date +%s) - start )) s, exit status $status"
grep -E '^stat::number_of_executed_units|^stat::peak_rss_mb|^#[0-9]+: cov' fuzz/last-run.log | tail -3 || true
ls fuzz/artifacts/gltf_loader 2>/dev/null | sed 's/^/fuzz.sh: artifact /' || true
exit "$status"
