#!/usr/bin/env bash
# Where the firmware's CPU time goes: an exact instruction profile per function of the real
# firmware ELF in QEMU, under the load scripts/cpu-load.sh measures (tests/cpuload/profile.py
# says how). A development tool, not part of the tests. About a minute.
#
#   scripts/cpu-profile.sh                 # the 30 functions with the most instructions
#   scripts/cpu-profile.sh --top 60 --seconds 5
set -euo pipefail
cd "$(dirname "$0")/.."
if ! command -v llvm-symbolizer >/dev/null || ! command -v llvm-nm >/dev/null; then
    sudo=()
    [[ $(id -u) == 0 ]] || sudo=(sudo)
    ${sudo[@]+"${sudo[@]}"} env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends llvm >&2
fi
exec scripts/cpu-load.sh --profile "$@"
