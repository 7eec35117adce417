"""Stop latency on the real firmware ELF in QEMU, as information (issue 33 item 6): from the moment
a stop is given to the moment the axis' `d` reaches the simulated controllers, for each face of a
stop, with 16 axes on the bus at 115.2 kbit/s and 4 of them moving.

    python3 tests/emu/stop_latency.py ELF [--repeats 8] [--json]
    (scripts/emu-stop-latency.sh builds the ELF and rc-sim and runs this)

Faces: the stop input (its pin opens), the PIO's *STP (axis 0 is the PIO axis, standing), DRG1 STP
and the STOP coil over Modbus (to mover 5), a broadcast STOP (unit 0). The clock is the host's
`CLOCK_MONOTONIC` on both sides: this program notes `time.monotonic()` just before it gives the
stop (the pin's qtest write, the Modbus request's first byte), and rc-sim's event log (`--events`)
notes when the `d` frame's bytes were read from the firmware's bus line. For the stop input and the
broadcast, which stop every axis, it gives the first `d` and the last (all 16).

Not a test and not a benchmark with a target: QEMU runs the firmware without `-icount`, its timing
is the host's and loose (a loaded host stretches it), and the Modbus line is a socket, not a wire.
The targets are met or not by `scripts/bench.sh` in virtual time (docs/performance.md); this gives
the same figures for the real ELF, so that a change in the firmware's stop path shows.
"""

import argparse
import json
import signal
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "pyshared"))

from emu import SON, STOP_INPUT, STP_N, Emulator, Pins, Plc, modbus_only  # noqa: E402
from plc import (  # noqa: E402
    COIL_STOP, adu, DRG1, DRG1_SON, DRG1_STP, G_PIO_AXIS, GATEWAY_UNIT, unit, wait_for,
)

AXES = range(16)
MOVERS = (1, 5, 10, 15)
TARGETS = (40_00, 60_00)  # 0.01 mm, both within the simulated stroke
SLOW = 5_00  # 0.01 mm/s: a move takes seconds, far longer than a round


def percentile(values, q):
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q * (len(ordered) - 1))))]


class Rounds:
    def __init__(self, emu, plc, pins):
        self.emu, self.plc, self.pins = emu, plc, pins
        self.given = []  # (face, t0 seconds, axes whose `d` is awaited)
        self.round = 0

    def start_moves(self):
        target = TARGETS[self.round % 2]
        self.round += 1
        for axis in MOVERS:
            self.plc.direct(axis, target, speed=SLOW, accel=30)
        # Seen under way by the gateway (its PNOW follows), so that the stop meets moving axes.
        time.sleep(0.4)

    def give(self, face):
        self.start_moves()
        if face == "stop input":
            t0 = time.monotonic()
            self.emu.set_pin(STOP_INPUT, False)
            awaited = list(AXES)
        elif face == "*STP":
            t0 = time.monotonic()
            self.pins.set(STP_N, False)
            awaited = [0]
        elif face == "DRG1 STP":
            t0 = time.monotonic()
            self.plc.write(unit(5), DRG1, DRG1_SON | DRG1_STP)
            awaited = [5]
        elif face == "STOP coil":
            t0 = time.monotonic()
            self.plc.coil(unit(5), COIL_STOP, True)
            awaited = [5]
        elif face == "broadcast":
            sock = self.plc.client.socket
            frame = adu(0, 0x05, COIL_STOP >> 8, COIL_STOP & 0xFF, 0xFF, 0x00)
            t0 = time.monotonic()
            sock.sendall(frame)  # no reply to a broadcast
            awaited = list(AXES)
        else:
            raise ValueError(face)
        self.given.append((face, t0, awaited))
        time.sleep(0.5)
        self.release(face)

    def release(self, face):
        if face == "stop input":
            self.emu.set_pin(STOP_INPUT, True)
            self.plc.acknowledge(timeout=10)
        elif face == "*STP":
            self.pins.set(STP_N, True)
        elif face == "DRG1 STP":
            self.plc.write(unit(5), DRG1, DRG1_SON)
        elif face == "STOP coil":
            self.plc.coil(unit(5), COIL_STOP, False)
        time.sleep(0.2)


def stops_from_events(path):
    """(t seconds, axis) of every `d` in rc-sim's event log."""
    found = []
    for line in path.read_text().splitlines():
        parts = line.split()
        if len(parts) >= 4 and parts[0] == "REQ" and parts[3] == "CancelMotion":
            found.append((int(parts[1]) / 1e6, int(parts[2])))
    return found


def latencies(given, stops):
    """Per face: the first `d` to each awaited axis after the stop was given, in ms."""
    per_face = {}
    for face, t0, awaited in given:
        firsts = []
        for axis in awaited:
            after = [t for t, a in stops if a == axis and t >= t0]
            if not after:
                raise AssertionError(f"{face}: no `d` to axis {axis} after the stop given at {t0:.3f}")
            firsts.append((min(after) - t0) * 1e3)
        entry = per_face.setdefault(face, {"first": [], "last": []})
        entry["first"].append(min(firsts))
        entry["last"].append(max(firsts))
    return per_face


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("elf")
    parser.add_argument("--repeats", type=int, default=8)
    parser.add_argument("--workdir", default=str(ROOT / "target" / "emu" / "stop-latency"))
    parser.add_argument("--json", action="store_true", help="print one JSON line too")
    args = parser.parse_args()
    workdir = Path(args.workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    events = workdir / "events.log"
    emu = Emulator(args.elf, workdir, "0-15", sim_args=["--events", str(events)], plc=False)
    plc = None
    try:
        emu.start(stop_closed=True)
        modbus_only(emu, AXES)
        plc = Plc(emu.plc_port)
        pins = Pins(emu)
        pins.set(STP_N, True)
        pins.set(SON, True)
        plc.write(GATEWAY_UNIT, G_PIO_AXIS, 0)  # axis 0 is the PIO axis: *STP stops it
        for axis in MOVERS:
            plc.home(axis)
        rounds = Rounds(emu, plc, pins)
        faces = ("stop input", "*STP", "DRG1 STP", "STOP coil", "broadcast")
        for _ in range(args.repeats):
            for face in faces:
                rounds.give(face)
        # rc-sim writes its event log out when it ends (SIGTERM).
        emu.sim.send_signal(signal.SIGTERM)
        emu.sim.wait(timeout=10)
        wait_for(lambda: events.exists() and events.stat().st_size > 0, 5, "rc-sim's event log")
        result = latencies(rounds.given, stops_from_events(events))
    finally:
        if plc is not None:
            plc.close()
        emu.stop()

    print(f"Stop latency on the firmware ELF in QEMU (information, not a target): stop given -> `d` read "
          f"by rc-sim, ms; 16 axes at 115.2 kbit/s, {len(MOVERS)} moving; {args.repeats} stops a face")
    print(f"{'face':<12} {'axes':>5} {'p50':>7} {'p99':>7} {'max':>7}")
    summary = {}
    for face, entry in result.items():
        rows = [("first", entry["first"])]
        if entry["last"] != entry["first"]:
            rows.append(("all 16", entry["last"]))
        for which, values in rows:
            name = face if which == "first" else f"{face}, last"
            p50, p99, top = statistics.median(values), percentile(values, 0.99), max(values)
            axes = "1" if which == "first" else "16"
            print(f"{name:<18} {axes:>3} {p50:7.2f} {p99:7.2f} {top:7.2f}")
            summary[name] = {"p50_ms": round(p50, 3), "p99_ms": round(p99, 3), "max_ms": round(top, 3)}
    if args.json:
        print("EMU_STOP_LATENCY " + json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
