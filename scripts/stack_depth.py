"""The deepest stack of a firmware ELF's start-up path by its static call graph, for what the
emulator cannot run: the settings load from flash exists only in the hardware builds (QEMU
models no flash interface), so scripts/emu-test.sh never measures it.

Frame sizes come from the disassembly (llvm-objdump, from rustup's llvm-tools): each function's
`push`, `vpush` and `sub sp` in its prologue. Calls are the direct ones (`bl`, and a `b` to
another function, a tail call). Indirect calls are not followed: the executor polls the tasks
through function pointers, so the tasks' stacks are the emulator's measurement, not this one.
An interrupt can come on top of any of it: the deepest handler of the vector table, plus the
frame the core stacks on entry (32 bytes; 104 with the FPU's registers, on the hard-float
target), is added.

    python3 scripts/stack_depth.py OBJDUMP ELF [ROOT]   # prints the path, ROOT default `main`
"""

import functools
import re
import subprocess
import sys

from elftools.elf.elffile import ELFFile

PROLOGUE = [
    (re.compile(r"\tpush(?:\.w)?\t\{([^}]*)\}"), lambda m: 4 * len(m.group(1).split(","))),
    (re.compile(r"\tvpush\t\{([^}]*)\}"), lambda m: 8 * len(m.group(1).split(","))),
    (re.compile(r"\tsub(?:\.w|w)?\tsp, (?:sp, )?#(0x[0-9a-f]+|\d+)\b"), lambda m: int(m.group(1), 0)),
]
CALL = re.compile(r"\t(bl|b|b\.w)\t0x[0-9a-f]+ <([^>+]*)>")
FUNCTION = re.compile(r"^[0-9a-f]+ <(.*)>:")


def call_graph(objdump, elf_path):
    """Frame size and direct callees of every function."""
    text = subprocess.run([objdump, "-d", "--no-show-raw-insn", elf_path],
                          check=True, capture_output=True, text=True).stdout
    frames, calls, current = {}, {}, None
    for line in text.splitlines():
        m = FUNCTION.match(line)
        if m:
            # `$t` and `$d` mark code and data inside a function, not new functions.
            if not m.group(1).startswith("$"):
                current = m.group(1)
                frames.setdefault(current, 0)
                calls.setdefault(current, set())
            continue
        if current is None:
            continue
        for pattern, size in PROLOGUE:
            m = pattern.search(line)
            if m:
                frames[current] += size(m)
        m = CALL.search(line)
        if m and m.group(2) != current:
            calls[current].add(m.group(2))
    return frames, calls


def deepest(frames, calls, root):
    """(bytes, path) of the deepest chain of direct calls from `root`; a recursion counts once."""

    @functools.lru_cache(maxsize=None)
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


def handlers(elf_path):
    """The functions the vector table points at (exceptions and interrupts), by name."""
    with open(elf_path, "rb") as f:
        elf = ELFFile(f)
        table = elf.get_section_by_name(".vector_table")
        words = table.data()
        addresses = {int.from_bytes(words[i:i + 4], "little") & ~1 for i in range(4, len(words), 4)}
        names = set()
        for sym in elf.get_section_by_name(".symtab").iter_symbols():
            if sym["st_info"]["type"] == "STT_FUNC" and (sym["st_value"] & ~1) in addresses:
                names.add(sym.name)
        hard_float = elf.header["e_flags"] & 0x400 != 0  # EF_ARM_ABI_FLOAT_HARD
    return names, hard_float


def worst_case(objdump, elf_path, root="main"):
    """(total, path, path bytes, handler, handler bytes, entry frame) for `root`."""
    frames, calls = call_graph(objdump, elf_path)
    if root not in frames:
        sys.exit(f"stack_depth: no function {root!r} in {elf_path}")
    path_bytes, path = deepest(frames, calls, root)
    names, hard_float = handlers(elf_path)
    handler, handler_bytes = max(((n, deepest(frames, calls, n)[0]) for n in names if n in frames),
                                 key=lambda x: x[1], default=("none", 0))
    entry = 104 if hard_float else 32
    return path_bytes + handler_bytes + entry, path, path_bytes, handler, handler_bytes, entry


def main(argv):
    objdump, elf_path = argv[0], argv[1]
    root = argv[2] if len(argv) > 2 else "main"
    total, path, path_bytes, handler, handler_bytes, entry = worst_case(objdump, elf_path, root)
    frames, _ = call_graph(objdump, elf_path)
    print(f"{total} B: {path_bytes} B from {root}, {handler_bytes} B in {handler}, {entry} B entry frame")
    for function in path:
        print(f"  {frames.get(function, 0):6d}  {function}")


if __name__ == "__main__":
    main(sys.argv[1:])
