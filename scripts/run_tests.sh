#!/usr/bin/env bash
# Builds the test targets `cargo test` would run (the arguments are cargo's, e.g. `--workspace
# --all-targets`) and runs every test in a process of its own, as many at a time as there are
# cores (COHERENT_TEST_JOBS overrides). Ignored tests stay ignored.
#
# Why not `cargo test`'s threads: the Khronos validation layer of Debian 12 (1.3.239) keeps its
# per-instance and per-device data in one process-wide map that it changes, without a lock,
# when an instance or device is created or destroyed, and reads on every Vulkan call
# (KhronosGroup/Vulkan-ValidationLayers#4391). Each test makes its own validated device, so two
# tests in one process can crash inside the layer: a threaded run of the GPU tests did
# (2026-12-03), and so did, within a minute, a program whose one thread made and destroyed
# validated devices while another made buffers on its own. Processes share nothing.
set -euo pipefail
cd "$(dirname "$0")/.."

jobs="${COHERENT_TEST_JOBS:-$(nproc)}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

# Human-readable diagnostics on stderr, artifacts as JSON on stdout.
cargo test --no-run --message-format=json-render-diagnostics "$@" >"$work/artifacts.json"

# The test harnesses: each artifact built with the test profile that has an executable, with
# its package's directory (a test runs there, as under cargo).
grep '"reason":"compiler-artifact"' "$work/artifacts.json" |
    grep -E '"profile":\{[^}]*"test":true' |
    grep '"executable":"' |
    sed -E 's/.*"manifest_path":"([^"]*)".*"executable":"([^"]*)".*/\1\t\2/' >"$work/binaries"
if [ ! -s "$work/binaries" ]; then
    echo "run_tests: cargo built no test binary" >&2
    exit 1
fi

ignored=0
: >"$work/tests"
while IFS=$'\t' read -r manifest exe; do
    dir="$(dirname "$manifest")"
    (cd "$dir" && "$exe" --list --format terse) | sed -n 's/: test$//p' | sort >"$work/all"
    (cd "$dir" && "$exe" --list --format terse --ignored) | sed -n 's/: test$//p' | sort >"$work/skip"
    ignored=$((ignored + $(wc -l <"$work/skip")))
    comm -23 "$work/all" "$work/skip" | while read -r name; do
        printf '%s\t%s\t%s\n' "$dir" "$exe" "$name"
    done >>"$work/tests"
done <"$work/binaries"
total=$(wc -l <"$work/tests")
echo "run_tests: $total tests in $(wc -l <"$work/binaries") binaries, $jobs at a time, each in its own process ($ignored ignored)"

mkdir -p "$work/logs"
export WORK="$work"
run_one() {
    local dir exe name log start rc
    IFS=$'\t' read -r dir exe name <<<"$1"
    log="$(mktemp "$WORK/logs/XXXXXX")"
    start=$SECONDS
    rc=0
    (cd "$dir" && CARGO_MANIFEST_DIR="$dir" "$exe" --exact "$name" --test-threads=1) >"$log" 2>&1 || rc=$?
    if [ "$rc" -eq 0 ]; then
        echo "ok     $(basename "$exe") $name ($((SECONDS - start)) s)"
    else
        printf '%s\t%s\n' "$(basename "$exe")" "$name" >>"$WORK/failed"
        echo "FAILED $(basename "$exe") $name (exit status $rc, $((SECONDS - start)) s); its output:"
        sed 's/^/    /' "$log"
    fi
}
export -f run_one

start=$SECONDS
# Every line is one test; xargs keeps `jobs` processes going.
tr '\n' '\0' <"$work/tests" | xargs -0 -P "$jobs" -I{} bash -c 'run_one "$1"' _ {} || true

failed=0
[ -f "$work/failed" ] && failed=$(wc -l <"$work/failed")
echo "run_tests: $((total - failed)) passed, $failed failed, $ignored ignored in $((SECONDS - start)) s"
if [ "$failed" -gt 0 ]; then
    echo "failed:"
    sed 's/^/    /' "$work/failed"
    exit 1
fi
