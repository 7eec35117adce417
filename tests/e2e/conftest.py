"""End-to-end fixtures: `rc-gateway-host` with simulated axes behind a pseudo-terminal, driven by
pymodbus, a Modbus RTU master nobody in this project wrote.

Every wait is bounded; the gateway process is ended in teardown (a `quit` line, then SIGTERM, then
SIGKILL), and it also ends by itself when its standard input closes.
"""

import inspect
import json
import os
import select
import signal
import subprocess
import time
from pathlib import Path

import pytest
from pymodbus.client import ModbusSerialClient
from pymodbus.exceptions import ModbusException

ROOT = Path(__file__).resolve().parents[2]
BINARY = Path(os.environ.get("RC_GATEWAY_HOST", ROOT / "target" / "debug" / "rc-gateway-host"))
GATEWAY_UNIT = 63
AXES = 3

# Axis registers (protocol/src/plc/map.rs).
PNOW, ALMC, DIPM, DOPM, DSS1, DSS2, DSSE = 0x9000, 0x9002, 0x9003, 0x9004, 0x9005, 0x9006, 0x9007
CMST, CMER, LINK, CMCT = 0x9F00, 0x9F01, 0x9F02, 0x9F03
DRG1, POSR, DIRECT = 0x0D00, 0x0D03, 0x9900
COIL_SON, COIL_ALRS, COIL_STP, COIL_HOME, COIL_STOP = 0x0403, 0x0407, 0x040A, 0x040B, 0x042C
DRG1_SON, DRG1_ALRS, DRG1_STP, DRG1_HOME, DRG1_CSTR = 1 << 12, 1 << 8, 1 << 5, 1 << 4, 1 << 3
DSS1_SV, DSS1_ALMH, DSS1_STP, DSS1_HEND, DSS1_PEND = 1 << 12, 1 << 10, 1 << 5, 1 << 4, 1 << 3
DOPM_ALM_N, DOPM_PEND, DOPM_HEND = 1 << 14, 1 << 11, 1 << 10
# Gateway unit.
G_VERSION, G_FAILSAFE, G_FAILSAFE_COUNT, G_WATCHDOG = 0x0000, 0x0004, 0x0005, 0x0006
G_SYNC_MASK, G_SYNC_START, G_SYNC_STATUS = 0x000B, 0x000C, 0x000D
G_REQUEST, G_RESPONSE = 0x0200, 0x0210
# CMST values and CMER reasons (protocol/src/plc/gateway.rs).
IDLE, TAKEN, DONE, FAILED = 0, 1, 2, 3
REASON_ALARM, REASON_CANCELLED, REASON_PAUSED = 4, 6, 10


def unit(axis):
    return axis + 1


class ModbusError(Exception):
    """An exception reply: `code` is the Modbus exception code."""

    def __init__(self, function, code):
        super().__init__(f"function {function:#04x}: exception {code:02d}")
        self.code = code


def _unit_keyword():
    """pymodbus renamed the unit keyword: `unit` (2.x), `slave` (3.0-3.8), `device_id` (3.9+)."""
    parameters = inspect.signature(ModbusSerialClient.read_holding_registers).parameters
    for name in ("device_id", "slave", "unit"):
        if name in parameters:
            return name
    raise RuntimeError(f"unknown pymodbus API: {list(parameters)}")


UNIT_KEYWORD = _unit_keyword()


class Gateway:
    """A running `rc-gateway-host` and a pymodbus client on its PLC line."""

    def __init__(self, process, port, log_path):
        self.process = process
        self.port = port
        self.log_path = log_path
        self._stdout = b""
        # Generous: a reply takes a few ms, but a loaded machine may stall the process a while.
        self.client = ModbusSerialClient(port=port, baudrate=115200, timeout=1, retries=1)
        if not self.client.connect():
            raise RuntimeError(f"cannot open {port}")

    # ------------------------------------------------------------------ Modbus, checked

    def _call(self, method, *args, **kwargs):
        kwargs[UNIT_KEYWORD] = kwargs.pop("unit")
        response = getattr(self.client, method)(*args, **kwargs)
        if response.isError():
            code = getattr(response, "exception_code", None)
            if code is None:
                raise ModbusException(f"{method}: {response}")
            raise ModbusError(getattr(response, "function_code", 0) & 0x7F, code)
        return response

    def read(self, unit, address, count=1):
        return list(self._call("read_holding_registers", address, count=count, unit=unit).registers)

    def read_input(self, unit, address, count=1):
        return list(self._call("read_input_registers", address, count=count, unit=unit).registers)

    def write(self, unit, address, values):
        """FC06 for one value, FC10 for a list."""
        if isinstance(values, int):
            self._call("write_register", address, values, unit=unit)
        else:
            self._call("write_registers", address, list(values), unit=unit)

    def coil(self, unit, address, on):
        self._call("write_coil", address, bool(on), unit=unit)

    def read_coils(self, unit, address, count=1):
        return list(self._call("read_coils", address, count=count, unit=unit).bits[:count])

    def call(self, method, *args, unit, **kwargs):
        """Any pymodbus client method, with the unit keyword of the installed version."""
        return self._call(method, *args, unit=unit, **kwargs)

    def exception(self, function, *args, **kwargs):
        """The exception code the gateway answers a request with (fails if it succeeds)."""
        try:
            function(*args, **kwargs)
        except ModbusError as error:
            return error.code
        raise AssertionError(f"{function.__name__}{args} succeeded; an exception was expected")

    # ------------------------------------------------------------------ axis helpers

    def pnow(self, axis):
        hi, lo = self.read(unit(axis), PNOW, 2)
        value = (hi << 16) | lo
        return value - (1 << 32) if value & 0x8000_0000 else value

    def dss1(self, axis):
        return self.read(unit(axis), DSS1)[0]

    def cmst(self, axis):
        state, reason = self.read(unit(axis), CMST, 2)
        return state, reason

    def settle(self, axis, timeout=15.0):
        """Poll like a PLC until the axis' last command is done or failed: (CMST, CMER)."""
        return wait_for(
            lambda: (lambda s: s if s[0] in (DONE, FAILED) else None)(self.cmst(axis)),
            timeout,
            f"axis {axis}: command settles",
        )

    def servo_on(self, axis):
        self.write(unit(axis), DRG1, DRG1_SON)
        assert self.settle(axis) == (DONE, 0)

    def home(self, axis):
        """Servo on, home (DRG1 HOME edge), wait HEND, release HOME."""
        self.servo_on(axis)
        self.write(unit(axis), DRG1, DRG1_SON | DRG1_HOME)
        wait_for(lambda: self.dss1(axis) & DSS1_HEND, 20.0, f"axis {axis}: HEND")
        assert self.settle(axis) == (DONE, 0)
        self.write(unit(axis), DRG1, DRG1_SON)

    def direct(self, axis, target, speed=100_00, accel=30, band=10, registers=7, ctlf=0):
        """FC10 at 0x9900: PCMD (0.01 mm), INP, VCMD (0.01 mm/s), ACMD (0.01 G)[, PPOW, CTLF]."""
        p = target & 0xFFFF_FFFF
        values = [p >> 16, p & 0xFFFF, band >> 16, band & 0xFFFF, speed >> 16, speed & 0xFFFF, accel]
        if registers == 9:
            values += [0, ctlf]
        self.write(unit(axis), DIRECT, values)

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


def crc16(data):
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return bytes([crc & 0xFF, crc >> 8])


def adu(*data):
    body = bytes(data)
    return body + crc16(body)


def wait_for(predicate, timeout, what, interval=0.05):
    """Poll `predicate` until it returns something truthy (returned), at most `timeout` s."""
    deadline = time.monotonic() + timeout
    last = None
    while True:
        last = predicate()
        if last:
            return last
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for: {what} (last: {last!r})")
        time.sleep(interval)


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
        pytest.fail(f"{BINARY} is missing: cargo build -p rc-host --bin rc-gateway-host")
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
