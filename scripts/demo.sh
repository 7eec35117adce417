#!/usr/bin/env bash
# The gateway's job without hardware, on a fresh machine: the real firmware ELF (its emulator
# build) in QEMU with four simulated Robo Cylinder controllers on its bus and a scripted PLC on
# its Modbus line and discrete inputs (tests/demo/demo.py). Installs what it needs: QEMU (as the
# test command does), the pinned Rust toolchain, a Python venv with pymodbus.
#
#   scripts/demo.sh                     # 4 axes at 115.2 kbit/s, faults offline + alarm
#   scripts/demo.sh --axes 8 --baud 38400 --duration 20 --faults none
#   scripts/demo.sh --help              # every knob
#   scripts/demo.sh --host-gateway      # the same gateway code on the PC in virtual time, and the
#                                       # codec on the vendor documents' examples (no QEMU)
set -euo pipefail
cd "$(dirname "$0")/.."

if [[ ${1:-} == --host-gateway ]]; then
    exec scripts/demo-host.sh
fi

rustup toolchain install >/dev/null 2>&1 || rustup toolchain install
cargo build --quiet --locked -p rc-tools --bin rc-sim --bin rcframe
python=$(scripts/py-env.sh)
if [[ " $* " == *" --help "* || " $* " == *" -h "* ]]; then
    exec "$python" tests/demo/demo.py --elf - "$@"
fi
scripts/qemu-install.sh
elf=$(scripts/emu-build.sh)
export PYTHONDONTWRITEBYTECODE=1
exec timeout --kill-after=10 900 "$python" tests/demo/demo.py --elf "$elf" "$@"
