"""The gateway's job without hardware: the real firmware ELF (its emulator build) in QEMU, simulated
Robo Cylinder controllers on its RS485 bus (rc-sim), and a scripted PLC on its Modbus line
(pymodbus) and on its discrete inputs (QEMU's GPIO). Run it through `scripts/demo.sh`, which
installs and builds what this needs; `scripts/demo.sh --help` lists the knobs.

The sequence is what a machine builder does on a first day: commission the axes (AXISCFG, APPLY,
the point table), servo on and home every axis, move to points, a synchronized start, a jog, one
axis driven by wire only (SON, HOME, PC1-PC32 + CSTR, as a PLC's digital outputs would), a cut
wire and an alarm on one axis and their recovery, then production moves for --duration seconds.
Each step waits for what the PLC would see (registers and output pins), with generous limits; a
step that does not get there fails the demo (exit status 1). A live table shows every axis as
the PLC reads it; a summary ends the run.
"""

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "pyshared"))

from emu import (  # noqa: E402
    CSTR, HEND, HOME, LED_ALARM, LED_LINK, LINK_OUT, PEND, SON, STOP_INPUT, STP_N, SV, Emulator,
    EmulatorError, Pins,
)
from pymodbus.exceptions import ModbusException  # noqa: E402

from plc import (  # noqa: E402
    CMST, COIL_ALRS, DONE, DRG1, DRG1_CSTR, DRG1_HOME, DRG1_SON, DSS1_ALMH, DSS1_HEND,
    DSS1_PEND, DSS1_SV, FAILED, G_FAILSAFE, G_PIO_AXIS, G_SYNC_MASK, G_SYNC_START, G_SYNC_STATUS,
    G_WATCHDOG, GATEWAY_UNIT, ILLEGAL_DATA_VALUE, LINK_OFFLINE, LINK_ONLINE, PNOW, POSR, SERVER_FAILURE,
    ModbusError,
    unit,
)

RATES = (9600, 19200, 38400, 57600, 115200)
FAULTS = ("offline", "alarm")
# Gateway unit registers the demo uses beyond plc.py's (README: register map).
G_BUSBAUD, G_APPLY, G_AXISCFG, G_DIAG, G_PLCLINK = 0x0007, 0x000A, 0x0100, 0x0400, 0x0510
DSSE_MOVE = 1 << 5
ROW = 0x1000  # position table: row n at 0x1000 + 16 n
# Points written to every axis: (point, position 0.01 mm, speed 0.01 mm/s).
POINTS = ((1, 10_00, 100_00), (2, 60_00, 150_00), (3, 35_00, 80_00))
ALARM_CODE = "E0"  # injected on one axis by --faults alarm


def parse_args(argv):
    parser = argparse.ArgumentParser(
        prog="scripts/demo.sh",
        description=__doc__.split("\n\n")[0].replace("\n", " "),
        epilog="Without a terminal (output to a file or a pipe) the table is printed at the end "
        "of each step instead of redrawn. scripts/demo.sh --host-gateway runs the same gateway "
        "code on the PC (in virtual time) instead of the firmware in QEMU.",
    )
    parser.add_argument("--axes", type=int, default=4, choices=range(2, 17), metavar="N",
                        help="simulated axes 0..N-1 on the bus, 2-16 (default 4); the last one is "
                        "driven through the discrete inputs")
    parser.add_argument("--baud", type=int, default=115200, choices=RATES,
                        help="RS485 bus rate the gateway establishes (default 115200)")
    parser.add_argument("--duration", type=float, default=8.0, metavar="SECONDS",
                        help="production moves at the end, seconds (default 8)")
    parser.add_argument("--faults", default="offline,alarm",
                        help="faults to inject and recover: a comma list of offline (a cut wire), "
                        "alarm (error E0 on a controller), or none (default: offline,alarm)")
    parser.add_argument("--elf", default=None, help="the firmware's emulator build (scripts/demo.sh passes it)")
    parser.add_argument("--plain", action="store_true", help="never redraw the table in place")
    args = parser.parse_args(argv)
    faults = [f for f in args.faults.split(",") if f and f != "none"]
    bad = [f for f in faults if f not in FAULTS]
    if bad:
        parser.error(f"--faults: unknown {', '.join(bad)} (choose from {', '.join(FAULTS)}, none)")
    args.faults = faults
    if args.elf is None:
        parser.error("--elf is required (run the demo through scripts/demo.sh)")
    return args


def alarm_texts():
    """Alarm code -> text, from the codec's own table (`rcframe alarm`)."""
    rcframe = ROOT / "target" / "debug" / "rcframe"
    out = subprocess.run([str(rcframe), "alarm"], capture_output=True, text=True, timeout=30, check=True)
    return {int(row["code"], 16): row["text"] for row in map(json.loads, out.stdout.splitlines())}


class StepFailed(Exception):
    pass


class Demo:
    def __init__(self, args, emu):
        self.args = args
        self.emu = emu
        self.plc = emu.plc
        self.pins = Pins(emu)
        self.axes = list(range(args.axes))
        self.enabled = [0]  # the firmware's defaults; commissioning enables the rest
        self.pio_axis = self.axes[-1]
        self.modbus_axes = self.axes[:-1]
        self.texts = alarm_texts()
        self.tty = sys.stdout.isatty() and not args.plain
        self.events = []
        self.steps = []
        self.state = {}
        self.moves_done = 0
        self.started = time.monotonic()

    # ------------------------------------------------------------------ what the PLC sees

    def refresh(self):
        """Read every axis as a PLC would: status block, command state, bus counters."""
        for axis in self.enabled:
            cmst, _cmer, link, cmct = self.plc.read(unit(axis), CMST, 4)
            diag = self.plc.read(GATEWAY_UNIT, G_DIAG + 16 * axis, 8)
            state = {"link": link, "cmst": cmst, "cmct": cmct,
                     "frames": diag[0] << 16 | diag[1], "timeouts": diag[4] << 16 | diag[5],
                     "servo": False, "homed": False, "moving": False, "pend": False, "alarm": 0, "pos": None}
            try:
                pnow_hi, pnow_lo, almc, _dipm, _dopm, dss1, _dss2, dsse = self.plc.read(unit(axis), PNOW, 8)
            except ModbusError as error:  # 04 until the axis has answered once
                if error.code != SERVER_FAILURE:
                    raise
            else:
                pnow = pnow_hi << 16 | pnow_lo
                state.update({
                    "servo": bool(dss1 & DSS1_SV), "homed": bool(dss1 & DSS1_HEND),
                    "moving": bool(dsse & DSSE_MOVE), "pend": bool(dss1 & DSS1_PEND),
                    "alarm": almc if dss1 & DSS1_ALMH else 0,
                    "pos": (pnow - (1 << 32) if pnow & 0x8000_0000 else pnow) / 100,
                })
            self.state[axis] = state
        self.draw()

    def table(self):
        head = f"{'axis':>4} {'unit':>4} {'driven by':<9} {'online':<7} {'servo':<5} {'homed':<5} " \
               f"{'moving':<6} {'pos mm':>8} {'cmds':>4} {'frames':>7} {'t/o':>4}  alarm"
        lines = [head, "-" * len(head)]
        for axis in self.axes:
            s = self.state.get(axis)
            if s is None:
                continue
            online = {LINK_ONLINE: "yes", LINK_OFFLINE: "NO"}.get(s["link"], "-")
            pos = "-" if s["pos"] is None else f"{s['pos']:.2f}"
            alarm = f"{s['alarm']:02X} {self.texts.get(s['alarm'], '')}" if s["alarm"] else ""
            lines.append(
                f"{axis:>4} {unit(axis):>4} {'wires' if axis == self.pio_axis else 'Modbus':<9} "
                f"{online:<7} {'on' if s['servo'] else 'off':<5} {'yes' if s['homed'] else 'no':<5} "
                f"{'yes' if s['moving'] else '':<6} {pos:>8} {s['cmct']:>4} {s['frames']:>7} "
                f"{s['timeouts']:>4}  {alarm}")
        leds = f"LEDs: link {'on' if self.emu.odr(LED_LINK) else 'off'}, alarm {'on' if self.emu.odr(LED_ALARM) else 'off'}"
        outputs = self.emu.outputs()
        pio = " ".join(name for name, bit in (("SV", SV), ("HEND", HEND), ("PEND", PEND), ("LINK", LINK_OUT))
                       if outputs >> bit & 1)
        lines.append(f"{leds}; output pins of axis {self.pio_axis}: {pio or '-'}, PM {outputs & 0xF}")
        return lines

    def draw(self, force=False):
        if not self.tty and not force:
            return
        elapsed = time.monotonic() - self.started
        out = []
        if self.tty:
            out.append("\x1b[H\x1b[J")
        out.append(f"rc-gateway firmware in QEMU, {len(self.axes)} simulated axes at {self.args.baud} bit/s — {elapsed:5.1f} s\n")
        out.extend(line + "\n" for line in self.table())
        if self.tty:
            out.append("\n")
            out.extend(f"  {line}\n" for line in self.events[-12:])
        sys.stdout.write("".join(out))
        sys.stdout.flush()

    def say(self, text):
        line = f"{time.monotonic() - self.started:6.1f} s  {text}"
        self.events.append(line)
        if not self.tty:
            print(line, flush=True)

    # ------------------------------------------------------------------ steps

    def wait(self, predicate, timeout, what):
        """Refresh the table until `predicate()` holds; at most `timeout` s."""
        deadline = time.monotonic() + timeout
        while True:
            self.refresh()
            if predicate():
                return
            if time.monotonic() >= deadline:
                raise StepFailed(f"timed out after {timeout} s waiting for {what}")
            time.sleep(0.05)

    def step(self, name, function):
        self.say(f"== {name}")
        began = time.monotonic()
        try:
            function()
        except (StepFailed, ModbusError, ModbusException, AssertionError) as error:
            self.steps.append((name, False, time.monotonic() - began, str(error)))
            self.say(f"   FAILED: {error}")
            self.draw(force=not self.tty)
            return False
        self.steps.append((name, True, time.monotonic() - began, ""))
        self.draw(force=not self.tty)
        return True

    def all_of(self, axes, key, value=True):
        return lambda: all(self.state[a][key] == value for a in axes)

    def commission(self):
        self.emu.set_pin(STOP_INPUT, True)  # the cabinet's stop chain closed
        self.pins.set(STP_N, True)  # *STP ON: the wired axis may move
        # The stop input was open at power-up: latched in FAILSAFE until acknowledged.
        self.plc.acknowledge()
        self.plc.write(GATEWAY_UNIT, G_WATCHDOG, 2000)
        self.say("   FAILSAFE acknowledged, PLC watchdog 2000 ms")
        for axis in self.axes[1:]:
            self.plc.write(GATEWAY_UNIT, G_AXISCFG + 8 * axis, 1)
        self.plc.write(GATEWAY_UNIT, G_BUSBAUD, self.args.baud // 100)
        self.plc.write(GATEWAY_UNIT, G_PIO_AXIS, self.pio_axis)
        self.say(f"   AXISCFG: axes 0-{self.axes[-1]} enabled; BUSBAUD {self.args.baud}; PIOAXIS {self.pio_axis}")
        deadline = time.monotonic() + 20
        while True:  # APPLY is refused (03) while the bus is busy
            try:
                self.plc.write(GATEWAY_UNIT, G_APPLY, 1)
                self.enabled = self.axes
                break
            except ModbusError as refused:
                if refused.code != ILLEGAL_DATA_VALUE or time.monotonic() > deadline:
                    raise
                self.refresh()
        self.say("   APPLY: break, communication change, every controller at the new rate")
        self.wait(lambda: all(self.state[a]["link"] == LINK_ONLINE for a in self.axes), 20 + 2 * len(self.axes),
                  "every axis online")
        for axis in self.axes:
            for point, position, speed in POINTS:
                row = [position >> 16, position & 0xFFFF, 0, 10, speed >> 16, speed & 0xFFFF,
                       0, 0, 0, 0, 30, 30, 0, 0, 0]
                self.plc.write(unit(axis), ROW + 16 * point, row)
        self.say("   position table: points 1-3 written to every axis (compared, stored with V5, verified)")
        self.wait(lambda: all(self._row_stored(a, p, pos) for a in self.axes for p, pos, _ in POINTS), 20,
                  "rows stored")

    def _row_stored(self, axis, point, position):
        try:
            hi, lo = self.plc.read(unit(axis), ROW + 16 * point, 2)
        except ModbusError:  # 04 while the row is written or fetched
            return False
        return (hi << 16 | lo) == position

    def servo_and_home(self):
        for axis in self.modbus_axes:
            self.plc.write(unit(axis), DRG1, DRG1_SON)
        self.wait(self.all_of(self.modbus_axes, "servo"), 15, "servo on")
        for axis in self.modbus_axes:
            self.plc.write(unit(axis), DRG1, DRG1_SON | DRG1_HOME)
        self.say(f"   DRG1 SON+HOME to units {', '.join(str(unit(a)) for a in self.modbus_axes)}")
        self.wait(self.all_of(self.modbus_axes, "homed"), 30, "HEND on every axis")
        for axis in self.modbus_axes:
            self.plc.write(unit(axis), DRG1, DRG1_SON)

    def start_move(self, axis, point):
        self.plc.write(unit(axis), POSR, point)
        self.plc.write(unit(axis), DRG1, DRG1_SON | DRG1_CSTR)
        self.plc.write(unit(axis), DRG1, DRG1_SON)

    def at(self, axes, position):
        return lambda: all(self.state[a]["pend"] and self.state[a]["pos"] is not None
                           and abs(self.state[a]["pos"] - position / 100) < 0.02
                           and self.state[a]["cmst"] in (DONE, FAILED) for a in axes)

    def move_to_points(self):
        for i, axis in enumerate(self.modbus_axes):
            point, position, _ = POINTS[i % len(POINTS)]
            self.start_move(axis, point)
            self.say(f"   unit {unit(axis)}: POSR {point} + CSTR")
        for i, axis in enumerate(self.modbus_axes):
            _, position, _ = POINTS[i % len(POINTS)]
            self.wait(self.at([axis], position), 20, f"axis {axis} at {position / 100:.2f} mm")
        self.moves_done += len(self.modbus_axes)

    def synchronized_start(self):
        point, position, _ = POINTS[1]
        mask = sum(1 << a for a in self.modbus_axes)
        for axis in self.modbus_axes:
            self.plc.write(unit(axis), POSR, point)
        self.plc.write(GATEWAY_UNIT, G_SYNC_MASK, mask)
        self.plc.write(GATEWAY_UNIT, G_SYNC_START, 1)
        self.say(f"   SYNCMASK {mask:#06x}, SYNCSTART: every axis buffers its move, then one start for all")
        self.wait(lambda: self.plc.read(GATEWAY_UNIT, G_SYNC_STATUS)[0] == 2, 15, "SYNCSTAT done")
        self.wait(self.at(self.modbus_axes, position), 20, f"every axis at {position / 100:.2f} mm")
        self.moves_done += len(self.modbus_axes)

    def jog(self):
        axis = self.modbus_axes[0]
        start = self.state[axis]["pos"]
        for step in (5_00, 5_00, -10_00):
            self.plc.direct(axis, step, speed=20_00, registers=9, ctlf=1 << 3)  # CTLF b3: incremental
            self.say(f"   unit {unit(axis)}: incremental move {step / 100:+.2f} mm")
            self.wait(lambda: self.state[axis]["cmst"] in (DONE, FAILED) and self.state[axis]["pend"], 15,
                      "the jog step done")
        if abs(self.state[axis]["pos"] - start) > 0.02:
            raise StepFailed(f"jogged back to {self.state[axis]['pos']:.2f} mm, not {start:.2f} mm")

    def wired_axis(self):
        axis = self.pio_axis
        output = lambda bit: self.emu.outputs() >> bit & 1  # noqa: E731
        self.pins.set(SON, True)
        self.say(f"   SON input ON (axis {axis})")
        self.wait(lambda: output(SV), 15, "SV output")
        self.pins.pulse(HOME)
        self.say("   HOME input pulsed")
        self.wait(lambda: output(HEND), 30, "HEND output")
        point, position, _ = POINTS[2]
        self.pins.select(point)
        self.pins.pulse(CSTR)
        self.say(f"   PC1-PC32 = {point}, CSTR pulsed")
        self.wait(lambda: output(PEND) and self.emu.outputs() & 0xF == point, 20, f"PEND and PM = {point}")

    def cut_wire(self):
        axis = self.modbus_axes[-1]
        self.emu.inject(f"silent {axis} on")
        self.say(f"   rc-sim: axis {axis} stops answering (a cut wire)")
        self.wait(lambda: self.state[axis]["link"] == LINK_OFFLINE, 15, f"axis {axis} offline")
        others = [a for a in self.axes if a != axis]
        if not all(self.state[a]["link"] == LINK_ONLINE for a in others):
            raise StepFailed("another axis went offline too")
        self.emu.inject(f"silent {axis} off")
        self.say(f"   rc-sim: axis {axis} answers again; the gateway's rejoin try brings it back")
        self.wait(lambda: self.state[axis]["link"] == LINK_ONLINE, 30, f"axis {axis} back online")

    def alarm(self):
        axis = self.modbus_axes[0]
        code = int(ALARM_CODE, 16)
        self.emu.inject(f"alarm {axis} {ALARM_CODE}")
        self.say(f"   rc-sim: axis {axis} raises {ALARM_CODE} ({self.texts.get(code, '?')})")
        self.wait(lambda: self.state[axis]["alarm"] == code, 10, f"ALMC {ALARM_CODE}")
        self.plc.coil(unit(axis), COIL_ALRS, True)
        self.plc.coil(unit(axis), COIL_ALRS, False)
        self.say(f"   unit {unit(axis)}: ALRS")
        self.wait(lambda: self.state[axis]["alarm"] == 0, 10, "alarm cleared")
        # The alarm took the servo off; SON is a level the PLC writes again.
        self.plc.write(unit(axis), DRG1, 0)
        self.plc.write(unit(axis), DRG1, DRG1_SON)
        self.wait(lambda: self.state[axis]["servo"], 10, "servo on again")

    def production(self):
        end = time.monotonic() + self.args.duration
        turn = 0
        while time.monotonic() < end:
            point, position, _ = POINTS[turn % 2]
            for axis in self.modbus_axes:
                self.start_move(axis, point)
            self.wait(self.at(self.modbus_axes, position), 20, f"every axis at point {point}")
            self.moves_done += len(self.modbus_axes)
            turn += 1

    def summary(self):
        print()
        print("Summary")
        for name, ok, seconds, why in self.steps:
            print(f"  {'ok  ' if ok else 'FAIL'} {name:<50} {seconds:5.1f} s  {why}")
        try:
            plclink = self.plc.read(GATEWAY_UNIT, G_PLCLINK, 8)
        except Exception as error:  # the emulator is gone
            print(f"  (counters not read: {error})")
            return
        u32 = lambda i: plclink[2 * i] << 16 | plclink[2 * i + 1]  # noqa: E731
        frames = sum(s["frames"] for s in self.state.values())
        timeouts = sum(s["timeouts"] for s in self.state.values())
        cut = " (the cut wire's included)" if "offline" in self.args.faults else ""
        print(f"  moves completed: {self.moves_done}; bus frames sent: {frames}, time-outs: {timeouts}{cut}")
        print(f"  Modbus frames received: {u32(0)}, CRC errors: {u32(1)}, exceptions: {u32(2)}, replies: {u32(3)}")
        commands = len(self.emu.bus_commands())
        print(f"  rc-sim: {commands} commands received on the bus ({self.emu.sim_log_path})")


def main(argv=None):
    args = parse_args(argv if argv is not None else sys.argv[1:])
    workdir = ROOT / "target" / "demo"
    workdir.mkdir(parents=True, exist_ok=True)
    emu = Emulator(args.elf, workdir, f"0-{args.axes - 1}", control=True)
    print(f"Starting QEMU (b-l475e-iot01a) with {args.elf} and {args.axes} simulated axes ...", flush=True)
    ok = False
    demo = None
    hwm = None
    try:
        emu.start()
        demo = Demo(args, emu)
        for line in emu.log():
            demo.say(f"firmware: {line}")
        steps = [
            ("commission: axes, bus rate, PIO axis, point table", demo.commission),
            ("servo on and home every Modbus axis", demo.servo_and_home),
            ("move to points (POSR + CSTR)", demo.move_to_points),
            ("synchronized start", demo.synchronized_start),
            ("jog (incremental moves)", demo.jog),
            (f"axis {demo.pio_axis} by wire: SON, HOME, PC + CSTR", demo.wired_axis),
        ]
        if "offline" in args.faults:
            steps.append(("fault: a cut wire, and the axis rejoining", demo.cut_wire))
        if "alarm" in args.faults:
            steps.append((f"fault: alarm {ALARM_CODE}, reset with ALRS", demo.alarm))
        steps.append((f"production moves for {args.duration:g} s", demo.production))
        ok = True
        for name, function in steps:
            if not demo.step(name, function):
                ok = False
                break
    except EmulatorError as error:
        print(f"demo: the emulator failed: {error}", file=sys.stderr)
        ok = False
    finally:
        if demo is not None:
            demo.summary()
        hwm = emu.stop()
    if hwm is not None:
        print(f"  firmware stack high-water mark: {hwm} bytes")
    if not ok:
        print("---- firmware log ----", file=sys.stderr)
        print("\n".join(emu.log()[-20:]), file=sys.stderr)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
