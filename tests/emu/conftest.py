"""pytest fixtures for the emulator tests: each test gets a fresh QEMU running the real firmware
(emulator build), with simulated controllers on its bus and pymodbus on its PLC line; the harness
itself is tests/pyshared/emu.py (shared with the demo and the interop run). Each test's stack
high-water mark is appended to `target/emu/stack-hwm.log`; a failing test prints the firmware's
log, the bus as rc-sim saw it (without status polls) and QEMU's stderr.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "pyshared"))

from emu import Emulator, record_stack  # noqa: E402


def _build_elf():
    path = os.environ.get("RC_GATEWAY_EMU_ELF")
    if path:
        return Path(path)
    result = subprocess.run([str(ROOT / "scripts" / "emu-build.sh")], capture_output=True, text=True, timeout=1200)
    if result.returncode != 0:
        pytest.fail(f"scripts/emu-build.sh failed:\n{result.stderr[-4000:]}")
    return Path(result.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="session")
def elf():
    path = _build_elf()
    if not path.is_file():
        pytest.fail(f"firmware ELF {path} missing: run scripts/emu-build.sh")
    return path


@pytest.hookimpl(tryfirst=True, hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    setattr(item, "report_" + report.when, report)


@pytest.fixture
def emu(request, elf, tmp_path):
    """A fresh QEMU running the firmware, past its `ready` line, with one simulated axis (axis
    0: the firmware's default configuration) on its bus. `@pytest.mark.axes("0-3")` gives more."""
    marker = request.node.get_closest_marker("axes")
    emulator = Emulator(elf, tmp_path, marker.args[0] if marker else "1", control=True)
    try:
        emulator.start()
        yield emulator
    finally:
        record_stack(emulator.stop(), request.node.name)
        failed = getattr(request.node, "report_call", None)
        if failed is not None and failed.failed:
            print("---- firmware log (semihosting) ----")
            print("\n".join(emulator.log()[-60:]))
            print("---- bus (rc-sim), without status polls ----")
            lines = [line for line in emulator.sim_log() if "command: Status }" not in line and "code: Status," not in line]
            print("\n".join(line[:200] for line in lines[-80:]))
            print("---- QEMU stderr ----")
            print(emulator.stderr()[-3000:])


def pytest_configure(config):
    config.addinivalue_line("markers", "axes(spec): the simulated axes on the bus (rc-sim --axes)")
