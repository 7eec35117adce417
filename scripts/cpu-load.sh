#!/usr/bin/env bash
# The gateway's CPU load on the MCU, measured on the real firmware ELF in QEMU with -icount
# (tests/cpuload/cpu_load.py says how and what it assumes). Installs what it needs as
# scripts/emu-test.sh does. About a minute.
#
#   scripts/cpu-load.sh            # one line
#   scripts/cpu-load.sh --json     # one JSON object (scripts/bench.sh reads cpu_load_percent)
#   scripts/cpu-load.sh --profile  # where it goes instead: scripts/cpu-profile.sh
set -euo pipefail
cd "$(dirname "$0")/.."
measure=tests/cpuload/cpu_load.py
if [[ ${1:-} == --profile ]]; then
    measure=tests/cpuload/profile.py
    shift
fi
scripts/qemu-install.sh >&2
rustup toolchain install >/dev/null 2>&1 || rustup toolchain install >&2
elf=$(scripts/emu-build.sh)
cargo build --locked --quiet -p rc-tools --bin rc-sim >&2
python=$(scripts/py-env.sh)
export PYTHONDONTWRITEBYTECODE=1
exec timeout --kill-after=10 300 "$python" "$measure" "$elf" "$@"
