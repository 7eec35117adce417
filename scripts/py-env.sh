#!/usr/bin/env bash
# Prints the path of a Python interpreter with pinned packages in a virtual environment, created
# and filled on first use (`pip --user` where python3-venv is missing). Progress and warnings go
# to standard error.
#
#   scripts/py-env.sh                          # target/emu-venv with the emulator harness'
#                                              # packages (scripts/emu-test.sh, scripts/demo.sh)
#   scripts/py-env.sh VENV PACKAGE==VERSION... # another venv, other packages (scripts/e2e.sh)
set -euo pipefail
cd "$(dirname "$0")/.."

PYTEST_VERSION=8.4.2
PYELFTOOLS_VERSION=0.32
PYMODBUS_VERSION=3.16.1
# Ed25519 of OpenSSL: signed firmware images made without our code (tests/pyshared/signed_image.py).
CRYPTOGRAPHY_VERSION=44.0.0

venv=${1:-target/emu-venv}
[[ $venv == /* ]] || venv=$PWD/$venv
has_pip() { [[ -x "$1" ]] && "$1" -m pip --version >/dev/null 2>&1; }
if ! has_pip "$venv/bin/python"; then
    rm -rf "$venv"
    python3 -m venv "$venv" >/dev/null 2>&1 || rm -rf "$venv"
fi
if has_pip "$venv/bin/python"; then
    python="$venv/bin/python"
    user=()
else
    echo "py-env: python3 -m venv failed (Debian: apt-get install python3-venv); using pip --user" >&2
    python=python3
    user=(--user)
fi
if (($# > 1)); then
    want=("${@:2}")
else
    want=("pytest==$PYTEST_VERSION" "pyelftools==$PYELFTOOLS_VERSION" "pymodbus==$PYMODBUS_VERSION"
          "cryptography==$CRYPTOGRAPHY_VERSION")
fi
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
