"""The real firmware (its emulator build) in QEMU's `b-l475e-iot01a` machine, with simulated Robo
Cylinder controllers on its bus and a Modbus RTU master on its PLC line: what the emulator tests
(tests/emu), the demo (tests/demo) and the interop run (scripts/interop.sh --firmware) start.

`Emulator.start()` starts QEMU paused (`-S`) with
- the PLC line (USART2, `-serial` #1) on a loopback TCP socket with TCP_NODELAY, where pymodbus
  (a Modbus RTU master nobody in this project wrote) talks RTU framing, or any other master
  through `plc_pty()`, a pseudo-terminal bridged to that socket,
- the RS485 bus (UART4, `-serial` #3) on the pseudo-terminal of `rc-sim`, the project's simulated
  controllers in real time (`--slow-baud-is-break`: the firmware's switch to 9600 bit/s right
  before its break stands for the break, which a pseudo-terminal cannot carry; `--log`: every
  frame, decoded, in `rc-sim.log`, read back as the controllers' view; `--control`: faults
  injected while it runs),
- semihosting on QEMU's standard output (the firmware's log, its `ready` line, panics),
- a qtest socket to drive input pins and read GPIO registers and RAM,
- a QMP socket to resume the machine.
QEMU runs without `-icount`: its virtual clock is then the host's, the clock rc-sim keeps too.
With `-icount shift=auto` the guest's clock runs fast to catch up after any stall of QEMU, so the
firmware's reply time-outs expire early against rc-sim's real-time controllers (seen: retries
colliding with late replies, axes going offline).
Before resuming, the stack region is painted with a pattern: [`_stack_end`, `_stack_start`), which
flip-link's layout puts at the bottom of RAM, from the start of RAM up to the statics (`.data`,
`.bss`, `.uninit` lie above it, untouched); `stop()` returns the stack high-water mark (the lowest
overwritten address).

Nothing is skipped: a missing QEMU, rc-sim or firmware ELF raises `EmulatorError`. Every wait is
bounded and `stop()` always kills QEMU and rc-sim.

As a program (`python3 tests/pyshared/emu.py ELF --axes 0-2`) it starts everything, prints
`PLC /dev/pts/N` (the PLC line as a serial port for any Modbus RTU master) and `BUS LOG path`, and
runs until SIGTERM/SIGINT or end of input.
"""

import json
import os
import pty
import select
import signal
import re
import shutil
import socket
import subprocess
import threading
import sys
import time
import tty
from pathlib import Path

from elftools.elf.elffile import ELFFile
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

from plc import PlcMaster, crc16, wait_for

ROOT = Path(__file__).resolve().parents[2]

class EmulatorError(AssertionError):
    """The emulator could not be started or died: a failure, never a skip."""


QEMU = os.environ.get("QEMU", "qemu-system-arm")
RC_SIM = Path(os.environ.get("RC_SIM", ROOT / "target" / "debug" / "rc-sim"))
HWM_LOG = ROOT / "target" / "emu" / "stack-hwm.log"
# The update path's (the L475 only: SHA-512 and the Ed25519 check in the gateway task), apart from
# HWM_LOG, which the size report also holds the F103's RAM budget to (the F103 has no update).
HWM_UPDATE_LOG = ROOT / "target" / "emu" / "stack-hwm-update.log"


def record_stack(hwm, name, log=HWM_LOG):
    """Appends a test's stack high-water mark (`Emulator.stop()`'s; None: not measured)."""
    if hwm is None:
        return
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "a") as out:
        out.write(f"{hwm} {name}\n")

PAINT = 0xA5
# The bus commands that only read (status and position polls, memory reads): everything else
# changes something on an axis.
READS = {"Status", "ReadMemory"}

# GPIO register blocks (RM0351): port n at 0x4800_0000 + 0x400 n.
GPIO_BASE = 0x4800_0000
MODER, IDR, ODR = 0x00, 0x10, 0x14
MODE_INPUT, MODE_OUTPUT, MODE_AF, MODE_ANALOG = 0, 1, 2, 3

# The board's pin table (src/board/l475.rs), as (port letter, pin).
INPUTS = {  # PIO bit -> pin (IN6-IN9 on port E: the emulator build's only, src/board/l475.rs)
    0: ("c", 5), 1: ("c", 4), 2: ("c", 3), 3: ("c", 2), 4: ("c", 1), 5: ("c", 0),
    6: ("e", 7), 7: ("e", 8), 8: ("e", 9), 9: ("e", 10),
    11: ("d", 14), 12: ("b", 0), 13: ("a", 3), 14: ("b", 4), 15: ("b", 1),
}
STOP_INPUT = ("a", 4)
OUTPUTS = {  # PIO bit -> pin (OUT4, OUT5, OUT9 on port E: the emulator build's only)
    0: ("b", 2), 1: ("a", 2), 2: ("a", 7), 3: ("a", 6), 4: ("e", 11), 5: ("e", 12), 6: ("b", 9),
    7: ("b", 8), 9: ("e", 13), 10: ("d", 0), 11: ("d", 1), 12: ("d", 2), 13: ("d", 7), 14: ("d", 3),
}
LED_RUN, LED_LINK, LED_ALARM = ("b", 14), ("a", 5), ("c", 9)
# PIO bits (src/board: the PCON pattern-0 signals): inputs, then outputs.
PC1, PC2, HOME, STP_N, CSTR, RES, SON = 0, 1, 11, 12, 13, 14, 15
PM1, PM2, MOVE, HEND, PEND, SV, LINK_OUT, ALM_N = 0, 1, 6, 10, 11, 12, 13, 14
BUS_TX, BUS_DE = ("a", 0), ("a", 15)
PLC_DE = ("d", 4)


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
            raise EmulatorError(f"cannot connect to QEMU's PLC socket on port {port}")
        super().__init__(client)

    def raw_exchange(self, frame, wait=1.0):
        """Send `frame` as it is; what comes back: a whole RTU frame (its CRC checks) as soon as
        it is there, else whatever came within `wait` seconds (generous: a loaded host stalls
        QEMU; a request that gets no answer costs the whole wait)."""
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
                if len(received) >= 5 and crc16(received[:-2]) == received[-2:]:
                    break
            return received
        finally:
            sock.setblocking(True)

    def close(self):
        self.client.close()


class Emulator:
    """A running QEMU with the firmware, rc-sim on its bus, and the host ends of its pins."""

    def __init__(self, elf, workdir, axes, sim_args=(), control=False, plc=True, qemu_args=(), accel="tcg"):
        """`axes`: rc-sim's --axes; `sim_args`: more rc-sim options (--baud, --drop ...);
        `control`: rc-sim reads faults to inject ([`inject`]); `plc`: connect pymodbus to the PLC
        line ([`plc`]) - without it the line's TCP port ([`plc_port`]) is free for another
        master, and [`plc_pty`] bridges it to a pseudo-terminal."""
        self.elf = Path(elf)
        self.workdir = Path(workdir)
        self.axes = axes
        self.sim_args = list(sim_args)
        self.with_control = control
        self.with_plc = plc
        self.qemu_args = list(qemu_args)
        self.accel = accel
        # Off after a deliberate overflow (`request_stack_overflow`): the whole region is used then.
        self.measure_stack = True
        self.plc_port = None
        self.log_lines = []
        self.log_lock = threading.Lock()
        self.process = None
        self.sim = None
        self.plc = None
        self.qtest = None
        self.qmp = None
        self.symbols = elf_symbols(elf)

    def bootloader_args(self):
        """QEMU's arguments that load the bootloader (rc-bootloader, which scripts/emu-build.sh
        builds beside the application) at the start of the flash, where the chip starts: the
        application is linked behind it (ACTIVE) and runs only through it, as on the board."""
        boot = self.elf.with_name("rc-bootloader")
        if not boot.is_file():
            raise EmulatorError(f"no bootloader beside {self.elf}: run scripts/emu-build.sh")
        return ["-device", f"loader,file={boot}"]

    # ------------------------------------------------------------------ lifecycle

    def start(self, stop_closed=False):
        """Start rc-sim and QEMU and run the firmware until its `ready` line. `stop_closed`: the
        cabinet's stop chain is closed from power-up (otherwise the stop input reads open until a
        test closes it, and FAILSAFE latches that at start)."""
        if shutil.which(QEMU) is None:
            raise EmulatorError(f"{QEMU} not found: run scripts/qemu-install.sh (or scripts/emu-test.sh)")
        if not RC_SIM.is_file():
            raise EmulatorError(f"{RC_SIM} missing: cargo build -p rc-tools --bin rc-sim")
        self.sim_log_path = self.workdir / "rc-sim.log"
        with open(self.sim_log_path, "wb") as sim_log:
            self.sim = subprocess.Popen(
                [str(RC_SIM), "--pty", "--axes", self.axes, "--slow-baud-is-break", "--log"]
                + (["--control"] if self.with_control else []) + self.sim_args,
                stdin=subprocess.PIPE if self.with_control else subprocess.DEVNULL,
                stdout=subprocess.PIPE, stderr=sim_log,
            )
        first = self.sim.stdout.readline().decode().split()
        # rc-sim's log times count from about now (it starts its clock right after this line).
        self.sim_started = time.monotonic()
        if len(first) != 2 or first[0] != "PTY":
            raise EmulatorError(f"rc-sim did not start: {first} {self.sim_log()}")
        bus_path = first[1]
        plc_port = self.plc_port = free_port()
        qtest_path = self.workdir / "qtest.sock"
        qmp_path = self.workdir / "qmp.sock"
        self.stderr_path = self.workdir / "qemu.stderr"
        args = [
            QEMU, "-M", "b-l475e-iot01a", "-accel", self.accel,
            "-nographic", "-monitor", "none", "-S",
            "-kernel", str(self.elf),
        ] + self.bootloader_args() + [
            "-semihosting-config", "enable=on,target=native",
            "-chardev", f"socket,id=plc,host=127.0.0.1,port={plc_port},server=on,wait=off,nodelay=on",
            "-chardev", f"serial,id=bus,path={bus_path}",
            "-serial", "null", "-serial", "chardev:plc", "-serial", "null", "-serial", "chardev:bus",
            "-qtest", f"unix:{qtest_path},server=on,wait=off", "-qtest-log", "/dev/null",
            "-qmp", f"unix:{qmp_path},server=on,wait=off",
            "-d", "guest_errors",
        ] + self.qemu_args
        self.args = args
        with open(self.stderr_path, "wb") as stderr:
            self.process = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=stderr)
        threading.Thread(target=self._read_stdout, daemon=True).start()
        wait_for(lambda: qtest_path.exists() and qmp_path.exists() or self._dead(), 20, "QEMU sockets")
        self._check_alive("starting")
        self.qtest = Qtest(qtest_path)
        self.qmp = Qmp(qmp_path)
        wait_for(lambda: _listening(plc_port) or self._dead(), 20, "QEMU's PLC socket")
        if self.with_plc:
            self.plc = Plc(plc_port)
        self._paint_stack()
        if stop_closed:
            self.set_pin(STOP_INPUT, True)
        self.qmp.execute("cont")
        # Bytes sent before the firmware has enabled its receivers are lost: wait for its word.
        self.wait_log("INFO  ready", 20)

    def inject(self, line):
        """A fault for rc-sim (`silent 2 on`, `alarm 2 E0`, `power 2 500`), or `where 2` (its log notes
        the axis' position: the simulator's truth); rc-sim --help."""
        if not self.with_control:
            raise EmulatorError("started without control=True")
        self.sim.stdin.write(line.encode() + b"\n")
        self.sim.stdin.flush()
        answer = self.sim.stdout.readline().decode().strip()
        if answer != "OK":
            raise EmulatorError(f"rc-sim refused {line!r}: {answer}")

    def _dead(self):
        return self.process.poll() is not None

    def _check_alive(self, doing):
        if self._dead():
            raise EmulatorError(f"QEMU exited ({self.process.returncode}) while {doing}:\n{self.stderr()}")

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

    def plc_pty(self):
        """A pseudo-terminal bridged to the PLC line's socket (for masters that open a serial
        device, such as libmodbus and mbpoll): its path. Only without `plc=True`."""
        if self.with_plc:
            raise EmulatorError("the PLC line is taken by pymodbus: start with plc=False")
        master, slave = pty.openpty()
        tty.setraw(slave)
        path = os.ttyname(slave)
        sock = connect(("127.0.0.1", self.plc_port))
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._bridge = (master, slave, sock)
        threading.Thread(target=_bridge, args=(master, sock), daemon=True).start()
        return path

    def stop(self):
        hwm = None
        try:
            if self.qtest is not None and not self._dead() and self.measure_stack:
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
        """[bottom, top) of the stack: cortex-m-rt's `_stack_end` and `_stack_start`. With flip-link
        (.cargo/config.toml) the bottom is the start of RAM and the top lies right below `.data`;
        with cortex-m-rt's own layout they would be the end of the statics and the end of RAM. Nothing
        else lives there before the firmware starts."""
        return self.symbols["_stack_end"], self.symbols["_stack_start"]

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
        """Makes the gateway task panic (emulator build only: `EMU_PANIC` in src/emu.rs)."""
        self.qtest.cmd(f"writeb {self.symbols['EMU_PANIC']:#x} 0x1")

    def request_stack_overflow(self):
        """Makes the firmware recurse without bound on its next wake (emulator build only:
        `EMU_OVERFLOW` in src/emu.rs). Its stack high-water mark is then the whole stack region, not
        a figure of the firmware's: `stop()` does not measure it."""
        self.measure_stack = False
        self.qtest.cmd(f"writeb {self.symbols['EMU_OVERFLOW']:#x} 0x1")

    NMI, UNBOUND_IRQ = 1, 2

    def request_fault(self, fault):
        """Raises `Emulator.NMI` (SCB ICSR NMIPENDSET) or `Emulator.UNBOUND_IRQ` (an interrupt
        no handler is bound to, enabled and pended in the NVIC) on the firmware's next wake
        (emulator build only: `EMU_FAULT_REQUEST` in src/emu.rs). The handler forces the outputs
        safe and then holds until `release_fault()` (10 s at most) before it resets the machine."""
        self.qtest.cmd(f"writeb {self.symbols['EMU_FAULT_REQUEST']:#x} {fault:#x}")

    def release_fault(self):
        """Lets a held fault handler reset the machine (`EMU_FAULT_SEEN` in src/emu.rs)."""
        self.qtest.cmd(f"writeb {self.symbols['EMU_FAULT_SEEN']:#x} 0x1")

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


class Pins:
    """A PLC's digital outputs wired to the gateway's inputs: levels held until changed."""

    def __init__(self, emu):
        self.emu = emu
        self.word = 0

    def set(self, bit, on):
        self.word = self.word | 1 << bit if on else self.word & ~(1 << bit)
        self.emu.set_pin(INPUTS[bit], on)

    def pulse(self, bit, seconds=0.1):
        """ON long enough for the input filter to see it, then OFF."""
        self.set(bit, True)
        time.sleep(seconds)
        self.set(bit, False)

    def select(self, point):
        """PC1-PC32: the point number in binary."""
        for bit in range(6):
            self.set(PC1 + bit, point >> bit & 1)


def _bridge(fd, sock):
    """Copy bytes between a pseudo-terminal's master side and a socket until either closes."""
    try:
        while True:
            ready, _, _ = select.select([fd, sock], [], [])
            if fd in ready:
                try:
                    data = os.read(fd, 4096)
                except OSError:  # EIO: no process has the slave open at the moment
                    time.sleep(0.01)
                    data = b""
                if data:
                    sock.sendall(data)
            if sock in ready:
                data = sock.recv(4096)
                if not data:
                    return
                os.write(fd, data)
    except OSError:
        return


def _listening(port):
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1):
            return True
    except OSError:
        return False


def elf_symbols(path):
    with open(path, "rb") as f:
        table = ELFFile(f).get_section_by_name(".symtab")
        wanted = ("_stack_end", "_stack_start", "__sheap", "__ebss", "__sbss", "__sdata")
        found = {}
        for symbol in table.iter_symbols():
            if symbol.name in wanted:
                found[symbol.name] = symbol["st_value"]
            else:  # mangled: rc_gateway::emu::qemu::EMU_PANIC, ...::requests::EMU_OVERFLOW
                for name in ("EMU_PANIC", "EMU_STALL", "EMU_OVERFLOW", "EMU_BUSY_US", "EMU_CLOCK_US",
                             "EMU_STOP_WAKES", "EMU_CSTR_SPAN_US", "EMU_PULSE_MASK",
                             "EMU_FAULT_REQUEST", "EMU_FAULT_SEEN"):
                    if name in symbol.name:
                        found[name] = symbol["st_value"]
        return found


def modbus_only(emulator, axes):
    """Commission the gateway as a Modbus-only installation, with pymodbus on the PLC line:
    watchdog off, no PIO axis, `axes` enabled with lead 8.00 mm and motor-end homing (the
    simulated actuator), APPLY; returns once every axis is online. The line is free afterwards."""
    from plc import G_PIO_AXIS, G_WATCHDOG, GATEWAY_UNIT, LINK, LINK_ONLINE, PNOW, ModbusError, unit

    plc = Plc(emulator.plc_port)
    try:
        plc.write(GATEWAY_UNIT, G_WATCHDOG, 0)
        plc.write(GATEWAY_UNIT, G_PIO_AXIS, 0xFFFF)
        for axis in axes:
            plc.write(GATEWAY_UNIT, 0x0100 + 8 * axis, [1, 800, 7])  # AXISCFG: enabled, lead, home

        def applied():
            try:
                plc.write(GATEWAY_UNIT, 0x000A, 1)  # APPLY; 03 while the bus is busy
                return True
            except ModbusError:
                return False

        wait_for(applied, 20, "APPLY taken")
        def status_readable(axis):
            try:  # 04 until the gateway has read the axis' position once
                return plc.read(unit(axis), PNOW, 8) is not None
            except ModbusError:
                return False

        for axis in axes:
            wait_for(lambda: plc.read(unit(axis), LINK)[0] == LINK_ONLINE, 30, f"axis {axis} online")
            wait_for(lambda: status_readable(axis), 10, f"axis {axis}: status readable")
    finally:
        plc.close()


def main():
    import argparse

    parser = argparse.ArgumentParser(description="The firmware in QEMU with simulated axes; the PLC line on a PTY.")
    parser.add_argument("elf", help="the emulator build (scripts/emu-build.sh prints its path)")
    parser.add_argument("--axes", default="1", help="rc-sim --axes (default: 1, axis 0)")
    parser.add_argument("--workdir", default=str(ROOT / "target" / "emu" / "run"))
    parser.add_argument("--modbus-only", action="store_true",
                        help="stop chain closed from power-up; commission every axis of --axes (a count "
                        "or a range a-b) over Modbus: watchdog off, no PIO axis, lead 8 mm, APPLY")
    parser.add_argument("sim_args", nargs="*", help="more rc-sim options, after --")
    args = parser.parse_args()
    workdir = Path(args.workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    emulator = Emulator(args.elf, workdir, args.axes, sim_args=args.sim_args, plc=False)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    try:
        emulator.start(stop_closed=args.modbus_only)
        if args.modbus_only:
            first, _, last = args.axes.partition("-")
            axes = range(int(first), int(last) + 1) if last else range(int(first))
            modbus_only(emulator, list(axes))
        print(f"PLC {emulator.plc_pty()}", flush=True)
        print(f"BUS LOG {emulator.sim_log_path}", flush=True)
        threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
        while not stop.wait(0.2):
            emulator._check_alive("running")
    finally:
        emulator.stop()


if __name__ == "__main__":
    main()
