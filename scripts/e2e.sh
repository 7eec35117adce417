#!/usr/bin/env bash
# End-to-end: pymodbus (a real Modbus RTU master) drives rc-gateway-host (the firmware's engine and
# register map on the PC) through a pseudo-terminal, with simulated controllers behind it.
# Installs what it needs: the pinned Rust toolchain, and pymodbus + pyserial + pytest in a venv at
# target/e2e-venv (scripts/py-env.sh). Extra arguments go to
# pytest, e.g. `scripts/e2e.sh -k watchdog -v`.
set -euo pipefail
cd "$(dirname "$0")/.."

# Pinned: the tests' compatibility shim also knows the older keywords (`slave=`, `unit=`).
PYMODBUS_VERSION=3.16.1
PYSERIAL_VERSION=3.5
PYTEST_VERSION=8.4.2

rustup toolchain install >/dev/null
# rc-sim: the --bus side's test talks to it through a pseudo-terminal.
cargo build --locked -p rc-tools --bin rc-gateway-host --bin rc-sim

python=$(scripts/py-env.sh target/e2e-venv "pymodbus==$PYMODBUS_VERSION" "pyserial==$PYSERIAL_VERSION" \
    "pytest==$PYTEST_VERSION")

export RC_GATEWAY_HOST="$PWD/target/debug/rc-gateway-host"
# Nothing written into the source tree (no __pycache__, no .pytest_cache).
export PYTHONDONTWRITEBYTECODE=1
# Bounded: each test waits at most tens of seconds; the whole run gets a hard limit too.
timeout --kill-after=10 600 "$python" -m pytest -q -p no:cacheprovider tests/e2e "$@"
