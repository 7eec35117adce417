"""The deepest stack of a firmware ELF's start-up path by its static call graph, for what the
emulator cannot run: the settings load from flash exists only in the hardware builds (QEMU
models no flash interface), so scripts/emu-test.sh never measures it.

Frame sizes come from the disassembly (llvm-objdump, from rustup's llvm-tools): every `push`,
`vpush`, `str rN, [sp, #-n]!` and `sub sp` of a function, wherever it is in the body (an
over-count at worst). Calls are the direct ones: `bl` (conditional too) and a `b` to another
function (a tail call, counted on top of its caller's frame: an over-count too). Indirect calls
are not followed: the executor polls the tasks through function pointers, so the tasks' stacks
are the emulator's measurement, not this one. One interrupt or fault comes on top: the deepest
handler of the vector table plus the frame the core stacks on entry (32 bytes; 104 with the FPU's
registers on the hard-float target; and 4 for the entry's alignment). A handler that moves the
stack pointer itself (`msr msp`: the HardFault entry of src/rt.rs, which runs on a fresh stack from
the top, so that it works after an overflow) does not come on top, only its entry frame. Nesting
is not counted: a fault inside a handler, or an interrupt of a higher priority inside another one.

    python3 scripts/stack_depth.py OBJDUMP ELF [ROOT]   # prints the path, ROOT default `main`
"""

import re
import subprocess
import sys

from elftools.elf.elffile import ELFFile


def registers(text):
    """Bytes of a register list: 8 for a double (`dN`), else 4."""
    return sum(8 if r.strip().startswith("d") else 4 for r in text.split(","))


IMMEDIATE = r"#(0x[0-9a-f]+|\d+)"
STACKING = [
    (re.compile(r"\tpush(?:\.w)?\t\{([^}]*)\}"), lambda m: registers(m.group(1))),
    (re.compile(r"\tvpush\t\{([^}]*)\}"), lambda m: registers(m.group(1))),
    (re.compile(r"\tstr(?:\.w)?\t\w+, \[sp, #-(0x[0-9a-f]+|\d+)\]!"), lambda m: int(m.group(1), 0)),
    (re.compile(r"\tsub(?:\.w|w)?\tsp, (?:sp, )?" + IMMEDIATE + r"\b"), lambda m: int(m.group(1), 0)),
]
CONDITIONS = "eq|ne|cs|hs|cc|lo|mi|pl|vs|vc|hi|ls|ge|lt|gt|le"
CALL = re.compile(rf"\t(bl|b)(?:{CONDITIONS})?(?:\.w)?\t0x[0-9a-f]+ <([^>+]*)>")
FUNCTION = re.compile(r"^([0-9a-f]+) <(.*)>:")
SETS_MSP = re.compile(r"\tmsr\tmsp, ")
# The vector table's first two words: the initial stack pointer and the reset handler.
FIRST_HANDLER = 8


def call_graph(objdump, elf_path):
    """Frame size and direct callees of every function, each function's name by address, and the
    functions that set the main stack pointer (`msr msp`)."""
    text = subprocess.run([objdump, "-d", "--no-show-raw-insn", elf_path],
                          check=True, capture_output=True, text=True).stdout
    frames, calls, at, own_stack, current = {}, {}, {}, set(), None
    for line in text.splitlines():
        m = FUNCTION.match(line)
        if m:
            # `$t` and `$d` mark code and data inside a function, not new functions.
            if not m.group(2).startswith("$"):
                current = m.group(2)
                at[int(m.group(1), 16)] = current
                frames.setdefault(current, 0)
                calls.setdefault(current, set())
            continue
        if current is None:
            continue
        for pattern, size in STACKING:
            m = pattern.search(line)
            if m:
                frames[current] += size(m)
        m = CALL.search(line)
        if m and m.group(2) != current:
            calls[current].add(m.group(2))
        if SETS_MSP.search(line):
            own_stack.add(current)
    return frames, calls, at, own_stack


def deepest(frames, calls, root):
    """(bytes, path) of the deepest chain of direct calls from `root`; a recursion counts once."""

    def walk(function, outer):
        best = (0, ())
        for callee in calls.get(function, ()):
            if callee in outer:
                continue
            below = walk(callee, outer | {function})
            if below[0] > best[0]:
                best = below
        return frames.get(function, 0) + best[0], (function,) + best[1]

    return walk(root, frozenset())


def handlers(elf_path, at):
    """The functions the vector table points at, past the reset handler (exceptions and
    interrupts), named as the disassembly names their addresses; and whether the ELF is for
    the hard-float ABI (the FPU's registers are stacked on entry then)."""
    with open(elf_path, "rb") as f:
        elf = ELFFile(f)
        words = elf.get_section_by_name(".vector_table").data()
        hard_float = elf.header["e_flags"] & 0x400 != 0  # EF_ARM_ABI_FLOAT_HARD
    addresses = {int.from_bytes(words[i:i + 4], "little") & ~1
                 for i in range(FIRST_HANDLER, len(words), 4)}
    return {at[a] for a in addresses if a in at}, hard_float


def worst_case(objdump, elf_path, root="main"):
    """(total, path, path bytes, handler, handler bytes, entry frame, frames) for `root`."""
    frames, calls, at, own_stack = call_graph(objdump, elf_path)
    if root not in frames:
        sys.exit(f"stack_depth: no function {root!r} in {elf_path}")
    path_bytes, path = deepest(frames, calls, root)
    names, hard_float = handlers(elf_path, at)
    names -= own_stack
    handler, handler_bytes = max(((n, deepest(frames, calls, n)[0]) for n in names),
                                 key=lambda x: x[1], default=("none", 0))
    entry = (104 if hard_float else 32) + 4
    total = path_bytes + handler_bytes + entry
    return total, path, path_bytes, handler, handler_bytes, entry, frames


def main(argv):
    objdump, elf_path = argv[0], argv[1]
    root = argv[2] if len(argv) > 2 else "main"
    total, path, path_bytes, handler, handler_bytes, entry, frames = worst_case(objdump, elf_path, root)
    print(f"{total} B: {path_bytes} B from {root}, {handler_bytes} B in {handler}, {entry} B entry frame")
    for function in path:
        print(f"  {frames[function]:6d}  {function}")


if __name__ == "__main__":
    main(sys.argv[1:])
