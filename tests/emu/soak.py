"""A soak of the real firmware in QEMU: a seeded random PLC against simulated controllers with
bus faults, checked by an oracle against the simulator, for a set time (scripts/soak.sh runs it;
CI runs two minutes of it in scripts/test-all.sh).

The world: the emulator build in QEMU (tests/pyshared/emu.py), `rc-sim` with 4 axes dropping,
corrupting and delaying replies (a delay longer than the firmware's reply time-out: a retry meets a
late reply) and injecting noise, and axis 3 going silent (a cut wire) now and then and coming
back. The gateway is commissioned as a Modbus-only installation (stop input closed, FAILSAFE
acknowledged, PIOAXIS none, lead 8 mm so that one pulse is 0.01 mm) with the PLC watchdog ON at
1000 ms once the axes are homed (off before: the start-up's pauses are not a PLC's polling). The
PLC (pymodbus, seeded) then loops: direct moves (absolute, relative from rest), position-table
rows written and read back, moves to those points (POSR + CSTR), stops (STOP coil, DRG1 STP held,
a STOP broadcast on unit 0), synchronized starts (SYNCMASK/SYNCSTART), refused requests (out of
the stroke; moves while STP is held) and reads, polling at least every 200 ms.

The oracle (each check counts what it passed; a violation ends the run with exit status 1):
  (a) done-at-target: CMST 2 (done) for a move only if PNOW is within the move's band of its
      target, and so is the simulator's own position (rc-sim's `where`, asked when the PLC sees
      "done"); once the axis rests, PNOW is the target exactly.
  (b) nothing-after-stop: after a stop (its `d` on the bus) or a refused command (an exception,
      or CMST 3 with CMCT unchanged), no motion command for that axis (a, m, Q3, Q2, o, h with a
      motion, a `t` that runs one) reaches the bus until the PLC's next accepted command.
  (c) rest-position: once an axis rests (its command settled for 1 s, online, DSSE MOVE off and
      the simulated axis neither moving nor homing), PNOW equals the simulator's position.
  (d) watchdog: FAILSAFE bit 0 (the PLC watchdog) never set while the PLC talks. A host stall of
      QEMU looks like silence to the firmware: a trip is excused only if the PLC itself saw a
      gap of at least 70 % of WATCHDOG between two replies (counted and printed). Bit 1 (the stop
      input, closed all along) never.
  (e) alive: UPTIME never goes back, RESETCAUSE never changes, the firmware logs no panic,
      HardFault or second `ready`, and QEMU keeps running.

Known firmware defects are counted and printed (KNOWN DEFECT), not fatal unless `--strict`: a stop
that gives up a synchronized start after its `t` went out, before the gateway saw the axis move,
leaves PNOW at the position before the move (found by this soak, seed 2).

`--prove CHECK` (a-e) breaks that check's expectation on purpose, to show it can fire: the run
must then fail with that check's message (a: the target expected 0.50 mm off; b: a direct move
after a stop that the driver does not count as accepted; c: the simulator's position taken 1
pulse off; d: 1.5 s of silence the driver does not count as a gap; e: the firmware is made to
panic through qtest).
"""

import argparse
import random
import re
import signal
import sys
import time
import traceback
from collections import Counter, deque
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "pyshared"))

from pymodbus.exceptions import ModbusException  # noqa: E402

from emu import STOP_INPUT, Emulator  # noqa: E402
from plc import (  # noqa: E402
    CMST,
    COIL_STOP,
    DONE,
    DRG1,
    DRG1_CSTR,
    DRG1_HOME,
    DRG1_SON,
    DRG1_STP,
    DSS1_HEND,
    FAILED,
    G_FAILSAFE,
    G_PIO_AXIS,
    G_SYNC_MASK,
    G_SYNC_START,
    G_SYNC_STATUS,
    G_WATCHDOG,
    GATEWAY_UNIT,
    LINK,
    LINK_ONLINE,
    PNOW,
    POSR,
    TAKEN,
    ModbusError,
    adu,
    unit,
    wait_for,
)

AXES = 4
SILENT_AXIS = 3
WATCHDOG_MS = 1000
POLL_S = 0.2  # the PLC talks at least this often
G_UPTIME, G_RESETCAUSE, G_APPLY, AXISCFG, ROW = 0x0002, 0x001A, 0x000A, 0x0100, 0x1000
DSSE, DSSE_MOVE = 0x9007, 1 << 5
STROKE_USED = 70_00  # 0.01 mm: inside the firmware's default stroke and the simulator's
POINTS = range(1, 7)
# Fault rates for rc-sim: per reply (drop, delay), per byte (corrupt), per frame (noise). The delay
# is longer than the emulator build's reply time-out (Trt + 250 ms of slack): the reply comes while
# the firmware resends.
SIM_FAULTS = ["--drop", "0.01", "--corrupt", "0.0005", "--delay", "0.005", "--delay-ms", "300",
              "--noise", "0.002"]
MOTION = ("MoveAbsolute", "MoveRelative", "MoveToPoint", "Home")


class Violation(AssertionError):
    pass


def s32(hi, lo):
    value = (hi << 16) | lo
    return value - (1 << 32) if value & 0x8000_0000 else value


def row(position, speed, accel, band):
    return [position >> 16, position & 0xFFFF, band >> 16, band & 0xFFFF, speed >> 16, speed & 0xFFFF,
            0, 0, 0, 0, accel, accel, 0, 0, 0]


class BusLog:
    """rc-sim's frame log, read as it grows: per axis the motion commands, stops (`d`) and the
    answers to `where` (the simulated axis' own state), in rc-sim's time (seconds since it
    started)."""

    REQUEST = re.compile(r"\s*([\d.]+) >> Request \{ axis: Axis\((\d+)\), command: (\w+)(.*)\}$")
    WHERE = re.compile(r"\s*([\d.]+) -- where: axis (\d+) position (-?\d+) target (-?\d+) moving (\w+) "
                       r"homing (\w+)")

    def __init__(self, path):
        self.path = path
        self.offset = 0
        self.partial = b""
        self.motions = {a: [] for a in range(16)}  # (t, command)
        self.cancels = {a: [] for a in range(16)}
        self.wheres = {a: [] for a in range(16)}
        self.polls = {a: [] for a in range(16)}  # status polls (`n`)
        self.buffered = set()  # axes with a motion waiting for `t`
        self.requests = 0
        self.kinds = Counter()
        self.now = 0.0

    def update(self):
        with open(self.path, "rb") as f:
            f.seek(self.offset)
            data = f.read()
        self.offset += len(data)
        lines = (self.partial + data).split(b"\n")
        self.partial = lines.pop()
        for raw in lines:
            line = raw.decode(errors="replace")
            if " >> Request" in line:
                m = self.REQUEST.match(line)
                if not m:
                    continue
                t, axis, command, rest = float(m.group(1)), int(m.group(2)), m.group(3), m.group(4)
                self.now = t
                self.requests += 1
                self.kinds[command] += 1
                if command == "Status":
                    self.polls[axis].append(t)
                elif command in MOTION or (command == "EditToExecution" and "Position" in rest):
                    self.motions[axis].append((t, command))
                elif command == "Buffer":
                    # `Buffer(Buffered(MoveToPoint(PositionNo(5))))`; `h` with `n` cancels.
                    if any(m in rest for m in MOTION) or "EditToExecution(Position" in rest:
                        self.buffered.add(axis)
                        self.motions[axis].append((t, "Buffer"))
                    else:
                        self.buffered.discard(axis)
                elif command == "ExecuteBuffered":
                    for a in self.buffered:
                        self.motions[a].append((t, "ExecuteBuffered"))
                    self.buffered = set()
                elif command == "CancelMotion":
                    self.cancels[axis].append(t)
            elif " -- where: " in line:
                m = self.WHERE.match(line)
                self.wheres[int(m.group(2))].append({
                    "t": float(m.group(1)), "position": -int(m.group(3)), "target": -int(m.group(4)),
                    "moving": m.group(5) == "true", "homing": m.group(6) == "true"})


class Soak:
    def __init__(self, args, elf, workdir):
        self.args = args
        self.rng = random.Random(args.seed)
        self.seed = args.seed
        self.elf = elf
        self.workdir = workdir
        self.stats = Counter()  # PLC requests and commands by kind
        self.trace = deque(maxlen=60)  # the last PLC requests, in rc-sim's time
        self.refusals = Counter()
        self.checks = Counter()
        self.skips = Counter()
        self.sync_axes = set()  # the axes of a synchronized start still running (SYNCSTAT 1)
        self.known = []  # known firmware defects seen (not fatal without --strict)
        self.excused = []  # watchdog trips excused by a host stall: the gap the PLC saw, ms
        self.last_reply = None
        self.max_gap = 0.0
        self.axes = {a: self._fresh_axis() for a in range(AXES)}
        self.points = {a: {} for a in range(AXES)}  # point -> (position, band), as read back
        self.windows = []  # (b): quiet windows to check once the log has them
        self.silent = False
        self.next_silence = 0.0
        self.uptime = 0
        self.next_alive = 0.0
        self.resetcause = None

    @staticmethod
    def _fresh_axis():
        return {
            "cmd": None,  # the last accepted command: dict(kind, target, band, sent, cmct)
            "cmct": None,
            "settled": None,  # time the last command was seen settled (CMST 2/3), or None
            "window": None,  # open quiet window: dict(start_kind, sent, returned)
            "checked": True,  # rest check done since the last command
            "held": False,  # DRG1 STP held
        }

    # ------------------------------------------------------------------ Modbus, timed

    def _timed(self, what, function, *args):
        """One PLC request: counted, its reply time noted for the watchdog check (d), kept in the
        trace printed on a failure."""
        self.stats["plc requests"] += 1
        self.trace.append(f"{self.sim_time(time.monotonic()):9.3f} {what} {args[:3]}")
        try:
            result = function(*args)
        except ModbusError as error:
            self._replied()
            raise error
        except ModbusException as error:
            # No answer on a line without faults: counted; the request's outcome is unknown.
            self.stats["plc requests unanswered"] += 1
            self._replied()
            raise Unknown(what) from error
        self._replied()
        return result

    def _replied(self):
        now = time.monotonic()
        if self.last_reply is not None:
            self.max_gap = max(self.max_gap, now - self.last_reply)
        self.last_reply = now

    def read(self, u, address, count=1):
        return self._timed("read", self.plc.read, u, address, count)

    def write(self, u, address, values):
        return self._timed("write", self.plc.write, u, address, values)

    def coil(self, u, address, on):
        return self._timed("coil", self.plc.coil, u, address, on)

    def broadcast_stop(self):
        """FC05 STOP ON to unit 0: no reply; the next request follows after the frame gap."""
        self.stats["plc requests"] += 1
        sock = self.plc.client.socket
        self.trace.append(f"{self.sim_time(time.monotonic()):9.3f} broadcast STOP")
        sock.sendall(adu(0, 0x05, COIL_STOP >> 8, COIL_STOP & 0xFF, 0xFF, 0x00))
        time.sleep(0.05)

    # ------------------------------------------------------------------ start

    def sim_time(self, t):
        """rc-sim's clock for a driver time (monotonic)."""
        return t - self.t0

    def start(self):
        self.t0 = time.monotonic()
        self.emu = Emulator(self.elf, self.workdir, f"0-{AXES - 1}",
                            sim_args=SIM_FAULTS + ["--seed", str(self.seed)], control=True)
        self.emu.start()
        # rc-sim starts its clock right after its first line: a little after it, refined by
        # every `where`.
        self.t0 = self.emu.sim_started - 0.005
        self.plc = self.emu.plc
        self.log = BusLog(self.emu.sim_log_path)
        # The PLC watchdog off until the soak's PLC polls (seed 9001 once failed its start: the
        # watchdog, 1 s by default, tripped in a pause of the start-up, rc-sim's `where` or a
        # request pymodbus resent after its 1 s time-out; the latch held motion, and every HOME
        # was refused with CMER reason 12 until "axis 0 not homed").
        self.plc.write(GATEWAY_UNIT, G_WATCHDOG, 0)
        self.emu.set_pin(STOP_INPUT, True)
        wait_for(lambda: self.plc.read(GATEWAY_UNIT, G_FAILSAFE)[0] & 2, 5, "the stop latched at power-up")
        self.plc.acknowledge()
        self.plc.write(GATEWAY_UNIT, G_PIO_AXIS, 0xFFFF)
        for a in range(AXES):
            self.plc.write(GATEWAY_UNIT, AXISCFG + 8 * a, [1, 800, 7])

        def applied():
            try:
                self.plc.write(GATEWAY_UNIT, G_APPLY, 1)
                return True
            except ModbusError:
                return False

        wait_for(applied, 30, "APPLY taken")
        for a in range(AXES):
            wait_for(lambda: self._online(a), 60, f"axis {a} online")
        self.resetcause = self.plc.read(GATEWAY_UNIT, G_RESETCAUSE)[0]
        start = self.t0
        for a in range(AXES):
            self.where(a)
        print(f"soak: rc-sim's clock starts {(self.t0 - start) * 1000 + 5:.0f} ms after its first line", flush=True)
        for a in range(AXES):
            # With the bus faults on, a command may fail (no answer after the retries): again.
            for attempt in range(4):
                self.plc.write(unit(a), DRG1, DRG1_SON)
                self.plc.write(unit(a), DRG1, DRG1_SON | DRG1_HOME)
                outcome = self.plc.settle(a, 30)
                self.plc.write(unit(a), DRG1, DRG1_SON)
                if outcome == (DONE, 0) and self.plc.dss1(a) & DSS1_HEND:
                    break
                latched = self.plc.read(GATEWAY_UNIT, G_FAILSAFE)[0]
                print(f"soak: axis {a}: homing ended {outcome} (FAILSAFE {latched:#x}), again", flush=True)
                if outcome[1] >> 8 == 12:
                    # Refused for a latched fail-safe (CMER reason 12): acknowledged, as a PLC does.
                    self.plc.acknowledge()
            else:
                raise AssertionError(f"axis {a} not homed")
        self.plc.write(GATEWAY_UNIT, G_WATCHDOG, WATCHDOG_MS)
        self.last_reply = time.monotonic()
        self.max_gap = 0.0
        for a in range(AXES):
            self.axes[a]["cmct"] = self.read(unit(a), CMST, 4)[3]
            self.axes[a]["settled"] = time.monotonic()
            self.axes[a]["checked"] = False

    def _online(self, a):
        try:
            return self.plc.read(unit(a), LINK)[0] == LINK_ONLINE and self.plc.read(unit(a), PNOW, 2)
        except ModbusError:
            return False

    # ------------------------------------------------------------------ the loop

    def run(self):
        end = time.monotonic() + self.args.minutes * 60
        self.next_silence = time.monotonic() + self.rng.uniform(10, 30)
        report = time.monotonic() + 30
        proved = False
        begun = time.monotonic()
        while time.monotonic() < end:
            self.guard()
            self.silence()
            self.action()
            self.follow()
            if self.args.prove == "e" and not proved and time.monotonic() > begun + 15:
                self.emu.request_panic()
                proved = True
            if time.monotonic() > report:
                report += 30
                self.progress()
        # Let everything settle, then a last round of checks.
        if self.silent:
            self.emu.inject(f"silent {SILENT_AXIS} off")
            self.silent = False
        settle_end = time.monotonic() + 25
        while time.monotonic() < settle_end and not all(self._rest_checked(a) for a in range(AXES)):
            self.guard()
            self.follow()
            time.sleep(0.05)
        self.guard()
        self.close_windows(final=True)

    def _rest_checked(self, a):
        return self.axes[a]["checked"]

    def progress(self):
        elapsed = time.monotonic() - self.t0
        print(f"[{elapsed:6.0f} s] requests {self.stats['plc requests']}, bus {self.log.requests}, "
              f"checks {sum(self.checks.values())}, refusals {sum(self.refusals.values())}", flush=True)

    # ------------------------------------------------------------------ (d), (e)

    def guard(self):
        """Every loop: FAILSAFE (d); every few seconds UPTIME and RESETCAUSE, and the log (e)."""
        if self.args.prove == "d" and self.stats["plc requests"] > 300 and not self.stats["proved d"]:
            self.stats["proved d"] = 1
            time.sleep(1.5)
            self.last_reply = time.monotonic()  # the silence hidden from the gap bookkeeping
        try:
            latched, count = self.read(GATEWAY_UNIT, G_FAILSAFE, 2)
        except (ModbusError, Unknown):
            self.alive()
            raise
        gap, self.max_gap = self.max_gap, 0.0
        if latched & 2:
            raise Violation(f"(d) FAILSAFE bit 1 (the stop input) set: {latched:#x}, the input is closed")
        if latched & 1:
            if gap * 1000 < 0.7 * WATCHDOG_MS:
                raise Violation(f"(d) the PLC watchdog tripped (FAILSAFE {latched:#x}, FSCOUNT {count}) while "
                                f"the PLC talked: its longest gap between replies was {gap * 1000:.0f} ms")
            self.excused.append(round(gap * 1000))
            # The trip stopped every axis: a stop for each, then the acknowledgement.
            now = time.monotonic()
            for a in range(AXES):
                self.open_window(a, "watchdog stop", now - gap, now, stop=True)
            self.write(GATEWAY_UNIT, G_FAILSAFE, 0)
        else:
            self.checks["(d) watchdog quiet while polled"] += 1
        if time.monotonic() > self.next_alive:
            self.next_alive = time.monotonic() + 3
            self.alive()

    def alive(self):
        if self.emu._dead():
            raise Violation(f"(e) QEMU exited ({self.emu.process.returncode}): {self.emu.stderr()[-2000:]}")
        log = self.emu.log()
        bad = [line for line in log if "panic" in line or "HardFault" in line]
        if bad:
            raise Violation(f"(e) the firmware panicked: {bad[:3]}")
        readies = [line for line in log if "INFO  ready" in line]
        if len(readies) != 1:
            raise Violation(f"(e) the firmware started {len(readies)} times: {readies}")
        up = self.read(GATEWAY_UNIT, G_UPTIME, 2)
        up = (up[0] << 16) | up[1]
        cause = self.read(GATEWAY_UNIT, G_RESETCAUSE)[0]
        if up < self.uptime or cause != self.resetcause:
            raise Violation(f"(e) the firmware restarted: UPTIME {self.uptime} -> {up}, RESETCAUSE "
                            f"{self.resetcause} -> {cause}")
        self.uptime = up
        self.checks["(e) alive, no reset"] += 1

    # ------------------------------------------------------------------ faults on the bus

    def silence(self):
        """Axis 3 loses its wire for 2-6 s every 20-60 s."""
        now = time.monotonic()
        if now < self.next_silence:
            return
        if self.silent:
            self.emu.inject(f"silent {SILENT_AXIS} off")
            self.trace.append(f"{self.sim_time(now):9.3f} silent {SILENT_AXIS} off")
            self.silent = False
            self.next_silence = now + self.rng.uniform(20, 60)
        else:
            self.emu.inject(f"silent {SILENT_AXIS} on")
            self.trace.append(f"{self.sim_time(now):9.3f} silent {SILENT_AXIS} on")
            self.stats["silences injected"] += 1
            self.silent = True
            self.axes[SILENT_AXIS]["checked"] = True  # no rest check across a silence
            self.next_silence = now + self.rng.uniform(2, 6)

    # ------------------------------------------------------------------ the PLC's actions

    def action(self):
        r = self.rng.random()
        a = self.rng.randrange(AXES)
        if a in self.sync_axes and r < 0.55:
            # KNOWN DEFECT (reported with issue 24 item 7): a move taken for an axis of a running
            # synchronized start does not cancel it; its `t` still goes out and the axis drives
            # to its sync point after the newer move was done (seed 2024). A careful PLC leaves
            # the axes of a running start alone but for stops; so does this one.
            r = 0.9
        try:
            if r < 0.30:
                self.direct(a, relative=self.rng.random() < 0.3)
            elif r < 0.45:
                self.point_move(a)
            elif r < 0.55:
                self.table_write(a)
            elif r < 0.63:
                self.stop(a)
            elif r < 0.68:
                self.hold(a)
            elif r < 0.73:
                self.sync_start()
            elif r < 0.76:
                self.out_of_stroke(a)
            else:
                self.read(unit(a), PNOW, 8)
                time.sleep(self.rng.uniform(0, 0.1))
        except Unknown:
            # No answer: whatever it was may or may not have been taken.
            for axis in range(AXES):
                self.close_window(axis)
                self.axes[axis]["cmd"] = None

    def at_rest(self, a):
        s = self.axes[a]
        return s["cmd"] is None or s["settled"] is not None

    def direct(self, a, relative=False):
        s = self.axes[a]
        if relative and not (self.at_rest(a) and s["checked"] and s.get("pos") is not None):
            relative = False
        band = self.rng.choice([5, 10, 20])
        speed = self.rng.choice([20_00, 50_00, 100_00, 200_00])
        accel = self.rng.choice([20, 30, 50])
        if relative:
            here = s["pos"]
            target = self.rng.randrange(0, STROKE_USED + 1)
            distance = target - here
            p = distance & 0xFFFF_FFFF
            values = [p >> 16, p & 0xFFFF, 0, band, 0, speed, accel, 0, 8]
            kind = "relative move"
        else:
            target = self.rng.randrange(0, STROKE_USED + 1)
            values = [target >> 16, target & 0xFFFF, 0, band, speed >> 16, speed & 0xFFFF, accel]
            kind = "direct move"
        values[4:6] = [speed >> 16, speed & 0xFFFF]
        self.command(a, kind, target, band, lambda: self.write(unit(a), 0x9900, values))

    def point_move(self, a):
        if not self.points[a]:
            return self.table_write(a)
        point = self.rng.choice(sorted(self.points[a]))
        target, band = self.points[a][point]
        try:
            self.write(unit(a), POSR, point)
        except ModbusError as error:
            self.refusals[f"exception {error.code:02d}"] += 1
            return
        drg1 = DRG1_SON | (DRG1_STP if self.axes[a]["held"] else 0)
        self.command(a, "point move", target, band, lambda: self.write(unit(a), DRG1, drg1 | DRG1_CSTR))
        self.write(unit(a), DRG1, drg1)

    def command(self, a, kind, target, band, send):
        """A motion request: sent, then classified by CMCT as taken or refused."""
        s = self.axes[a]
        idle = self.at_rest(a)
        self.stats[kind] += 1
        sent = time.monotonic()
        try:
            send()
        except ModbusError as error:
            self.refusals[f"exception {error.code:02d}"] += 1
            if idle:
                self.open_window(a, f"{kind} refused with {error.code:02d}", sent, time.monotonic())
            return
        state, reason, _, cmct = self.read(unit(a), CMST, 4)
        if cmct == s["cmct"]:
            self.refusals[f"CMST 3 reason {reason >> 8}"] += 1
            if state != FAILED or reason >> 8 not in (9, 10, 12):
                raise Violation(f"(b) axis {a}: {kind} neither taken (CMCT {cmct}) nor refused: CMST {state} "
                                f"CMER {reason:#06x}")
            if idle:
                self.open_window(a, f"{kind} held (reason {reason >> 8})", sent, time.monotonic())
            return
        self.taken(a, kind, target, band, sent, cmct)
        self.note_state(a, state, reason)

    def taken(self, a, kind, target, band, sent, cmct):
        s = self.axes[a]
        s["cmct"] = cmct
        self.close_window(a, sent)
        if self.args.prove == "a":
            target += 50
        s["cmd"] = {"kind": kind, "target": target, "band": band, "sent": sent}
        s["mismatch"] = None
        s["settled"] = None
        s["checked"] = False
        s["pos"] = None
        self.stats["commands taken"] += 1

    def table_write(self, a):
        point = self.rng.choice(POINTS)
        position = self.rng.randrange(0, STROKE_USED + 1)
        band = self.rng.choice([5, 10, 20])
        values = row(position, self.rng.choice([30_00, 80_00, 150_00]), self.rng.choice([20, 30]), band)
        self.stats["table writes"] += 1
        self.points[a].pop(point, None)  # unknown until read back
        try:
            self.write(unit(a), ROW + 16 * point, values)
        except ModbusError as error:
            self.refusals[f"table write: exception {error.code:02d}"] += 1
            return
        deadline = time.monotonic() + 3
        while time.monotonic() < deadline:
            self.guard()
            try:
                back = self.read(unit(a), ROW + 16 * point, 15)
            except ModbusError as error:
                if error.code != 4:
                    raise Violation(f"axis {a}: row {point} read back: exception {error.code:02d}")
                time.sleep(0.05)
                continue
            if back[:6] == values[:6] and back[10] == values[10]:
                self.points[a][point] = (position, band)
                self.checks["table row read back as written"] += 1
            else:
                # A write that failed its verify (or lost to an offline axis) leaves the
                # controller's row: fine, as long as the read-back is what the controller has.
                self.stats["table writes not stored"] += 1
            return
        self.stats["table read-backs still 04 after 3 s"] += 1

    def stop(self, a):
        how = self.rng.choice(["STOP coil", "STOP coil", "broadcast STOP"])
        self.stats[how] += 1
        sent = time.monotonic()
        if how == "broadcast STOP":
            self.broadcast_stop()
            axes = range(AXES)
        else:
            self.coil(unit(a), COIL_STOP, True)
            axes = [a]
        for axis in axes:
            self.open_window(axis, how, sent, time.monotonic(), stop=True)
        if self.args.prove == "b" and self.stats["STOP coil"] > 3 and not self.stats["proved b"]:
            self.stats["proved b"] = 1
            self.write(unit(a), 0x9900, [0, 30_00, 0, 10, 0, 50_00, 30])  # not noted as taken

    def hold(self, a):
        """DRG1 STP held for a moment, a move tried meanwhile (held: CMST 3 reason 10), released."""
        s = self.axes[a]
        self.stats["STP held"] += 1
        sent = time.monotonic()
        try:
            self.write(unit(a), DRG1, DRG1_SON | DRG1_STP)
        except ModbusError as error:
            self.refusals[f"STP: exception {error.code:02d}"] += 1
            return
        s["held"] = True
        self.open_window(a, "DRG1 STP", sent, time.monotonic(), stop=True)
        until = time.monotonic() + self.rng.uniform(0.2, 1.5)
        tried = False
        while time.monotonic() < until:
            self.guard()
            if not tried:
                tried = True
                self.direct(a)
            time.sleep(0.05)
        self.write(unit(a), DRG1, DRG1_SON)
        s["held"] = False

    def sync_start(self):
        axes = [a for a in range(AXES) if self.points[a] and self.at_rest(a) and not self.axes[a]["held"]]
        if len(axes) < 2:
            return
        axes = self.rng.sample(axes, self.rng.randint(2, len(axes)))
        self.stats["sync starts"] += 1
        chosen = {}
        for a in axes:
            point = self.rng.choice(sorted(self.points[a]))
            try:
                self.write(unit(a), POSR, point)
            except ModbusError as error:
                self.refusals[f"POSR: exception {error.code:02d}"] += 1
                return
            chosen[a] = self.points[a][point]
        mask = sum(1 << a for a in axes)
        self.write(GATEWAY_UNIT, G_SYNC_MASK, mask)
        idle = {a: self.at_rest(a) for a in axes}
        sent = time.monotonic()
        try:
            self.write(GATEWAY_UNIT, G_SYNC_START, 1)
        except ModbusError as error:
            self.refusals[f"sync start: exception {error.code:02d}"] += 1
            for a in axes:
                if idle[a]:
                    self.open_window(a, f"sync start refused with {error.code:02d}", sent, time.monotonic())
            return
        for a in axes:
            state, reason, _, cmct = self.read(unit(a), CMST, 4)
            if cmct != self.axes[a]["cmct"]:
                self.taken(a, "sync start", chosen[a][0], chosen[a][1], sent, cmct)
                self.axes[a]["sync_since_check"] = True
                self.note_state(a, state, reason)
            else:
                self.refusals[f"sync start: axis CMST 3 reason {reason >> 8}"] += 1
        if self.read(GATEWAY_UNIT, G_SYNC_STATUS)[0] == 1:
            self.sync_axes = set(axes)

    def out_of_stroke(self, a):
        """A direct move beyond the stroke: exception 03, nothing on the bus."""
        self.stats["out-of-stroke moves"] += 1
        target = 100_01 + self.rng.randrange(0, 5000)
        values = [target >> 16, target & 0xFFFF, 0, 10, 0, 50_00, 30]
        sent = time.monotonic()
        try:
            self.write(unit(a), 0x9900, values)
        except ModbusError as error:
            self.refusals[f"exception {error.code:02d}"] += 1
            if self.at_rest(a):
                self.open_window(a, f"out-of-stroke move refused with {error.code:02d}", sent, time.monotonic())
            return
        raise Violation(f"axis {a}: a direct move to {target} (beyond the stroke) was taken")

    # ------------------------------------------------------------------ following commands

    def follow(self):
        """CMST of every axis with a command in flight; rest checks (c) for those settled."""
        now = time.monotonic()
        if self.sync_axes and self.read(GATEWAY_UNIT, G_SYNC_STATUS)[0] != 1:
            self.sync_axes = set()
        for a in range(AXES):
            s = self.axes[a]
            if s["cmd"] is not None and s["settled"] is None:
                state, reason, link, cmct = self.read(unit(a), CMST, 4)
                if cmct != s["cmct"]:
                    raise Violation(f"axis {a}: CMCT moved from {s['cmct']} to {cmct} without a command")
                self.note_state(a, state, reason)
            elif not s["checked"] and s["settled"] is not None and now - s["settled"] > 1.0:
                self.rest_check(a)
        self.close_windows()

    def note_state(self, a, state, reason):
        s = self.axes[a]
        if state == TAKEN or s["settled"] is not None:
            return
        now = time.monotonic()
        s["settled"] = now
        cmd = s["cmd"]
        if state == DONE:
            self.stats["commands done"] += 1
            hi, lo = self.read(unit(a), PNOW, 2)
            pnow = s32(hi, lo)
            if abs(pnow - cmd["target"]) > cmd["band"] + 1:
                raise Violation(f"(a) axis {a}: {cmd['kind']} done (CMST 2) at PNOW {pnow}, target "
                                f"{cmd['target']} band {cmd['band']}")
            self.checks["(a) done: PNOW within the band"] += 1
            truth = self.where(a)
            if abs(truth["position"] - cmd["target"]) > cmd["band"] + 1:
                raise Violation(f"(a) axis {a}: {cmd['kind']} done, the simulator's position "
                                f"{truth['position']}, target {cmd['target']} band {cmd['band']} "
                                f"(rc-sim log at {truth['t']:.3f} s)")
            self.checks["(a) done: simulator within the band"] += 1
        elif state == FAILED:
            self.refusals[f"{cmd['kind']} failed, reason {reason >> 8}"] += 1
            cmd["failed"] = True
            cmd["reason"] = reason >> 8
        else:
            raise Violation(f"axis {a}: CMST {state} after a command")

    def rest_check(self, a):
        """(c): once the axis rests, PNOW equals the simulator's position (rc-sim's `where`); (a) a
        move done rests on its target."""
        s = self.axes[a]
        if self.silent and a == SILENT_AXIS:
            return
        if self.read(unit(a), LINK)[0] != LINK_ONLINE:
            self.skips["rest check: axis offline"] += 1
            return
        if self.read(unit(a), DSSE)[0] & DSSE_MOVE:
            self.skips["rest check: still moving, later"] += 1
            s["settled"] = time.monotonic()
            return
        hi, lo = self.read(unit(a), PNOW, 2)
        pnow = s32(hi, lo)
        truth = self.where(a)
        if truth["moving"] or truth["homing"]:
            self.skips["rest check: the simulated axis still moves, later"] += 1
            s["settled"] = time.monotonic()
            return
        position = truth["position"] + (1 if self.args.prove == "c" else 0)
        if pnow != position:
            # The gateway learns that a stopped axis came to rest from its status polls, which a
            # busy bus (a table write: ~25 frames) delays: PNOW must follow within 3 s and 3
            # status polls of the axis after the simulator was seen at rest.
            first = s.get("mismatch") or truth
            s["mismatch"] = first
            polls = sum(1 for t in self.log.polls[a] if t > first["t"])
            if truth["t"] - first["t"] < 3.0 or polls < 3:
                self.stats["rest checks waiting for PNOW to follow"] += truth is first
                s["settled"] = time.monotonic() - 0.8  # again in 0.2 s
                return
            message = (f"(c) axis {a} at rest: PNOW {pnow}, the simulator's position {position} (rc-sim log "
                       f"at {first['t']:.3f} s and {truth['t']:.3f} s, {polls} status polls of the axis between)")
            cmd = s["cmd"]
            if not self.args.strict and s.get("sync_since_check") and s.get("stopped_since"):
                # KNOWN DEFECT (reported with issue 24 item 7): a stop that gives up a synchronized
                # start after its `t` went out, before the gateway saw the axis move, leaves PNOW
                # at the position before the move: no read follows. Counted and shown, not fatal
                # (--strict makes it fatal); the axis' PNOW is not checked again until its next
                # command.
                self.known.append(message + f" after a synchronized start and a stop (last command: "
                                  f"{cmd['kind'] if cmd else None})")
                print(f"KNOWN DEFECT: {self.known[-1]}", flush=True)
                s["checked"] = True
                s["mismatch"] = None
                return
            raise Violation(message)
        s["checked"] = True
        s["mismatch"] = None
        s["sync_since_check"] = False
        self.checks["(c) at rest: PNOW = simulator"] += 1
        cmd = s["cmd"]
        if cmd is not None and not cmd.get("failed") and not s.get("stopped_since"):
            if pnow != cmd["target"]:
                raise Violation(f"(a) axis {a}: {cmd['kind']} done, at rest on {pnow}, target {cmd['target']}")
            self.checks["(a) done: rests on the target"] += 1
        s["pos"] = pnow

    def where(self, a):
        """The simulated axis as rc-sim has it now (`where`, noted in its log). Each answer also
        pins rc-sim's clock to the driver's: it was noted after the driver asked, so rc-sim
        started its clock no earlier than (asked - its time of the note)."""
        before = len(self.log.wheres[a])
        asked = time.monotonic()
        self.emu.inject(f"where {a}")
        deadline = time.monotonic() + 2
        while len(self.log.wheres[a]) == before:
            if time.monotonic() > deadline:
                raise AssertionError(f"rc-sim did not note `where {a}`")
            time.sleep(0.01)
            self.log.update()
        truth = self.log.wheres[a][-1]
        self.t0 = max(self.t0, asked - truth["t"])
        return truth

    # ------------------------------------------------------------------ (b) quiet windows

    def open_window(self, a, why, sent, returned, stop=False):
        s = self.axes[a]
        if s["window"] is None:
            s["window"] = {"why": why, "sent": sent, "returned": returned, "stop": stop}
        if stop:
            s["stopped_since"] = True

    def close_window(self, a, until=None):
        """The PLC sends its next command to `a` at `until`: the quiet window ends there."""
        s = self.axes[a]
        s["stopped_since"] = False
        if s["window"] is not None:
            w = s["window"]
            w["until"] = until if until is not None else time.monotonic()
            w["axis"] = a
            self.windows.append(w)
            s["window"] = None

    def close_windows(self, final=False):
        if final:
            for a in range(AXES):
                self.close_window(a)
            time.sleep(0.5)
        if not self.windows:
            return
        self.log.update()
        keep = []
        for w in self.windows:
            a = w["axis"]
            until = self.sim_time(w["until"]) - 0.02
            if self.log.now < until + 0.1 and not final:
                keep.append(w)
                continue
            start = self.sim_time(w["sent"])
            if w["stop"]:
                # From the stop's `d` on the bus (a move taken before the stop may go out first).
                cancels = [t for t in self.log.cancels[a] if t >= start]
                if cancels and cancels[0] < until:
                    start = cancels[0]
                else:
                    start = self.sim_time(w["returned"]) + 0.5
            late = [(t, c) for t, c in self.log.motions[a] if start < t < until]
            if late:
                raise Violation(f"(b) axis {a}: {late[0][1]} on the bus at {late[0][0]:.3f} s after {w['why']} "
                                f"(quiet from {start:.3f} s to {until:.3f} s, rc-sim time)")
            if until > start:
                self.checks["(b) nothing on the bus after a stop or refusal"] += 1
        self.windows = keep

    # ------------------------------------------------------------------ end

    def stop_sim(self):
        """rc-sim's own counters: SIGTERM makes it print them on its log."""
        if self.emu.sim is not None and self.emu.sim.poll() is None:
            self.emu.sim.send_signal(signal.SIGTERM)
            try:
                self.emu.sim.wait(timeout=5)
            except Exception:
                pass
        lines = [line for line in self.emu.sim_log()[-5:] if line.startswith("rc-sim:")]
        return lines

    def summary(self, sim_lines):
        print("---- soak summary ----")
        print(f"seed {self.seed}, {self.args.minutes} min, {AXES} axes, rc-sim {' '.join(SIM_FAULTS)}")
        for name, counter in (("PLC", self.stats), ("refusals and failures", self.refusals),
                              ("oracle checks passed", self.checks), ("checks skipped", self.skips)):
            print(f"{name}:")
            for key, value in sorted(counter.items()):
                print(f"  {key}: {value}")
        print(f"watchdog trips excused by a host stall: {len(self.excused)} {self.excused}")
        print(f"known defects seen: {len(self.known)}")
        for line in self.known:
            print(f"  {line}")
        print(f"bus commands (rc-sim log): {self.log.requests}")
        print("  " + ", ".join(f"{k} {v}" for k, v in self.log.kinds.most_common()))
        for line in sim_lines:
            print(line)


class Unknown(Exception):
    """A request without an answer: its outcome is unknown."""


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("elf")
    parser.add_argument("--minutes", type=float, default=20)
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("--workdir", default=str(ROOT / "target" / "emu" / "soak"))
    parser.add_argument("--strict", action="store_true", help="known firmware defects fail the run too")
    parser.add_argument("--prove", choices="abcde", help="break check CHECK's expectation: the run must fail")
    args = parser.parse_args()
    if args.seed is None:
        args.seed = random.randrange(1 << 32)
    workdir = Path(args.workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    soak = Soak(args, args.elf, workdir)
    print(f"soak: seed {args.seed}, {args.minutes} min, logs in {workdir}", flush=True)
    failure = None
    try:
        soak.start()
        soak.run()
    except Exception as error:
        failure = error
        traceback.print_exc()
    finally:
        sim_lines = []
        try:
            sim_lines = soak.stop_sim() if getattr(soak, "emu", None) else []
        except Exception:
            pass
        if getattr(soak, "emu", None):
            soak.emu.stop()
            (workdir / "firmware.log").write_text("\n".join(soak.emu.log()) + "\n")
        if getattr(soak, "log", None):
            soak.summary(sim_lines)
    if failure is not None:
        print("---- the last PLC requests (rc-sim's time, s; unit, address, value) ----")
        print("\n".join(soak.trace))
        axis = re.search(r"axis (\d+)", str(failure))
        bus = workdir / "rc-sim.log"
        if axis and bus.exists():
            # What the axis was told and answered, its status polls left out (a CI machine's
            # logs are gone when its report is read).
            tag = f"Axis({axis.group(1)})"
            lines = [line for line in bus.read_text(errors="replace").splitlines()
                     if tag in line and "command: Status }" not in line and "code: Status," not in line]
            print(f"---- the bus for axis {axis.group(1)}, status polls left out (rc-sim's log) ----")
            print("\n".join(lines[-50:]))
        print(f"SOAK FAILED (seed {args.seed}; rerun: scripts/soak.sh --minutes {args.minutes:g} --seed "
              f"{args.seed}): {failure}")
        print(f"logs: {workdir}/rc-sim.log (the bus), {workdir}/firmware.log")
        return 1
    print(f"SOAK PASSED (seed {args.seed})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
