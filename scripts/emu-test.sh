#!/usr/bin/env bash
# The firmware in QEMU, end to end: installs what it needs (qemu-system-arm >= 10, the pinned
# Rust toolchain, pytest + pyelftools + pymodbus in a venv at target/emu-venv), builds the
# emulator variant and the simulated controllers (rc-sim), and runs tests/emu/. Extra arguments go to pytest, e.g. `scripts/emu-test.sh -k break -v`.
# Each test's stack high-water mark is appended to target/emu/stack-hwm.log (scripts/size-report.sh
# reports the largest).
set -euo pipefail
cd "$(dirname "$0")/.."

PYTEST_VERSION=8.4.2
PYELFTOOLS_VERSION=0.32
PYMODBUS_VERSION=3.16.1

scripts/qemu-install.sh
rustup toolchain install >/dev/null 2>&1 || rustup toolchain install
elf=$(scripts/emu-build.sh)
cargo build --locked --quiet -p rc-host --bin rc-sim

venv=target/emu-venv
has_pip() { [[ -x "$1" ]] && "$1" -m pip --version >/dev/null 2>&1; }
if ! has_pip "$venv/bin/python"; then
    rm -rf "$venv"
    python3 -m venv "$venv" >/dev/null 2>&1 || rm -rf "$venv"
fi
if has_pip "$venv/bin/python"; then
    python="$venv/bin/python"
    user=()
else
    echo "emu-test: python3 -m venv failed (Debian: apt-get install python3-venv); using pip --user" >&2
    python=python3
    user=(--user)
fi
want=("pytest==$PYTEST_VERSION" "pyelftools==$PYELFTOOLS_VERSION" "pymodbus==$PYMODBUS_VERSION")
if ! "$python" - "${want[@]}" <<'PY'
import sys
from importlib.metadata import version, PackageNotFoundError
for spec in sys.argv[1:]:
    name, wanted = spec.split("==")
    try:
        if version(name) != wanted:
            sys.exit(1)
    except PackageNotFoundError:
        sys.exit(1)
PY
then
    "$python" -m pip install --quiet --disable-pip-version-check ${user[@]+"${user[@]}"} "${want[@]}"
fi

export RC_GATEWAY_EMU_ELF="$elf"
export PYTHONDONTWRITEBYTECODE=1
mkdir -p target/emu
: > target/emu/stack-hwm.log
# Bounded: each test waits at most seconds; the whole run gets a hard limit too.
timeout --kill-after=10 900 "$python" -m pytest -q -p no:cacheprovider tests/emu "$@"
