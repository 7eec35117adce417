"""scripts/size-report.sh's arithmetic: flash and static RAM of each board's ELF from its section
headers, the room the layout leaves the stack (flip-link's: from the start of RAM up to the
statics), the stack (the emulator's high-water mark, or the start-up path of the hardware build by
its call graph if that is deeper: scripts/stack_depth.py), each against its budget, and where
the bytes go (by crate, and the largest symbols).

Arguments: TOP HWM_LOG CHECK OBJDUMP, then per board: NAME ELF FLASH_START FLASH_END RAM_START
RAM_END FLASH_BUDGET_KIB RAM_BUDGET_KIB ENFORCED. With CHECK 1, a board that is over a budget fails
the report if it is ENFORCED (1); the others' budgets are targets, reported.
"""

import collections
import re
import sys

from elftools.elf.constants import SH_FLAGS
from elftools.elf.elffile import ELFFile

import stack_depth


def demangle(name):
    """Rust's legacy mangling (`_ZN` len-prefixed segments, a hash last), readably; else as is."""
    if not (name.startswith("_ZN") and name.endswith("E")):
        return name
    body, parts = name[3:-1], []
    while body and body[0].isdigit():
        digits = re.match(r"\d+", body).group()
        body = body[len(digits):]
        parts.append(body[: int(digits)])
        body = body[int(digits):]
    if parts and re.fullmatch(r"h[0-9a-f]{16}", parts[-1]):
        parts.pop()
    text = "::".join(parts)
    for code, char in (("$LT$", "<"), ("$GT$", ">"), ("$u20$", " "), ("$u7b$", "{"), ("$u7d$", "}"),
                       ("$RF$", "&"), ("$C$", ","), ("..", "::"), ("$u27$", "'")):
        text = text.replace(code, char)
    return text


def crate(name):
    """The crate a symbol's code comes from (for `<T as Trait>` impls: T's crate)."""
    text = demangle(name).lstrip("_<")
    return text.split("::", 1)[0] if "::" in text else "(other: runtime, compiler builtins)"


def kib(n):
    return f"{n / 1024:5.1f} KiB"


def stack_high_water_mark(path):
    lines = [line.split() for line in open(path) if line.strip()]
    stack = max(int(n) for n, _ in lines)
    deepest = [name for n, name in lines if int(n) == stack]
    where = (f"in all {len(lines)} emulator tests" if len(deepest) == len(lines)
             else f"deepest in {', '.join(deepest[:2])}")
    return stack, where


def report(name, elf_path, flash_region, ram_region, flash_budget, ram_budget, stack, stack_where, top,
           objdump):
    inside = lambda address, region: region[0] <= address < region[1]  # noqa: E731
    with open(elf_path, "rb") as f:
        elf = ELFFile(f)
        sections = [s for s in elf.iter_sections() if s["sh_flags"] & SH_FLAGS.SHF_ALLOC and s["sh_size"]]
        # A section occupies flash if its load address is there (.data's initial values too).
        load = {}
        for segment in elf.iter_segments():
            if segment["p_type"] != "PT_LOAD":
                continue
            for s in sections:
                if segment.section_in_segment(s):
                    load[s.name] = segment["p_paddr"] + s["sh_addr"] - segment["p_vaddr"]
        flash = {s.name: s["sh_size"] for s in sections
                 if inside(load.get(s.name, s["sh_addr"]), flash_region) and s["sh_type"] != "SHT_NOBITS"}
        ram = {s.name: s["sh_size"] for s in sections if inside(s["sh_addr"], ram_region)}
        symtab = elf.get_section_by_name(".symtab")
        symbols = sorted(
            ((sym["st_size"], sym.name, "flash" if inside(sym["st_value"], flash_region) else "ram")
             for sym in symtab.iter_symbols()
             if sym["st_size"] and sym["st_info"]["type"] in ("STT_FUNC", "STT_OBJECT")),
            reverse=True)
        # The stack's region, [_stack_end, _stack_start): with flip-link (.cargo/config.toml) from
        # the start of RAM up to the statics, so that an overflow faults at the start of RAM.
        bounds = {sym.name: sym["st_value"] for sym in symtab.iter_symbols()
                  if sym.name in ("_stack_end", "_stack_start")}
    flash_total, static_ram = sum(flash.values()), sum(ram.values())
    over = []
    print(f"{name}: {elf_path}")
    verdict = lambda used, budget: "fits" if used <= budget else f"OVER by {kib(used - budget).strip()}"  # noqa: E731
    print(f"  flash        {kib(flash_total)}  budget {kib(flash_budget)}  {verdict(flash_total, flash_budget)}"
          f"   ({', '.join(f'{k} {v}' for k, v in flash.items())})")
    print(f"  static RAM   {kib(static_ram)}   ({', '.join(f'{k} {v}' for k, v in ram.items())})")
    if len(bounds) == 2:
        room = bounds["_stack_start"] - bounds["_stack_end"]
        print(f"  stack room   {kib(room)}   ({room} B, {bounds['_stack_end']:#x}-{bounds['_stack_start']:#x}: "
              f"{'the start of RAM up to the statics; an overflow faults' if bounds['_stack_end'] == ram_region[0] else 'above the statics'})")
    print(f"  stack HWM    {kib(stack)}   ({stack} B, {stack_where}; emulator build of the L475)")
    # The hardware build's start-up (the settings load from flash, which QEMU cannot run) by its
    # call graph, with the deepest interrupt on top.
    boot, path, path_bytes, handler, handler_bytes, entry, _ = stack_depth.worst_case(objdump, elf_path)
    # Named by the firmware's own function deepest on the path (below it: libraries).
    ours = [demangle(f) for f in path if f.startswith("_ZN10rc_gateway")]
    print(f"  start-up     {kib(boot)}   ({boot} B by the call graph: {path_bytes} B from main, "
          f"through {ours[-1] if ours else '-'}; + {handler_bytes} B in {handler} "
          f"+ {entry} B interrupt entry)")
    deepest = max(stack, boot)
    print(f"  RAM + stack  {kib(static_ram + deepest)}  budget {kib(ram_budget)}  "
          f"{verdict(static_ram + deepest, ram_budget)}   (the deeper of the two stacks; "
          f"{ram_budget - static_ram - deepest} B to spare)")
    if flash_total > flash_budget:
        over.append("flash")
    if static_ram + deepest > ram_budget:
        over.append("RAM")
    by_crate = collections.Counter()
    for size, symbol, where in symbols:
        by_crate[(where, crate(symbol))] += size
    print("  where the bytes go (symbol sizes by crate; a task's code counts as embassy_executor's):")
    for (where, owner), size in by_crate.most_common(10):
        print(f"    {size:6d}  {where:5s}  {owner}")
    print("  largest symbols:")
    for size, symbol, where in symbols[:top]:
        print(f"    {size:6d}  {where:5s}  {demangle(symbol)[:100]}")
    return over


def main(argv):
    top, hwm_path, check, objdump = int(argv[0]), argv[1], argv[2] == "1", argv[3]
    try:
        stack, stack_where = stack_high_water_mark(hwm_path)
    except (OSError, ValueError):
        sys.exit(f"no stack measurement in {hwm_path}: did scripts/emu-test.sh run?")
    boards = argv[4:]
    failures = []
    targets_missed = []
    for i in range(0, len(boards), 9):
        name, elf, fs, fe, rs, re_, fb, rb, enforced = boards[i:i + 9]
        over = report(name, elf, (int(fs, 16), int(fe, 16)), (int(rs, 16), int(re_, 16)),
                      int(fb) * 1024, int(rb) * 1024, stack, stack_where, top, objdump)
        missed = [f"{name.split()[0]} {what}" for what in over]
        if enforced == "1":
            failures += missed
        else:
            targets_missed += missed
        print()
    if targets_missed:
        print(f"over a target (reported, not enforced): {', '.join(targets_missed)}")
    if failures:
        print(f"over budget: {', '.join(failures)}")
        if check:
            sys.exit(1)
    else:
        print("every enforced budget met")


if __name__ == "__main__":
    main(sys.argv[1:])
