"""Emulator harness: the real firmware (emulator build) in QEMU's `b-l475e-iot01a` machine.

Each test gets a fresh QEMU, started paused (`-S`) with
- the PLC line (USART2, `-serial` #1) on a loopback TCP socket with TCP_NODELAY,
- the RS485 bus (UART4, `-serial` #3) on a pseudo-terminal through `-chardev serial`, so that the
  rate the firmware programs shows as the terminal's termios speed,
- semihosting on QEMU's standard output (the firmware's log, its `ready` line, panics),
- a qtest socket to drive input pins and read GPIO registers and RAM,
- a QMP socket to resume the machine.
Before resuming, RAM between the end of the firmware's statics and the top of the stack is painted
with a pattern; at the end of the test the lowest overwritten address gives the stack high-water
mark, appended to `target/emu/stack-hwm.log`.

Nothing is skipped: a missing QEMU or firmware ELF fails the test. Every wait is bounded and QEMU
is always killed in teardown.
"""

import json
import os
import pty
import select
import shutil
import socket
import subprocess
import termios
import threading
import time
import tty
from pathlib import Path

import pytest
from elftools.elf.elffile import ELFFile

ROOT = Path(__file__).resolve().parents[2]
QEMU = os.environ.get("QEMU", "qemu-system-arm")
HWM_LOG = ROOT / "target" / "emu" / "stack-hwm.log"

ESC = 0x1B
PAINT = 0xA5

# GPIO register blocks (RM0351): port n at 0x4800_0000 + 0x400 n.
GPIO_BASE = 0x4800_0000
MODER, IDR, ODR = 0x00, 0x10, 0x14
MODE_INPUT, MODE_OUTPUT, MODE_AF, MODE_ANALOG = 0, 1, 2, 3

# The board's pin table (src/board.rs), as (port letter, pin).
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


class Emulator:
    """A running QEMU with the firmware, and the host ends of its lines and pins."""

    def __init__(self, elf, workdir):
        self.elf = elf
        self.workdir = workdir
        self.log_lines = []
        self.log_lock = threading.Lock()
        self.process = None
        self.plc = None
        self.qtest = None
        self.qmp = None
        self._bus_rx = b""
        self._plc_rx = b""
        self.symbols = elf_symbols(elf)

    # ------------------------------------------------------------------ lifecycle

    def start(self):
        if shutil.which(QEMU) is None:
            pytest.fail(f"{QEMU} not found: run scripts/qemu-install.sh (or scripts/emu-test.sh)")
        # The bus: a pseudo-terminal. We keep the master (our end) and a slave descriptor (to read
        # the termios QEMU sets through its own descriptor of the same terminal).
        self.bus_master, self.bus_slave = pty.openpty()
        tty.setraw(self.bus_slave)
        os.set_blocking(self.bus_master, False)
        bus_path = os.ttyname(self.bus_slave)
        plc_port = free_port()
        qtest_path = self.workdir / "qtest.sock"
        qmp_path = self.workdir / "qmp.sock"
        self.stderr_path = self.workdir / "qemu.stderr"
        args = [
            QEMU, "-M", "b-l475e-iot01a", "-accel", "tcg", "-icount", "shift=auto",
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
        self.plc = connect(("127.0.0.1", plc_port))
        self.plc.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.plc.setblocking(False)
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
        for closer in (self.qtest, self.qmp, self.plc):
            if closer is not None:
                try:
                    closer.close()
                except OSError:
                    pass
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
        if self.process is not None:
            self.process.wait(timeout=10)
        for fd in ("bus_master", "bus_slave"):
            if hasattr(self, fd):
                try:
                    os.close(getattr(self, fd))
                except OSError:
                    pass
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

    # ------------------------------------------------------------------ lines

    def plc_send(self, data):
        self.plc.setblocking(True)
        self.plc.sendall(bytes(data))
        self.plc.setblocking(False)

    def bus_send(self, data):
        data = bytes(data)
        while data:
            _, writable, _ = select.select([], [self.bus_master], [], 5)
            if not writable:
                raise AssertionError("bus pseudo-terminal not writable")
            data = data[os.write(self.bus_master, data):]

    def _poll_plc(self):
        try:
            chunk = self.plc.recv(65536)
            if not chunk:
                raise AssertionError("QEMU closed the PLC socket")
            self._plc_rx += chunk
        except BlockingIOError:
            pass

    def _poll_bus(self):
        try:
            self._bus_rx += os.read(self.bus_master, 65536)
        except (BlockingIOError, OSError):
            pass

    def plc_receive(self, count, timeout=5):
        """Exactly `count` bytes from the PLC line (fails on time-out)."""
        def enough():
            self._check_alive("reading the PLC line")
            self._poll_plc()
            return len(self._plc_rx) >= count

        wait_for(enough, timeout, f"{count} bytes on the PLC line (have {self._plc_rx!r})")
        data, self._plc_rx = self._plc_rx[:count], self._plc_rx[count:]
        return data

    def bus_receive(self, count, timeout=5):
        def enough():
            self._check_alive("reading the bus")
            self._poll_bus()
            return len(self._bus_rx) >= count

        wait_for(enough, timeout, f"{count} bytes on the bus (have {self._bus_rx!r})")
        data, self._bus_rx = self._bus_rx[:count], self._bus_rx[count:]
        return data

    def quiet(self, seconds=0.2):
        """Whatever arrives on both lines within `seconds`: (bus bytes, PLC bytes)."""
        time.sleep(seconds)
        self._poll_bus()
        self._poll_plc()
        bus, plc = self._bus_rx, self._plc_rx
        self._bus_rx = self._plc_rx = b""
        return bus, plc

    def bus_speed(self):
        """The pseudo-terminal's termios output speed, in bit/s (the rate the guest set)."""
        speed = termios.tcgetattr(self.bus_slave)[5]
        for name in dir(termios):
            if name.startswith("B") and name[1:].isdigit() and getattr(termios, name) == speed:
                return int(name[1:])
        return speed

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

    # ------------------------------------------------------------------ bring-up commands

    def command(self, body, answer, timeout=5):
        """A bring-up command frame (ESC + body, padded to 16 bytes); waits for its answer."""
        frame = bytes([ESC]) + body
        frame += b" " * (16 - len(frame))
        self.plc_send(frame)
        got = self.plc_receive(2, timeout)
        assert got == bytes([ESC]) + answer, f"answer to {body!r}: {got!r}"


def elf_symbols(path):
    with open(path, "rb") as f:
        table = ELFFile(f).get_section_by_name(".symtab")
        wanted = ("__sheap", "_stack_start", "__ebss", "__sbss", "__sdata")
        return {s.name: s["st_value"] for s in table.iter_symbols() if s.name in wanted}


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
    """A fresh QEMU running the firmware, past its `ready` line."""
    emulator = Emulator(elf, tmp_path)
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
            print("---- QEMU stderr ----")
            print(emulator.stderr()[-3000:])
