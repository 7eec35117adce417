"""Where the firmware's CPU time goes: an exact instruction profile of the real firmware ELF (its
emulator build) in QEMU under the same load as cpu_load.py (16 simulated axes at 115.2 kbit/s,
the PLC silent).

How: QEMU runs with `-accel tcg,one-insn-per-tb=on` (every translated block is one instruction) and
`-d nochain` (every block executed goes through the logger); for --seconds of wall time, `exec`
logging is switched on over QMP, which logs every block executed: every instruction, with its
address. Instructions per function are those addresses, attributed to the function they are in
(llvm-symbolizer). (Counting blocks times their length instead goes wrong for blocks that touch
I/O: under -icount QEMU translates them again, shorter.) Logging slows the guest down, so the
profile gives shares, not a load: cpu_load.py measures that.

Output: the functions with the most instructions and their share of all instructions traced;
then, per transaction, how often the clock is read, the CPU sleeps and the gateway task is
polled (entries of those functions, and executions of the WFI instruction). The clock reads
include the emulator's own: its CPU-load meter reads the clock twice per sleep, and its SysTick
driver interrupts every millisecond; the boards have neither.
"""

import argparse
import collections
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "pyshared"))

from emu import Emulator, modbus_only  # noqa: E402

TRACE = re.compile(r"^Trace \d+: \S+ \[[0-9a-f]+/([0-9a-f]+)/")
# The bus UART's interrupt handler on the emulated board (src/board/l475.rs).
BUS_IRQ = "UART4"


def record(elf, log, seconds, axes):
    with tempfile.TemporaryDirectory() as workdir:
        emu = Emulator(elf, workdir, f"0-{axes - 1}", plc=False,
                       qemu_args=["-icount", "shift=4,sleep=on", "-d", "nochain", "-D", str(log)],
                       accel="tcg,one-insn-per-tb=on")
        try:
            emu.start(stop_closed=True)
            modbus_only(emu, list(range(axes)))
            time.sleep(1.0)
            monitor = lambda line: emu.qmp.execute("human-monitor-command", **{"command-line": line})  # noqa: E731
            monitor("log nochain,exec")
            time.sleep(seconds)
            monitor("log nochain")
        finally:
            emu.stop()


def parse(log):
    """Executions by address (each block is one instruction)."""
    executed = collections.Counter()
    with open(log, errors="replace") as f:
        for line in f:
            trace = TRACE.match(line)
            if trace:
                executed[int(trace.group(1), 16)] += 1
    return executed


def entry(elf, symbol):
    """The address of `symbol` (Thumb bit cleared)."""
    out = subprocess.run(["llvm-nm", elf], capture_output=True, text=True, check=True).stdout
    for line in out.splitlines():
        fields = line.split()
        if len(fields) == 3 and fields[2] == symbol:
            return int(fields[0], 16) & ~1
    sys.exit(f"cpu-profile: no {symbol} in {elf}")


def functions(elf, addresses):
    """The function each address is in (the outermost, not an inlined one)."""
    out = subprocess.run(["llvm-symbolizer", f"--obj={elf}", "--functions=linkage", "--inlining=false",
                          "--demangle"],
                         input="\n".join(hex(a) for a in addresses), capture_output=True, text=True,
                         check=True).stdout
    names = [block.split("\n")[0] for block in out.strip().split("\n\n")]
    return dict(zip(addresses, names))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("elf")
    parser.add_argument("--seconds", type=float, default=3.0, help="wall time traced (default 3)")
    parser.add_argument("--axes", type=int, default=16, choices=range(1, 17), metavar="N")
    parser.add_argument("--top", type=int, default=30, help="functions listed (default 30)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "qemu.log"
        record(args.elf, log, args.seconds, args.axes)
        executed = parse(log)
    if not executed:
        sys.exit("cpu-profile: nothing was traced")
    names = functions(args.elf, list(executed))
    per_function = collections.Counter()
    for pc, count in executed.items():
        per_function[re.sub(r"::h[0-9a-f]{16}$", "", names[pc])] += count
    total = sum(per_function.values())
    frames = executed[entry(args.elf, BUS_IRQ)] / 33
    print(f"{total} instructions traced, about {frames:.0f} transactions (bus UART interrupts / 33; "
          f"logging slows the guest, so the time-driven work per transaction (SysTick, timers) is "
          f"more than under scripts/cpu-load.sh: read the shares, not the sums)")
    for name, count in per_function.most_common(args.top):
        print(f"{100 * count / total:5.1f} %  {count:9d}  {name[:110]}")
    if frames:
        sleeps = sum(executed[a] for a in wfi_addresses(args.elf))
        polls = sum(executed[a] for a in task_polls(args.elf))
        print(f"per transaction: {executed[entry(args.elf, '_embassy_time_now')] / frames:.1f} "
              f"clock reads ({2 * sleeps / frames:.1f} of them the emulator's meter, 2 per sleep), "
              f"{sleeps / frames:.1f} sleeps (WFI), {polls / frames:.1f} task polls, "
              f"{executed[entry(args.elf, 'SysTick')] / frames:.1f} SysTick interrupts")


def wfi_addresses(elf):
    """Where the firmware executes WFI."""
    out = subprocess.run(["llvm-objdump", "-d", "--no-show-raw-insn", elf], capture_output=True,
                         text=True, check=True).stdout
    return [int(m.group(1), 16) for m in re.finditer(r"^\s+([0-9a-f]+):\s+wfi\b", out, re.M)]


def task_polls(elf):
    """The entries of the executor's per-task poll functions."""
    out = subprocess.run(["llvm-nm", "--demangle", elf], capture_output=True, text=True,
                         check=True).stdout
    return [int(line.split()[0], 16) & ~1 for line in out.splitlines()
            if "TaskStorage" in line and "::poll::" in line]

if __name__ == "__main__":
    main()
