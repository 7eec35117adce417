#!/usr/bin/env bash
# Fuzz the protocol crate: every cargo-fuzz target of protocol/fuzz for FUZZ_SECONDS (default 60)
# seconds each. Works from any directory. Needs the nightly toolchain and cargo-fuzz; installs
# whichever is missing (cargo-fuzz from crates.io, nightly through rustup, minimal profile).
#
# Targets are built with debug assertions and overflow checks (-a), so an arithmetic overflow is
# a crash, as it is in the debug builds the crate's "never panics" promise covers.
# A crash leaves its input in protocol/fuzz/artifacts/<target>/; reproduce it with
#   cargo +nightly fuzz run -a <target> protocol/fuzz/artifacts/<target>/crash-...   (from protocol/)
set -euo pipefail

cd "$(dirname "$0")/.."

seconds="${FUZZ_SECONDS:-60}"

if ! rustup run nightly rustc --version >/dev/null 2>&1; then
    rustup toolchain install nightly --profile minimal
fi

if ! cargo fuzz --version >/dev/null 2>&1; then
    cargo install cargo-fuzz --locked
fi

cd protocol
targets=$(cargo +nightly fuzz list)
if [ -z "$targets" ]; then
    echo "fuzz.sh: no fuzz targets in protocol/fuzz" >&2
    exit 1
fi

for target in $targets; do
    echo "=== fuzzing $target for ${seconds}s"
    corpus="fuzz/corpus/$target"
    mkdir -p "$corpus"
    # The checked-in seeds are read, never written: new inputs go to the (ignored) corpus.
    seeds=()
    if [ -d "fuzz/seeds/$target" ]; then
        seeds=("fuzz/seeds/$target")
    fi
    cargo +nightly fuzz run -a "$target" "$corpus" "${seeds[@]}" -- -max_total_time="$seconds"
done
echo "=== fuzzing done: $targets"
