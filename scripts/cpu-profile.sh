#!/usr/bin/env bash
# Where the firmware's CPU time goes: an exact instruction profile per function of the real
# firmware ELF in QEMU, under the load scripts/cpu-load.sh measures (tests/cpuload/profile.py
# says how). A development tool, not part of the tests. About a minute.
#
#   scripts/cpu-profile.sh                 # the 30 functions with the most instructions
#   scripts/cpu-profile.sh --top 60 --seconds 5
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/qemu-install.sh >&2
if ! command -v llvm-symbolizer >/dev/null || ! command -v llvm-nm >/dev/null; then
    sudo=()
    [[ $(id -u) == 0 ]] || sudo=(sudo)
    ${sudo[@]+"${sudo[@]}"} env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends llvm >&2
fi
rustup toolchain install >/dev/null 2>&1 || rustup toolchain install >&2
elf=$(scripts/emu-build.sh)
cargo build --locked --quiet -p rc-host --bin rc-sim >&2
python=$(scripts/py-env.sh)
export PYTHONDONTWRITEBYTECODE=1
exec timeout --kill-after=10 300 "$python" tests/cpuload/profile.py "$elf" "$@"
