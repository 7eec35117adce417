#!/usr/bin/env bash
# Fuzz the protocol crate: every cargo-fuzz target of protocol/fuzz for FUZZ_SECONDS (default 60)
# seconds each. Works from any directory. Needs the nightly toolchain and cargo-fuzz; installs
# whichever is missing (cargo-fuzz from crates.io, nightly through rustup, minimal profile).
#
#   scripts/fuzz.sh                          # every target, FUZZ_SECONDS (default 60) s each
#   scripts/fuzz.sh --seconds 300            # every target, 300 s each
#   scripts/fuzz.sh --runs 1000000           # every target, 1 M executions each (no time limit)
#   scripts/fuzz.sh --long                   # the long run: 10 M executions of every target
#   scripts/fuzz.sh --long --target node     # one target (repeat --target for several)
#   scripts/fuzz.sh --long --target node --no-asan   # without AddressSanitizer: about 10x faster
#
# AddressSanitizer (cargo-fuzz's default) finds memory errors in unsafe code; the protocol crate
# forbids unsafe code, so for it ASan watches only its dependencies (heapless, core) and costs a
# factor of about ten on the `node` target (6,700 against 700 exec/s). `--no-asan` keeps what
# the targets check (panics, debug assertions and overflow checks, the targets' own rules) and
# drops ASan: for the long runs; the short runs in CI keep it.
#
# One libFuzzer process at a time (no -jobs/-workers). After each target it prints the
# executions done, the time, exec/s, the corpus size and whether it found a crash; a summary of
# every target ends the run. The exit status is non-zero if any target crashed (the other
# targets still run).
#
# Targets are built with debug assertions and overflow checks (-a), so an arithmetic overflow is
# a crash, as it is in the debug builds the crate's "never panics" promise covers.
# A crash leaves its input in protocol/fuzz/artifacts/<target>/; reproduce it with
#   cargo +nightly fuzz run -a <target> fuzz/artifacts/<target>/crash-...   (from protocol/)
set -euo pipefail

usage() {
    awk 'NR > 1 && !/^#/ { exit } NR > 1 { sub(/^# ?/, ""); print }' "$0"
}

seconds="${FUZZ_SECONDS:-60}"
no_asan=""
seconds_given=""
runs=""
chosen=()
while [ $# -gt 0 ]; do
    case "$1" in
        --seconds)
            seconds="${2:?--seconds needs a number}"
            seconds_given=1
            shift 2
            ;;
        --runs)
            runs="${2:?--runs needs a number}"
            shift 2
            ;;
        --long)
            runs=10000000
            shift
            ;;
        --no-asan)
            no_asan=1
            shift
            ;;
        --target)
            chosen+=("${2:?--target needs a name}")
            shift 2
            ;;
        -h | --help)
            usage
            exit 0
            ;;
        *)
            echo "fuzz.sh: unknown argument $1 (see --help)" >&2
            exit 2
            ;;
    esac
done
for n in "$seconds" "$runs"; do
    if [ -n "$n" ] && ! [[ "$n" =~ ^[0-9]+$ ]]; then
        echo "fuzz.sh: $n is not a whole number" >&2
        exit 2
    fi
done

cd "$(dirname "$0")/.."
sanitizer=()
if [ -n "$no_asan" ]; then
    sanitizer=(-s none)
fi

if ! rustup run nightly rustc --version >/dev/null 2>&1; then
    rustup toolchain install nightly --profile minimal
fi

if ! cargo fuzz --version >/dev/null 2>&1; then
    cargo install cargo-fuzz --locked
fi

cd protocol
all=$(cargo +nightly fuzz list)
if [ -z "$all" ]; then
    echo "fuzz.sh: no fuzz targets in protocol/fuzz" >&2
    exit 1
fi
if [ ${#chosen[@]} -eq 0 ]; then
    targets="$all"
else
    for t in "${chosen[@]}"; do
        if ! grep -qx -- "$t" <<<"$all"; then
            echo "fuzz.sh: no target $t; the targets are:" $all >&2
            exit 2
        fi
    done
    targets="${chosen[*]}"
fi

# The limit: a number of executions (no time limit unless --seconds is given too), or a time.
limits=(-print_final_stats=1)
if [ -n "$runs" ]; then
    limits+=(-runs="$runs")
    what="$runs executions"
    if [ -n "$seconds_given" ]; then
        limits+=(-max_total_time="$seconds")
        what="$what or ${seconds}s"
    fi
else
    limits+=(-max_total_time="$seconds")
    what="${seconds}s"
fi

# Build every chosen target first, so that the times below are fuzzing only.
for target in $targets; do
    cargo +nightly fuzz build -a "${sanitizer[@]}" "$target"
done

log_dir=$(mktemp -d)
trap 'rm -rf "$log_dir"' EXIT
summary=()
failed=0
for target in $targets; do
    echo "=== fuzzing $target for $what"
    corpus="fuzz/corpus/$target"
    mkdir -p "$corpus"
    # The checked-in seeds are read, never written: new inputs go to the (ignored) corpus.
    seeds=()
    if [ -d "fuzz/seeds/$target" ]; then
        seeds=("fuzz/seeds/$target")
    fi
    log="$log_dir/$target.log"
    start=$(date +%s)
    status=0
    cargo +nightly fuzz run -a "${sanitizer[@]}" "$target" "$corpus" "${seeds[@]}" -- "${limits[@]}" 2>&1 |
        tee "$log" || status=$?
    elapsed=$(($(date +%s) - start))
    # libFuzzer's final statistics (-print_final_stats=1) and its last status line.
    execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -n 1)
    rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -n 1)
    corp=$(grep -o 'corp: [0-9]*/[0-9a-zA-Z]*' "$log" | tail -n 1 | sed 's/corp: //')
    files=$(find "$corpus" -type f | wc -l)
    if [ "$status" -ne 0 ]; then
        artifact=$(sed -n 's/.*Test unit written to \(.*\)$/\1/p' "$log" | tail -n 1)
        crash="CRASH (exit $status${artifact:+, input $artifact})"
        failed=1
    else
        crash="no crash"
    fi
    line="$target: ${execs:-?} executions in ${elapsed}s, ${rate:-?} exec/s, corpus ${corp:-?} (entries/bytes in memory), $files files in $corpus, $crash"
    echo "=== $line"
    summary+=("$line")
done
echo "=== fuzzing done ($what per target):"
printf '  %s\n' "${summary[@]}"
exit "$failed"
