#!/usr/bin/env bash
# Prints the path of a Python interpreter with the emulator harness' packages (pytest, pyelftools,
# pymodbus at pinned versions): a virtual environment at target/emu-venv, created and filled on
# first use; `pip --user` where python3-venv is missing. Used by scripts/emu-test.sh and
# scripts/demo.sh. Progress and warnings go to standard error.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTEST_VERSION=8.4.2
PYELFTOOLS_VERSION=0.32
PYMODBUS_VERSION=3.16.1

venv=target/emu-venv
has_pip() { [[ -x "$1" ]] && "$1" -m pip --version >/dev/null 2>&1; }
if ! has_pip "$venv/bin/python"; then
    rm -rf "$venv"
    python3 -m venv "$venv" >/dev/null 2>&1 || rm -rf "$venv"
fi
if has_pip "$venv/bin/python"; then
    python="$PWD/$venv/bin/python"
    user=()
else
    echo "py-env: python3 -m venv failed (Debian: apt-get install python3-venv); using pip --user" >&2
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
    "$python" -m pip install --quiet --disable-pip-version-check ${user[@]+"${user[@]}"} "${want[@]}" >&2
fi
echo "$python"
