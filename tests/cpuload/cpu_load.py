"""The gateway's CPU load on the MCU, measured on the real firmware ELF (its emulator build) in
QEMU: 16 simulated axes (rc-sim) polled at 115.2 kbit/s, the PLC silent, for --seconds of guest
time.

How: QEMU runs with `-icount shift=4,sleep=on`, so guest time follows the instructions executed
(2^4 = 16 ns each) while the CPU runs, and real time while it sleeps. The firmware's executor loop
(emulator build, `LoadMeter` in src/emu.rs) adds up the time spent outside WFI (tasks and interrupt
handlers) in `EMU_BUSY_US`, and the time of its last sleep in `EMU_CLOCK_US`; both are read over
qtest at the start and end of the window. The transactions in the window are the frames the
gateway sent (DIAG, unit 63), read over Modbus before and after.

What it means: 16 ns per instruction is 62.5 million instructions per second, the STM32L475 at
80 MHz if an instruction takes 1.28 cycles on average (flash wait states behind the ART
accelerator; an assumption, not a measurement: QEMU models no cycles). Busy time includes
everything the firmware does meanwhile: the bus, the 1 ms input sampling, the LEDs. The load at
another clock scales with 1/clock (the F103 at 72 MHz: about 1.1x).
"""

import argparse
import json
import re
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "pyshared"))

from emu import Emulator, Plc, modbus_only  # noqa: E402
from plc import GATEWAY_UNIT  # noqa: E402

SHIFT = 4
G_DIAG = 0x0400  # per axis n at 0x0400 + 16 n: frames sent (u32) first


def frames_sent(plc, axes):
    total = 0
    for axis in axes:
        hi, lo = plc.read(GATEWAY_UNIT, G_DIAG + 16 * axis, 2)
        total += hi << 16 | lo
    return total


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("elf")
    parser.add_argument("--seconds", type=float, default=20.0, help="the measured window (default 20)")
    parser.add_argument("--json", action="store_true", help="one JSON object")
    parser.add_argument("--shift", type=int, default=SHIFT, choices=range(0, 9),
                        help="-icount shift: 2^shift ns per instruction (default 4: the board)")
    parser.add_argument("--axes", type=int, default=16, choices=range(1, 17), metavar="N",
                        help="simulated axes 0..N-1 (default 16)")
    parser.add_argument("--doc", metavar="MD",
                        help="check the figure documented between MD's cpu markers: exit status 3 when "
                             f"it is more than {DOC_SLACK_PERCENT} % off the one measured")
    args = parser.parse_args()
    axes = list(range(args.axes))
    with tempfile.TemporaryDirectory() as workdir:
        emu = Emulator(args.elf, workdir, f"0-{args.axes - 1}", plc=False,
                       qemu_args=["-icount", f"shift={args.shift},sleep=on"])
        try:
            emu.start(stop_closed=True)
            modbus_only(emu, axes)
            plc = Plc(emu.plc_port)
            busy_at, clock_at = emu.symbols["EMU_BUSY_US"], emu.symbols["EMU_CLOCK_US"]
            time.sleep(1.0)  # settle after commissioning
            frames0 = frames_sent(plc, axes)
            busy0, clock0 = emu.qtest.readl(busy_at), emu.qtest.readl(clock_at)
            time.sleep(args.seconds)
            busy1, clock1 = emu.qtest.readl(busy_at), emu.qtest.readl(clock_at)
            frames1 = frames_sent(plc, axes)
            plc.close()
        finally:
            emu.stop()
    window_us = (clock1 - clock0) % (1 << 32)
    busy_us = (busy1 - busy0) % (1 << 32)
    transactions = frames1 - frames0
    if window_us == 0 or transactions == 0:
        sys.exit(f"cpu-load: nothing measured (window {window_us} us, {transactions} transactions)")
    result = {
        "cpu_load_percent": round(100.0 * busy_us / window_us, 2),
        "instructions_per_transaction": round(busy_us * 1000 / (1 << args.shift) / transactions),
        "transactions_per_second": round(transactions / (window_us / 1e6), 1),
        "window_guest_s": round(window_us / 1e6, 2),
        "axes": len(axes),
        "baud": 115200,
        "ns_per_instruction": 1 << args.shift,
        "assumes": "STM32L475 at 80 MHz, 1.28 cycles per instruction",
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(f"CPU load {result['cpu_load_percent']} % at {len(axes)} axes, 115.2 kbit/s "
              f"({result['transactions_per_second']} transactions/s, "
              f"{result['instructions_per_transaction']} instructions each, "
              f"{result['window_guest_s']} s of guest time; {result['assumes']})")
    if args.doc and args.axes == 16 and args.shift == SHIFT:
        problem = stale(args.doc, result)
        if problem:
            print(problem, file=sys.stderr)
            sys.exit(3)


DOC_SLACK_PERCENT = 3
DOC_BEGIN, DOC_END = "<!-- cpu:begin", "<!-- cpu:end -->"


def stale(path, result):
    """Why the instructions per transaction documented in `path` (between its cpu markers) are
    stale, if they are: more than DOC_SLACK_PERCENT off the measured figure. The instructions, not
    the percentage, are checked: the percentage follows the emulated bus' rate, which the host moves
    by a few percent from run to run; the instructions per transaction do not move."""
    measured = result["instructions_per_transaction"]
    line = (f"**{measured / 1000:.1f}k instructions per transaction** ({result['cpu_load_percent']} % at "
            f"the emulator's {result['transactions_per_second']} transactions/s)")
    try:
        text = open(path).read()
        block = text.split(DOC_BEGIN, 1)[1].split(DOC_END, 1)[0]
        documented = float(re.search(r"([0-9.]+)k instructions per transaction", block).group(1)) * 1000
    except (OSError, IndexError, AttributeError, ValueError):
        return f"cpu-load: {path} has no figure between its cpu markers; measured: {line}"
    if abs(documented - measured) > measured * DOC_SLACK_PERCENT / 100:
        return (f"cpu-load: {path}'s CPU figure is stale: documented {documented / 1000:.1f}k instructions "
                f"per transaction, measured {measured} (more than {DOC_SLACK_PERCENT} % off); paste: {line}")
    return None


if __name__ == "__main__":
    main()
