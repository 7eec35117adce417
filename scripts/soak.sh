#!/usr/bin/env bash
# A soak of the real firmware in QEMU: a seeded random PLC (moves, stops, table writes,
# synchronized starts, broadcasts) against 4 simulated axes with bus faults (dropped, corrupted
# and late replies, noise, an axis that goes silent and comes back), checked by an oracle against
# the simulator (tests/emu/soak.py says what it checks). Installs what it needs as
# scripts/emu-test.sh does. Exit status 1 on any violation, with the seed to rerun it.
#
#   scripts/soak.sh                      # 20 minutes, a random seed
#   scripts/soak.sh --minutes 1 --seed 24 # what CI runs, for seeds 24, 5577 and 31337
#                                         # (scripts/test-all.sh)
set -euo pipefail
cd "$(dirname "$0")/.."

scripts/qemu-install.sh
rustup toolchain install >/dev/null 2>&1 || rustup toolchain install
elf=$(scripts/emu-build.sh)
cargo build --locked --quiet -p rc-tools --bin rc-sim
python=$(scripts/py-env.sh)

export PYTHONDONTWRITEBYTECODE=1
minutes=20
for ((i = 1; i <= $#; i++)); do
    if [[ ${!i} == --minutes ]]; then j=$((i + 1)); minutes=${!j}; fi
done
# Bounded: the run, its settling and the start-up, with a margin.
limit=$(python3 -c "import sys; print(int(float(sys.argv[1]) * 60 + 300))" "$minutes")
timeout --kill-after=10 "$limit" "$python" tests/emu/soak.py "$elf" "$@"
