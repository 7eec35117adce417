"""End-to-end fixtures: `rc-gateway-host` with simulated axes behind a pseudo-terminal, driven by
pymodbus, a Modbus RTU master nobody in this project wrote.

Every wait is bounded; the gateway process is ended in teardown (a `quit` line, then SIGTERM, then
SIGKILL), and it also ends by itself when its standard input closes.
"""

import json
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymodbus.client import ModbusSerialClient

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "pyshared"))

# The register map and the checked Modbus master, shared with the emulator tests; re-exported
# for the test modules.
from plc import *  # noqa: E402,F401,F403
from plc import PlcMaster, wait_for  # noqa: E402

BINARY = Path(os.environ.get("RC_GATEWAY_HOST", ROOT / "target" / "debug" / "rc-gateway-host"))
AXES = 3


class Gateway(PlcMaster):
    """A running `rc-gateway-host` and a pymodbus client on its PLC line."""

    def __init__(self, process, port, log_path):
        self.process = process
        self.port = port
        self.log_path = log_path
        self._stdout = b""
        # Generous: a reply takes a few ms, but a loaded machine may stall the process a while.
        client = ModbusSerialClient(port=port, baudrate=115200, timeout=1, retries=1)
        if not client.connect():
            raise RuntimeError(f"cannot open {port}")
        super().__init__(client)

    # ------------------------------------------------------------------ control lines

    def control(self, line, timeout=5.0):
        """Send a control line on the process' stdin; its one-line JSON answer."""
        self.process.stdin.write((line + "\n").encode())
        self.process.stdin.flush()
        fd = self.process.stdout.fileno()
        deadline = time.monotonic() + timeout
        while b"\n" not in self._stdout:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"no answer to {line!r}")
            ready, _, _ = select.select([fd], [], [], left)
            if ready:
                chunk = os.read(fd, 65536)
                if not chunk:
                    raise EOFError(f"gateway exited before answering {line!r}")
                self._stdout += chunk
        answer, self._stdout = self._stdout.split(b"\n", 1)
        return json.loads(answer)

    def stats(self):
        answer = self.control("stats")
        assert answer["ok"], answer
        return answer

    def sim(self, axis):
        return self.stats()["axes"][axis]

    # ------------------------------------------------------------------ raw bytes

    def raw_exchange(self, frame, wait=0.3):
        """Write `frame` as it is on a second descriptor of the PLC line; what comes back within
        `wait` seconds (read through pymodbus' own port, so that nothing is left for it)."""
        serial = self.client.socket
        serial.reset_input_buffer()
        fd = os.open(self.port, os.O_WRONLY | os.O_NOCTTY)
        try:
            os.write(fd, bytes(frame))
        finally:
            os.close(fd)
        deadline = time.monotonic() + wait
        received = b""
        while time.monotonic() < deadline:
            waiting = serial.in_waiting
            if waiting:
                received += serial.read(waiting)
            else:
                time.sleep(0.01)
        return received

    def close(self):
        self.client.close()


def _read_first_line(process, timeout):
    fd = process.stdout.fileno()
    data = b""
    deadline = time.monotonic() + timeout
    while b"\n" not in data:
        left = deadline - time.monotonic()
        if left <= 0 or process.poll() is not None:
            raise RuntimeError(f"rc-gateway-host did not start: {data!r}")
        ready, _, _ = select.select([fd], [], [], left)
        if ready:
            chunk = os.read(fd, 4096)
            if not chunk:
                raise RuntimeError(f"rc-gateway-host exited: {data!r}")
            data += chunk
    line, rest = data.split(b"\n", 1)
    return line.decode(), rest


def _stop(process):
    if process.poll() is None:
        try:
            process.stdin.write(b"quit\n")
            process.stdin.flush()
        except (BrokenPipeError, OSError):
            pass
        try:
            process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(timeout=5)
    for stream in (process.stdin, process.stdout):
        try:
            stream.close()
        except OSError:
            pass


@pytest.hookimpl(tryfirst=True, hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    setattr(item, "report_" + report.when, report)


@pytest.fixture
def gateway(request, tmp_path):
    """`rc-gateway-host --plc-pty --sim 3 --points --watchdog-ms 2000`, axes online."""
    if not BINARY.exists():
        pytest.fail(f"{BINARY} is missing: cargo build -p rc-tools --bin rc-gateway-host")
    log_path = tmp_path / "rc-gateway-host.log"
    with open(log_path, "wb") as log:
        process = subprocess.Popen(
            [str(BINARY), "--plc-pty", "--sim", str(AXES), "--points", "--watchdog-ms", "2000", "--log"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=log,
        )
    gw = None
    try:
        line, rest = _read_first_line(process, timeout=10)
        assert line.startswith("PLC /dev/"), line
        gw = Gateway(process, line.split(" ", 1)[1], log_path)
        gw._stdout = rest
        for axis in range(AXES):
            wait_for(lambda: gw.read(unit(axis), LINK)[0] == 1, 5.0, f"axis {axis} online")
        yield gw
    finally:
        if gw is not None:
            gw.close()
        _stop(process)
        failed = getattr(request.node, "report_call", None)
        if failed is not None and failed.failed and log_path.exists():
            tail = log_path.read_text(errors="replace").splitlines()[-80:]
            print("---- rc-gateway-host log (last lines) ----")
            print("\n".join(tail))
