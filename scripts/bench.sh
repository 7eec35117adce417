#!/usr/bin/env bash
# Engine benchmark on the simulated bus, in virtual time: status cycle, PLC request latency, a
# dead axis, a moving axis' position age and four moving axes, each against the wire limit
# computed in the same run. Deterministic (identical figures every run). After the table, one line
# `BENCH {...}`: the headline figures, their targets and whether each is met, with the firmware's
# CPU load measured on its ELF in QEMU (scripts/cpu-load.sh, about a minute; BENCH_CPU=0 skips
# it, and the figure is then null). `--json` for one JSON object with every row instead.
set -euo pipefail
cd "$(dirname "$0")/.."
rustup toolchain install >/dev/null
cpu=()
if [[ ${BENCH_CPU:-1} != 0 ]]; then
    if detail=$(scripts/cpu-load.sh --json 2>target/cpu-load.log); then
        percent=$(sed -n 's/.*"cpu_load_percent": \([0-9.]*\).*/\1/p' <<<"$detail")
        cpu=(--cpu-load-percent "$percent" --cpu-load-detail "$detail")
    else
        echo "bench: scripts/cpu-load.sh failed (target/cpu-load.log); cpu_load_percent is null" >&2
    fi
fi
cargo run --release --locked -p rc-host --bin bench -- ${cpu[@]+"${cpu[@]}"} "$@"
