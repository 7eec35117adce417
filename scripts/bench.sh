#!/usr/bin/env bash
# Engine benchmark on the simulated bus, in virtual time: status cycle, PLC request latency, a
# dead axis and a moving axis' position age, each against the wire limit computed in the same
# run. Deterministic (identical figures every run). `--json` for one JSON object.
set -euo pipefail
cd "$(dirname "$0")/.."
rustup toolchain install >/dev/null
cargo run --release --locked -p rc-host --bin bench -- "$@"
