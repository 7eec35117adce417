#!/usr/bin/env bash
# Modbus TCP end to end (tests/tcp): pymodbus and raw-socket clients against
#   - rc-gateway-host --modbus-tcp (the node on the PC, simulated axes), and
#   - the firmware's network build in QEMU's mps2-an386 (rc-gateway-mps2: the node and the
#     Ethernet board's network task rc-net, over an emulated LAN9118),
# four clients at once, pipelined requests, a byte-a-second client beside a normal one, malformed
# MBAP headers, refused clients, the connection limit, the idle close, the watchdog fed over TCP.
#
#   scripts/tcp-test.sh [--target host|firmware|all] [PYTEST-ARGS...]
#
# Installs what it needs: qemu-system-arm (scripts/qemu-install.sh), the pinned Rust toolchain,
# pytest + pymodbus in the emulator venv (scripts/py-env.sh). Every wait is bounded.
set -euo pipefail
cd "$(dirname "$0")/.."

target=all
if [[ ${1:-} == --target ]]; then
    target=${2:?usage: $0 [--target host|firmware|all] [PYTEST-ARGS...]}
    shift 2
fi
rustup toolchain install >/dev/null 2>&1 || rustup toolchain install
cargo build --locked --quiet -p rc-tools --bin rc-gateway-host
if [[ $target != host ]]; then
    scripts/qemu-install.sh
    scripts/emu-net.sh build >/dev/null
fi
python=$(scripts/py-env.sh)
export PYTHONDONTWRITEBYTECODE=1
timeout --kill-after=10 900 "$python" -m pytest -q -p no:cacheprovider tests/tcp --target "$target" "$@"
