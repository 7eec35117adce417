"""Emulator harness: the real firmware (emulator build) in QEMU's `b-l475e-iot01a` machine, with
simulated Robo Cylinder controllers on its bus and a Modbus RTU master on its PLC line.

Each test gets a fresh QEMU, started paused (`-S`) with
- the PLC line (USART2, `-serial` #1) on a loopback TCP socket with TCP_NODELAY, where pymodbus
  (a Modbus RTU master nobody in this project wrote) talks RTU framing,
- the RS485 bus (UART4, `-serial` #3) on the pseudo-terminal of `rc-sim`, the project's simulated
  controllers in real time (`--slow-baud-is-break`: the firmware's switch to 9600 bit/s right
  before its break stands for the break, which a pseudo-terminal cannot carry; `--log`: every
  frame, decoded, in `rc-sim.log`, which the tests read as the controllers' view),
- semihosting on QEMU's standard output (the firmware's log, its `ready` line, panics),
- a qtest socket to drive input pins and read GPIO registers and RAM,
- a QMP socket to resume the machine.
QEMU runs without `-icount`: its virtual clock is then the host's, the clock rc-sim keeps too.
With `-icount shift=auto` the guest's clock runs fast to catch up after any stall of QEMU, so the
firmware's reply time-outs expire early against rc-sim's real-time controllers (seen: retries
colliding with late replies, axes going offline).
Before resuming, RAM between the end of the firmware's statics and the top of the stack is painted
with a pattern; at the end of the test the lowest overwritten address gives the stack high-water
mark, appended to `target/emu/stack-hwm.log`.

Nothing is skipped: a missing QEMU, rc-sim or firmware ELF fails the test. Every wait is bounded
and QEMU and rc-sim are always killed in teardown.
"""

import json
import os
import re
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from elftools.elf.elffile import ELFFile
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "pyshared"))

from plc import PlcMaster  # noqa: E402

QEMU = os.environ.get("QEMU", "qemu-system-arm")
RC_SIM = Path(os.environ.get("RC_SIM", ROOT / "target" / "debug" / "rc-sim"))
HWM_LOG = ROOT / "target" / "emu" / "stack-hwm.log"

PAINT = 0xA5
# The bus commands that only read (status and position polls, memory reads): everything else
# changes something on an axis.
READS = {"Status", "ReadMemory"}

# GPIO register blocks (RM0351): port n at 0x4800_0000 + 0x400 n.
GPIO_BASE = 0x4800_0000
MODER, IDR, ODR = 0x00, 0x10, 0x14
MODE_INPUT, MODE_OUTPUT, MODE_AF, MODE_ANALOG = 0, 1, 2, 3

# The board's pin table (src/board/l475.rs), as (port letter, pin).
INPUTS = {  # PIO bit -> pin
    0: ("c", 5), 1: ("c", 4), 2: ("c", 3), 3: ("c", 2), 4: ("c", 1), 5: ("c", 0),
    11: ("d", 14), 12: ("b", 0), 13: ("a", 3), 14: ("b", 4), 15: ("b", 1),
}
STOP_INPUT = ("a", 4)
OUTPUTS = {  # PIO bit -> pin
    0: ("b", 2), 1: ("a", 2), 2: ("a", 7), 3: ("a", 6), 6: ("b", 9), 7: ("b", 8),
    10: ("d", 0), 11: ("d", 1), 12: ("d", 2), 13: ("d", 7), 14: ("d", 3),
}
LED_RUN, LED_LINK, LED_ALARM = ("b", 14), ("a", 5), ("c", 9)
BUS_TX, BUS_DE = ("a", 0), ("a", 15)
PLC_DE = ("d", 4)


def wait_for(predicate, timeout, what, interval=0.01):
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


def connect(address, family=socket.AF_INET, timeout=20):
    """A connected socket; retried while QEMU is still setting up its listening sockets (a unix
    socket's file appears at bind, a moment before listen)."""
    deadline = time.monotonic() + timeout
    while True:
        sock = socket.socket(family)
        sock.settimeout(10)
        try:
            sock.connect(address)
            return sock
        except (ConnectionRefusedError, FileNotFoundError):
            sock.close()
            if time.monotonic() >= deadline:
                raise
            time.sleep(0.02)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Qtest:
    """QEMU's qtest line protocol: one command per line, answered `OK ...` or `FAIL ...`."""

    def __init__(self, path):
        self.sock = connect(str(path), socket.AF_UNIX)
        self.buf = b""
        self.lock = threading.Lock()

    def cmd(self, line):
        with self.lock:
            self.sock.sendall(line.encode() + b"\n")
            while True:
                while b"\n" not in self.buf:
                    chunk = self.sock.recv(1 << 20)
                    if not chunk:
                        raise EOFError(f"qtest closed during {line!r}")
                    self.buf += chunk
                answer, self.buf = self.buf.split(b"\n", 1)
                answer = answer.decode()
                if answer.startswith("IRQ"):  # asynchronous notifications: not ours
                    continue
                if not answer.startswith("OK"):
                    raise RuntimeError(f"qtest {line!r}: {answer}")
                return answer[2:].strip()

    def readl(self, address):
        return int(self.cmd(f"readl {address:#x}"), 16)

    def read(self, address, size):
        return bytes.fromhex(self.cmd(f"read {address:#x} {size:#x}")[2:])

    def memset(self, address, size, value):
        self.cmd(f"memset {address:#x} {size:#x} {value:#x}")

    def close(self):
        self.sock.close()


class Qmp:
    def __init__(self, path):
        self.sock = connect(str(path), socket.AF_UNIX)
        self.file = self.sock.makefile("rwb")
        json.loads(self.file.readline())  # greeting
        self.execute("qmp_capabilities")

    def execute(self, command, **arguments):
        message = {"execute": command}
        if arguments:
            message["arguments"] = arguments
        self.file.write(json.dumps(message).encode() + b"\n")
        self.file.flush()
        while True:
            answer = json.loads(self.file.readline())
            if "event" in answer:
                continue
            if "error" in answer:
                raise RuntimeError(f"QMP {command}: {answer['error']}")
            return answer.get("return")

    def close(self):
        self.sock.close()


class Plc(PlcMaster):
    """pymodbus on the firmware's PLC line, RTU framing over QEMU's socket."""

    def __init__(self, port):
        client = ModbusTcpClient("127.0.0.1", port=port, framer=FramerType.RTU, timeout=1, retries=2)
        if not client.connect():
            raise AssertionError(f"cannot connect to QEMU's PLC socket on port {port}")
        super().__init__(client)

    def raw_exchange(self, frame, wait=0.3):
        """Send `frame` as it is; whatever comes back within `wait` seconds."""
        sock = self.client.socket
        sock.setblocking(False)
        try:
            while True:  # nothing stale left for the answer
                try:
                    if not sock.recv(65536):
                        break
                except BlockingIOError:
                    break
            sock.sendall(bytes(frame))
            deadline = time.monotonic() + wait
            received = b""
            while time.monotonic() < deadline:
                try:
                    received += sock.recv(65536)
                except BlockingIOError:
                    time.sleep(0.01)
            return received
        finally:
            sock.setblocking(True)

    def close(self):
        self.client.close()


class Emulator:
    """A running QEMU with the firmware, rc-sim on its bus, and the host ends of its pins."""

    def __init__(self, elf, workdir, axes):
        self.elf = elf
        self.workdir = workdir
        self.axes = axes
        self.log_lines = []
        self.log_lock = threading.Lock()
        self.process = None
        self.sim = None
        self.plc = None
        self.qtest = None
        self.qmp = None
        self.symbols = elf_symbols(elf)

    # ------------------------------------------------------------------ lifecycle

    def start(self):
        if shutil.which(QEMU) is None:
            pytest.fail(f"{QEMU} not found: run scripts/qemu-install.sh (or scripts/emu-test.sh)")
        if not RC_SIM.is_file():
            pytest.fail(f"{RC_SIM} missing: cargo build -p rc-host --bin rc-sim")
        self.sim_log_path = self.workdir / "rc-sim.log"
        with open(self.sim_log_path, "wb") as sim_log:
            self.sim = subprocess.Popen(
                [str(RC_SIM), "--pty", "--axes", self.axes, "--slow-baud-is-break", "--log"],
                stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=sim_log,
            )
        first = self.sim.stdout.readline().decode().split()
        if len(first) != 2 or first[0] != "PTY":
            raise AssertionError(f"rc-sim did not start: {first} {self.sim_log()}")
        bus_path = first[1]
        plc_port = free_port()
        qtest_path = self.workdir / "qtest.sock"
        qmp_path = self.workdir / "qmp.sock"
        self.stderr_path = self.workdir / "qemu.stderr"
        args = [
            QEMU, "-M", "b-l475e-iot01a", "-accel", "tcg",
            "-nographic", "-monitor", "none", "-S",
            "-kernel", str(self.elf),
            "-semihosting-config", "enable=on,target=native",
            "-chardev", f"socket,id=plc,host=127.0.0.1,port={plc_port},server=on,wait=off,nodelay=on",
            "-chardev", f"serial,id=bus,path={bus_path}",
            "-serial", "null", "-serial", "chardev:plc", "-serial", "null", "-serial", "chardev:bus",
            "-qtest", f"unix:{qtest_path},server=on,wait=off", "-qtest-log", "/dev/null",
            "-qmp", f"unix:{qmp_path},server=on,wait=off",
            "-d", "guest_errors",
        ]
        self.args = args
        with open(self.stderr_path, "wb") as stderr:
            self.process = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=stderr)
        threading.Thread(target=self._read_stdout, daemon=True).start()
        wait_for(lambda: qtest_path.exists() and qmp_path.exists() or self._dead(), 20, "QEMU sockets")
        self._check_alive("starting")
        self.qtest = Qtest(qtest_path)
        self.qmp = Qmp(qmp_path)
        wait_for(lambda: _listening(plc_port) or self._dead(), 20, "QEMU's PLC socket")
        self.plc = Plc(plc_port)
        self._paint_stack()
        self.qmp.execute("cont")
        # Bytes sent before the firmware has enabled its receivers are lost: wait for its word.
        self.wait_log("INFO  ready", 20)

    def _dead(self):
        return self.process.poll() is not None

    def _check_alive(self, doing):
        if self._dead():
            raise AssertionError(f"QEMU exited ({self.process.returncode}) while {doing}:\n{self.stderr()}")

    def _read_stdout(self):
        for raw in self.process.stdout:
            with self.log_lock:
                self.log_lines.append(raw.decode(errors="replace").rstrip("\n"))

    def stderr(self):
        try:
            return self.stderr_path.read_text(errors="replace")
        except OSError:
            return ""

    def log(self):
        with self.log_lock:
            return list(self.log_lines)

    def wait_log(self, text, timeout=10):
        def seen():
            self._check_alive(f"waiting for {text!r}")
            return next((line for line in self.log() if text in line), None)

        return wait_for(seen, timeout, f"log line {text!r}")

    def stop(self):
        hwm = None
        try:
            if self.qtest is not None and not self._dead():
                hwm = self.stack_high_water_mark()
        except Exception as error:  # the measurement must never hide the test's own result
            print(f"stack high-water mark not measured: {error}")
        for closer in (self.plc, self.qtest, self.qmp):
            if closer is not None:
                try:
                    closer.close()
                except OSError:
                    pass
        for process in (self.process, self.sim):
            if process is not None and process.poll() is None:
                process.kill()
            if process is not None:
                process.wait(timeout=10)
        return hwm

    # ------------------------------------------------------------------ stack

    def _stack_region(self):
        return self.symbols["__sheap"], self.symbols["_stack_start"]

    def _paint_stack(self):
        low, high = self._stack_region()
        self.qtest.memset(low, high - low, PAINT)

    def stack_high_water_mark(self):
        """Bytes of stack ever used: top of stack minus the lowest byte not holding the paint."""
        low, high = self._stack_region()
        ram = self.qtest.read(low, high - low)
        untouched = len(ram) - len(ram.lstrip(bytes([PAINT])))
        return high - (low + untouched)

    def request_panic(self):
        """Makes the gateway task panic (emulator build only: `EMU_PANIC` in src/gateway.rs)."""
        self.qtest.cmd(f"writeb {self.symbols['EMU_PANIC']:#x} 0x1")

    # ------------------------------------------------------------------ the bus, as rc-sim saw it

    def sim_log(self):
        try:
            return self.sim_log_path.read_text(errors="replace").splitlines()
        except OSError:
            return []

    def bus_commands(self, axis=None):
        """Every command the controllers received, in order: (time s, axis, command name)."""
        found = []
        for line in self.sim_log():
            m = re.match(r"\s*([\d.]+) >> Request \{ axis: Axis\((\d+)\), command: (\w+)", line)
            if m and (axis is None or int(m.group(2)) == axis):
                found.append((float(m.group(1)), int(m.group(2)), m.group(3)))
        return found

    def bus_changes(self, axis=None):
        """The commands that change something on an axis (not status, position or memory reads)."""
        return [c for c in self.bus_commands(axis) if c[2] not in READS]

    def bus_events(self):
        """rc-sim's line events in order: breaks, rate changes, communication changes."""
        events = []
        for line in self.sim_log():
            if " -- " in line or "communication-change" in line:
                events.append(line.split(None, 1)[1])
        return events

    # ------------------------------------------------------------------ pins

    def set_pin(self, pin, high):
        port, number = pin
        self.qtest.cmd(f"set_irq_in /machine/soc/gpio{port} unnamed-gpio-in {number} {int(bool(high))}")

    def reg(self, port, offset):
        return self.qtest.readl(GPIO_BASE + 0x400 * (ord(port) - ord("a")) + offset)

    def odr(self, pin):
        port, number = pin
        return (self.reg(port, ODR) >> number) & 1

    def mode(self, pin):
        port, number = pin
        return (self.reg(port, MODER) >> (2 * number)) & 3

    def outputs(self):
        """The PIO output word read back from the pins (bit n = OUTn)."""
        return sum(self.odr(pin) << bit for bit, pin in OUTPUTS.items())

    def set_inputs(self, word, stop_released=True):
        self.set_pin(STOP_INPUT, stop_released)
        for bit, pin in INPUTS.items():
            self.set_pin(pin, word >> bit & 1)


def _listening(port):
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1):
            return True
    except OSError:
        return False


def elf_symbols(path):
    with open(path, "rb") as f:
        table = ELFFile(f).get_section_by_name(".symtab")
        wanted = ("__sheap", "_stack_start", "__ebss", "__sbss", "__sdata")
        found = {}
        for symbol in table.iter_symbols():
            if symbol.name in wanted:
                found[symbol.name] = symbol["st_value"]
            elif "EMU_PANIC" in symbol.name:  # mangled: rc_gateway::gateway::EMU_PANIC
                found["EMU_PANIC"] = symbol["st_value"]
        return found


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
    emulator = Emulator(elf, tmp_path, marker.args[0] if marker else "1")
    try:
        emulator.start()
        yield emulator
    finally:
        hwm = emulator.stop()
        if hwm is not None:
            HWM_LOG.parent.mkdir(parents=True, exist_ok=True)
            with open(HWM_LOG, "a") as log:
                log.write(f"{hwm} {request.node.name}\n")
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
