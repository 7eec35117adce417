#!/usr/bin/env bash
# The network side in QEMU's mps2-an386 (Cortex-M4 + SMSC LAN9118): builds rc-gateway-mps2
# (emu-net/: the node's Modbus TCP side behind rc-net) and runs it with a free host port forwarded
# to the guest's TCP port 502.
#
#   scripts/emu-net.sh          # build, run; prints the port, the guest log goes to stdout
#   scripts/emu-net.sh build    # build only, prints the ELF's path
#   scripts/emu-net.sh test     # build, then the Modbus TCP suite against it (scripts/tcp-test.sh)
#
# QEMU: scripts/qemu-install.sh (qemu-system-arm 10.0 from bookworm-backports).
set -euo pipefail
cd "$(dirname "$0")/.."
target=thumbv7em-none-eabihf
elf=$PWD/target/$target/release/rc-gateway-mps2

rustup toolchain install >/dev/null 2>&1 || rustup toolchain install
# The workspace's linker for this target (.cargo/config.toml).
scripts/flip-link-install.sh
cargo build --release --locked -p rc-gateway-mps2 --target "$target" >&2

case "${1:-run}" in
build)
    echo "$elf"
    ;;
test)
    exec scripts/tcp-test.sh --target firmware
    ;;
run)
    port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
    echo "emu-net: guest TCP port 502 is 127.0.0.1:$port (Ctrl-C ends QEMU)" >&2
    echo "$port"
    exec qemu-system-arm -M mps2-an386 -nographic -monitor none -serial null \
        -icount shift=auto \
        -semihosting-config enable=on,target=native \
        -nic "user,hostfwd=tcp:127.0.0.1:$port-:502" \
        -kernel "$elf"
    ;;
*)
    echo "usage: $0 [run|build|test]" >&2
    exit 2
    ;;
esac
