#!/usr/bin/env bash
# Engine benchmark on the simulated bus, in virtual time: status cycle, PLC request latency, a
# dead axis, a moving axis' position age and four moving axes, each against the wire limit
# computed in the same run. Deterministic (identical figures every run). After the table, one line
# `BENCH {...}`: the headline figures, their targets and whether each is met. `--json` for one
# JSON object with every row instead.
set -euo pipefail
cd "$(dirname "$0")/.."
rustup toolchain install >/dev/null
cargo run --release --locked -p rc-host --bin bench -- "$@"
