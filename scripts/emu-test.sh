#!/usr/bin/env bash
# The firmware in QEMU, end to end: installs what it needs (qemu-system-arm >= 10, the pinned
# Rust toolchain, pytest + pyelftools + pymodbus in a venv at target/emu-venv: scripts/py-env.sh),
# builds the emulator variant and the simulated controllers (rc-sim), and runs tests/emu/. Extra
# arguments go to pytest, e.g. `scripts/emu-test.sh -k break -v`.
# Each test's stack high-water mark is appended to target/emu/stack-hwm.log (scripts/size-report.sh
# reports the largest).
set -euo pipefail
cd "$(dirname "$0")/.."

scripts/qemu-install.sh
rustup toolchain install >/dev/null 2>&1 || rustup toolchain install
elf=$(scripts/emu-build.sh)
cargo build --locked --quiet -p rc-tools --bin rc-sim

python=$(scripts/py-env.sh)

export RC_GATEWAY_EMU_ELF="$elf"
export PYTHONDONTWRITEBYTECODE=1
mkdir -p target/emu
: > target/emu/stack-hwm.log
: > target/emu/stack-hwm-update.log
# Bounded: each test waits at most seconds; the whole run gets a hard limit too.
timeout --kill-after=10 900 "$python" -m pytest -q -p no:cacheprovider tests/emu "$@"
