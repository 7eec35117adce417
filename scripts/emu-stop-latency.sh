#!/usr/bin/env bash
# Stop latency on the real firmware ELF in QEMU, as information (issue 33 item 6): each face of a
# stop (stop input, *STP, DRG1 STP, STOP coil, broadcast) -> the axis' `d` read by rc-sim, with 16
# simulated axes at 115.2 kbit/s and 4 moving; tests/emu/stop_latency.py says how it measures.
# Installs what it needs as scripts/emu-test.sh does. Not run by CI: QEMU's timing is the host's.
#
#   scripts/emu-stop-latency.sh              # 8 stops a face
#   scripts/emu-stop-latency.sh --repeats 3 --json
set -euo pipefail
cd "$(dirname "$0")/.."

scripts/qemu-install.sh
rustup toolchain install >/dev/null 2>&1 || rustup toolchain install
elf=$(scripts/emu-build.sh)
cargo build --locked --quiet -p rc-tools --bin rc-sim
python=$(scripts/py-env.sh)
export PYTHONDONTWRITEBYTECODE=1
timeout --kill-after=10 1200 "$python" tests/emu/stop_latency.py "$elf" "$@"
