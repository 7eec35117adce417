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
cpu_doc_stale=0
if [[ ${BENCH_CPU:-1} != 0 ]]; then
    # --doc: docs/performance.md's instructions per transaction must be the measured ones (3 %):
    # status 3 when they are not, with the line to paste.
    status=0
    detail=$(scripts/cpu-load.sh --json --doc docs/performance.md 2>target/cpu-load.log) || status=$?
    if [[ $status == 0 || $status == 3 ]]; then
        percent=$(sed -n 's/.*"cpu_load_percent": \([0-9.]*\).*/\1/p' <<<"$detail")
        cpu=(--cpu-load-percent "$percent" --cpu-load-detail "$detail")
    else
        echo "bench: scripts/cpu-load.sh failed (target/cpu-load.log); cpu_load_percent is null" >&2
    fi
    if [[ $status == 3 ]]; then
        grep "cpu-load:" target/cpu-load.log >&2
        cpu_doc_stale=1
    fi
fi
cargo run --release --locked -p rc-host --bin bench -- ${cpu[@]+"${cpu[@]}"} "$@"

# The same targets in real time (issue 34): rc-gateway-host against rc-sim over pseudo-terminals
# with no wire time (a frame arrives whole when written, as through a USB adapter), 16 axes, four
# moving in rounds whose ends come together, a Modbus RTU master polling PEND; direct moves and
# moves to points, the controllers answering at RTIM 3 ms and 7 ms; measured from rc-sim's event
# log against the run's own mean transaction time (`tests/src/bin/rt-bench`). About 2 minutes
# (RT_BENCH_SECONDS per run, 20 by default); BENCH_RT=0 skips it. One line `BENCH_RT {...}`.
if [[ ${BENCH_RT:-1} != 0 ]]; then
    cargo build --release --locked --quiet -p rc-host -p rc-tools --bin rt-bench --bin rc-sim --bin rc-gateway-host
    "${CARGO_TARGET_DIR:-target}/release/rt-bench" --seconds "${RT_BENCH_SECONDS:-20}"
fi

# Modbus TCP, in real time (not virtual): request -> reply latency over loopback with 4 clients,
# p50/p99 and requests per second, against rc-gateway-host (target: p99 <= 1 ms for cached
# reads); then the same against the network firmware in QEMU's mps2-an386 when QEMU is there
# (an emulator's figure: slirp and TCG in the path, not the Ethernet board's), BENCH_NET_EMU=0
# skips it.
cargo build --release --locked --quiet -p rc-host -p rc-tools --bin tcp-bench --bin rc-gateway-host
"${CARGO_TARGET_DIR:-target}/release/tcp-bench"
if [[ ${BENCH_NET_EMU:-1} != 0 ]] && command -v qemu-system-arm >/dev/null; then
    net_elf=$(scripts/emu-net.sh build 2>/dev/null)
    port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
    log=$(mktemp)
    qemu-system-arm -M mps2-an386 -nographic -monitor none -serial null -icount shift=auto \
        -semihosting-config enable=on,target=native \
        -nic "user,hostfwd=tcp:127.0.0.1:$port-:502" -kernel "$net_elf" >"$log" 2>&1 </dev/null &
    qemu=$!
    for _ in $(seq 300); do grep -q '^ready' "$log" && break; sleep 0.2; done
    "${CARGO_TARGET_DIR:-target}/release/tcp-bench" --addr "127.0.0.1:$port" --axes false --requests 2000 ||
        echo "bench: the network firmware in QEMU did not answer ($log)" >&2
    kill "$qemu" 2>/dev/null || true
    wait "$qemu" 2>/dev/null || true
fi

# A firmware update's transfer (issue 37): a full-size image into rc-gateway-host's board model
# over TCP and over an RTU pseudo-terminal, per board, and the 115.2 kbit/s RTU time computed from
# its frames (scripts/update-bench.sh, about a minute). BENCH_UPDATE=0 skips it.
if [[ ${BENCH_UPDATE:-1} != 0 ]]; then
    scripts/update-bench.sh
fi
if [[ $cpu_doc_stale == 1 ]]; then
    echo "bench: docs/performance.md's CPU figure is stale (above: the line to paste between its cpu markers)" >&2
    exit 1
fi
