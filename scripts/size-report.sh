#!/usr/bin/env bash
# Flash and RAM of the hardware firmware against the board's budget, with the stack high-water
# mark measured in the emulator (scripts/emu-test.sh paints the stack and measures each test).
#
#   scripts/size-report.sh              # builds, runs the emulator tests, prints the report
#   SIZE_TOP=30 scripts/size-report.sh  # and the 30 largest symbols (default 15)
#
# Budget for the finished firmware on the B-L475E-IOT01A: 48 KiB flash, 16 KiB static RAM + stack.
set -euo pipefail
cd "$(dirname "$0")/.."

rustup toolchain install >/dev/null 2>&1 || rustup toolchain install
cargo fw --locked --quiet
# Runs the whole emulator suite: the high-water mark is the deepest any test drove the stack to.
scripts/emu-test.sh -q >/dev/null

target/emu-venv/bin/python - target/thumbv7em-none-eabihf/release/rc-gateway target/emu/stack-hwm.log \
    "${SIZE_TOP:-15}" <<'PY'
import sys
from elftools.elf.constants import SH_FLAGS
from elftools.elf.elffile import ELFFile

elf_path, hwm_path, top = sys.argv[1], sys.argv[2], int(sys.argv[3])
FLASH, RAM = (0x0800_0000, 0x0810_0000), (0x2000_0000, 0x2001_8000)
FLASH_BUDGET, RAM_BUDGET = 48 * 1024, 16 * 1024

def demangle(name):
    """Rust's legacy mangling (`_ZN` len-prefixed segments, a hash last), readably; else as is."""
    import re
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

def inside(address, region):
    return region[0] <= address < region[1]

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
    flash = {s.name: s["sh_size"] for s in sections if inside(load.get(s.name, s["sh_addr"]), FLASH)
             and s["sh_type"] != "SHT_NOBITS"}
    ram = {s.name: s["sh_size"] for s in sections if inside(s["sh_addr"], RAM)}
    symbols = sorted(
        ((sym["st_size"], sym.name, "flash" if inside(sym["st_value"], FLASH) else "ram")
         for sym in elf.get_section_by_name(".symtab").iter_symbols()
         if sym["st_size"] and sym["st_info"]["type"] in ("STT_FUNC", "STT_OBJECT")),
        reverse=True)

try:
    lines = [line.split() for line in open(hwm_path) if line.strip()]
    stack = max(int(n) for n, _ in lines)
    deepest = [name for n, name in lines if int(n) == stack]
    deepest = (f"in all {len(lines)} tests" if len(deepest) == len(lines)
               else f"deepest in {', '.join(deepest[:3])}")
except (OSError, ValueError):
    sys.exit(f"no stack measurement in {hwm_path}: did scripts/emu-test.sh run?")

flash_total = sum(flash.values())
static_ram = sum(ram.values())
def kib(n):
    return f"{n / 1024:6.1f} KiB"

print(f"rc-gateway (hw build): {elf_path}")
print(f"  flash        {kib(flash_total)}  ({', '.join(f'{k} {v}' for k, v in flash.items())})"
      f"  budget {kib(FLASH_BUDGET)}")
print(f"  static RAM   {kib(static_ram)}  ({', '.join(f'{k} {v}' for k, v in ram.items())})")
print(f"  stack HWM    {kib(stack)}  ({stack} B, {deepest}; emulator build, an upper bound)")
print(f"  RAM + stack  {kib(static_ram + stack)}  budget {kib(RAM_BUDGET)}")
print(f"  largest symbols:")
from itertools import islice
for size, name, where in islice(symbols, top):
    print(f"    {size:6d}  {where:5s}  {demangle(name)[:100]}")
over = []
if flash_total > FLASH_BUDGET:
    over.append("flash")
if static_ram + stack > RAM_BUDGET:
    over.append("RAM")
if over:
    sys.exit(f"over budget: {', '.join(over)}")
PY
