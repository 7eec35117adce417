#!/usr/bin/env bash
# End-to-end: pymodbus (a real Modbus RTU master) drives rc-gateway-host (the firmware's engine and
# register map on the PC) through a pseudo-terminal, with simulated controllers behind it.
# Installs what it needs: the pinned Rust toolchain, and pymodbus + pyserial + pytest in a venv at
# target/e2e-venv (or `pip install --user` where venv is unavailable). Extra arguments go to
# pytest, e.g. `scripts/e2e.sh -k watchdog -v`.
set -euo pipefail
cd "$(dirname "$0")/.."

# Pinned: the tests' compatibility shim also knows the older keywords (`slave=`, `unit=`).
PYMODBUS_VERSION=3.16.1
PYSERIAL_VERSION=3.5
PYTEST_VERSION=8.4.2

rustup toolchain install >/dev/null
# rc-sim: the --bus side's test talks to it through a pseudo-terminal.
cargo build --locked -p rc-host --bin rc-gateway-host --bin rc-sim

venv=target/e2e-venv
has_pip() { [[ -x "$1" ]] && "$1" -m pip --version >/dev/null 2>&1; }
if ! has_pip "$venv/bin/python"; then
    rm -rf "$venv"
    python3 -m venv "$venv" >/dev/null 2>&1 || rm -rf "$venv"
fi
if has_pip "$venv/bin/python"; then
    python="$venv/bin/python"
    user=()
else
    echo "e2e: python3 -m venv failed (Debian: apt-get install python3-venv); using pip --user" >&2
    python=python3
    user=(--user)
fi

want=("pymodbus==$PYMODBUS_VERSION" "pyserial==$PYSERIAL_VERSION" "pytest==$PYTEST_VERSION")
if ! "$python" - "${want[@]}" <<'EOF'
import sys
from importlib.metadata import version, PackageNotFoundError
for spec in sys.argv[1:]:
    name, wanted = spec.split("==")
    try:
        if version(name) != wanted:
            sys.exit(1)
    except PackageNotFoundError:
        sys.exit(1)
EOF
then
    "$python" -m pip install --quiet --disable-pip-version-check ${user[@]+"${user[@]}"} "${want[@]}"
fi

export RC_GATEWAY_HOST="$PWD/target/debug/rc-gateway-host"
# Nothing written into the source tree (no __pycache__, no .pytest_cache).
export PYTHONDONTWRITEBYTECODE=1
# Bounded: each test waits at most tens of seconds; the whole run gets a hard limit too.
timeout --kill-after=10 600 "$python" -m pytest -q -p no:cacheprovider tests/e2e "$@"
