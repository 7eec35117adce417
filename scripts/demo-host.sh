#!/usr/bin/env bash
# `scripts/demo.sh --host-gateway`: the gateway's code (the firmware's `protocol::node::Node`) on
# the PC instead of the firmware in QEMU: simulated Robo Cylinders on the bus, a scripted PLC
# writing and reading the gateway's Modbus registers (virtual time, so it is exact and quick);
# then the codec at work on the vendor documents' own examples through the `rcframe` bus tool.
set -euo pipefail
cd "$(dirname "$0")/.."
rustup toolchain install >/dev/null 2>&1 || rustup toolchain install
cargo build --quiet --locked -p rc-tools -p rc-host --bin rcframe --bin demo
rcframe=target/debug/rcframe

echo "== The gateway with simulated actuators and a scripted PLC"
target/debug/demo
echo

show() { printf '\n$ rcframe %s\n' "$*"; "$rcframe" "$@"; }

echo "== Encoding the brief edition's examples (§5-2, §5-3) =="
show encode 3 o --home motor
show encode 2 v --mm-s 100 --g 0.2 --lead 2.5
show encode C a --mm 56.8 --lead 6 --home motor
show encode 0 Q3 --point 11
show encode 5 W4 --mm 32.45 --lead 8 --home motor
show encode 0 h a --mm 100 --lead 10 --home motor --twos
show encode 0 enq

echo
echo "== Decoding a position response (§5-2 7): 896.72 mm =="
show decode U0R4FFFF167AFE --lead 12 --home motor

echo
echo "== A printed example with a wrong BCC (§5-2 5) is caught =="
show decode CmFFFFE26A00F6 || echo "(exit status $?: BCC mismatch reported)"

echo
echo "== A capture with line noise and a cut-off frame between good frames =="
capture='02 30 6E 30 30 30 30 30 30 30 30 30 30 38 32 03  FF 00 13  02 55 30 6E
         02 55 30 52 34 46 46 46 46 31 36 37 41 46 45 03'
printf '\n$ echo "%s" | rcframe decode - --summary\n' "$capture"
echo "$capture" | "$rcframe" decode - --summary || echo "(exit status $?: the capture had a bad candidate)"
