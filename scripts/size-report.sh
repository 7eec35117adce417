#!/usr/bin/env bash
# Flash and RAM of the hardware firmware of every board against its budget, with the stack
# high-water mark measured in the emulator (scripts/emu-test.sh paints the stack and measures each
# test; the L475 emulator build runs the same tasks as both hardware builds) or, if deeper, the
# hardware build's start-up path by its call graph (scripts/stack_depth.py: the settings load
# from flash, which QEMU cannot run).
#
#   scripts/size-report.sh           # builds every board, reuses the emulator's stack log when it
#                                    # is newer than the emulator ELF (else runs the emulator suite)
#   scripts/size-report.sh --check   # the same, exit status 1 when the F103 or the F429 is over
#                                    # budget
#   SIZE_TOP=30 scripts/size-report.sh   # and the 30 largest symbols per board (default 12)
#
# Budgets: STM32F103C8 56 KiB flash (of its 60 KiB outside the settings pages) and 16 KiB static
# RAM + stack, enforced: it is the chip that limits the firmware, and its build is the one linked
# for it (memory/f103c8.x), so a build that outgrows the chip does not even link. B-L475E-IOT01A
# (STM32L475VG, 1 MiB flash) 96 KiB flash and 20 KiB static RAM + stack for the application: a
# target, reported (its partition, ACTIVE, is 480 KiB; 96 KiB keeps an update over 115.2 kbit/s
# RTU near 12 s; 48 KiB until its firmware update took Ed25519, SHA-512 and embassy-boot's state).
# Its bootloader (rc-bootloader) 32 KiB flash, enforced (its partition: the application is linked
# behind it), and 8 KiB of RAM + stack (it runs before the application, in the same RAM).
# NUCLEO-F429ZI (STM32F429ZI, Ethernet: Modbus TCP beside RTU) 128 KiB flash and 64 KiB static
# RAM + stack, enforced: the chip has 1 MiB of program flash and 192 KiB of SRAM, so the budget
# is not the chip's limit but a fence against growth. 128 KiB of flash leaves about 40 KiB over
# the first build (89 KiB) and fits the smallest STM32 with this Ethernet MAC; 64 KiB of RAM is
# a third of the chip's, with the Ethernet frames (12 KiB), the TCP buffers (10 KiB), the
# socket pipes (8 KiB) and the node (13 KiB) in it, and leaves the rest for more frames or
# sockets. Its stack is the deeper of the L475 emulator's (no TCP: an underestimate of the
# gateway task's) and its own start-up path by the call graph (with its own, larger node). Its
# application is linked into ACTIVE (sectors 5-10, 768 KiB) and its bootloader, 32 KiB enforced
# and 8 KiB of RAM + stack as the L475's, into the first 128 KiB (rc_boot::layout::F429).
set -euo pipefail
cd "$(dirname "$0")/.."

check=0
[[ ${1:-} == --check ]] && check=1

rustup toolchain install >/dev/null 2>&1 || rustup toolchain install
# The firmware's linker (.cargo/config.toml).
scripts/flip-link-install.sh
# The F429 first: it is built for the same target as the L475 and writes the same ELF path, so
# its ELF is copied aside before the L475's build replaces it. Both with a key, as a board is
# built (README, "Updating the firmware"): without one the image's signature check is not linked
# at all (7 KB less). Which key does not matter: the TEST key's public half, boot/test-key.pub.
RC_GATEWAY_UPDATE_KEY=$PWD/boot/test-key.pub cargo fw-eth --locked --quiet
mkdir -p target/f429
cp target/thumbv7em-none-eabihf/release/rc-gateway target/f429/rc-gateway
cargo boot-f429 --locked --quiet
cp target/thumbv7em-none-eabihf/release/rc-bootloader target/f429/rc-bootloader
RC_GATEWAY_UPDATE_KEY=$PWD/boot/test-key.pub cargo fw --locked --quiet
cargo boot-l475 --locked --quiet
# The F103 build as it is flashed (`cargo fw-run-f103`).
cargo fw-f103 --locked --quiet

hwm=target/emu/stack-hwm.log
emu_elf=target/emu/target/thumbv7em-none-eabihf/release/rc-gateway
if ! [[ -s $hwm && -f $emu_elf && $hwm -nt $emu_elf ]]; then
    scripts/emu-test.sh -q >/dev/null
fi
python=$(scripts/py-env.sh)
# llvm-objdump from rustup's llvm-tools (rust-toolchain.toml), for the start-up stack.
objdump="$(rustc --print sysroot)/lib/rustlib/$(rustc -vV | sed -n 's/^host: //p')/bin/llvm-objdump"

"$python" scripts/size_report.py "${SIZE_TOP:-12}" "$hwm" "$check" "$objdump" \
    "L475 B-L475E-IOT01A (STM32L475VG), the application in ACTIVE" target/thumbv7em-none-eabihf/release/rc-gateway \
        0x08008000 0x08080000 0x20000000 0x20018000 96 20 0 \
    "L475-bootloader rc-bootloader (embassy-boot), its 32 KiB" target/thumbv7em-none-eabihf/release/rc-bootloader \
        0x08000000 0x08008000 0x20000000 0x20018000 32 8 1 \
    "F103 STM32F103C8 (blue pill)" target/thumbv7m-none-eabi/release/rc-gateway \
        0x08000000 0x0800F000 0x20000000 0x20005000 56 16 1 \
    "F429 NUCLEO-F429ZI (STM32F429ZI, Ethernet), the application in ACTIVE" target/f429/rc-gateway \
        0x08020000 0x080E0000 0x20000000 0x20030000 128 64 1 \
    "F429-bootloader rc-bootloader (embassy-boot), 32 KiB of its 128 KiB" target/f429/rc-bootloader \
        0x08000000 0x08008000 0x20000000 0x20030000 32 8 1
# The update path's stack (the L475's SHA-512 and Ed25519 check in the gateway task), measured by
# the emulator's update tests apart from the log above (the F103, held to that one, has no update).
update_hwm=target/emu/stack-hwm-update.log
if [[ -s $update_hwm ]]; then
    deepest=$(sort -n "$update_hwm" | tail -1)
    general=$(sort -n "$hwm" | tail -1 | cut -d' ' -f1)
    echo "L475 stack with an update under way (emulator): ${deepest%% *} B (${deepest#* }); without: $general B"
fi
