"""Counts the clients the firmware resets as they connect right after others closed (issue 36):
rounds of four clients that each read a register and close, then a fifth at once that reads,
against rc-gateway-mps2 in QEMU (conftest.py starts it; RC_GATEWAY_MPS2_ELF picks another
build). Not a test: it prints counts. See docs/development.md, "The network side in QEMU".

    python tests/tcp/reconnect_burst.py [ROUNDS] [PAUSE-S] [PCAP]

PAUSE-S is the wait between rounds (0: back to back, where the last round's connections are
still ending); PCAP, if given, is where QEMU writes the guest's frames (-object filter-dump).
Use the emulator venv's python (scripts/py-env.sh) after scripts/emu-net.sh build.
"""

import socket
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import conftest  # noqa: E402
from test_modbus_tcp import DIRECT, GATEWAY, UNITID, Client  # noqa: E402


def with_dump(pcap):
    """Makes conftest start QEMU with its user netdev's frames dumped to `pcap`."""
    popen = conftest.subprocess.Popen

    def start(args, **kw):
        if args and args[0] == conftest.QEMU:
            i = args.index("-nic")
            netdev = args[i + 1].replace("user,", "user,id=n0,", 1)
            args = args[:i] + ["-netdev", netdev, "-net", "nic,netdev=n0",
                               "-object", f"filter-dump,id=f0,netdev=n0,file={pcap}"] + args[i + 2:]
        return popen(args, **kw)

    conftest.subprocess.Popen = start


def served(port):
    """Whether a new client gets its reply (False: reset or closed)."""
    try:
        c = Client(port)
        try:
            return c.read(DIRECT, UNITID, 1) == [GATEWAY]
        finally:
            c.close()
    except (ConnectionError, OSError, socket.timeout):
        return False


def main():
    rounds = int(sys.argv[1]) if len(sys.argv) > 1 else 100
    pause = float(sys.argv[2]) if len(sys.argv) > 2 else 0.0
    if len(sys.argv) > 3:
        with_dump(sys.argv[3])
    gateway = conftest.start_firmware()
    fifth_reset = four_reset = clean = clean_reset = 0
    try:
        for r in range(rounds):
            four = [Client(gateway.port) for _ in range(4)]
            failed = 0
            for c in four:
                try:
                    assert c.read(DIRECT, UNITID, 1) == [GATEWAY]
                except (ConnectionError, OSError):
                    failed += 1
            for c in four:
                c.close()
            ok = served(gateway.port)
            four_reset += failed
            fifth_reset += not ok
            if failed == 0:
                clean += 1
                clean_reset += not ok
            if failed or not ok:
                print(f"round {r}: {failed} of four reset, fifth {'served' if ok else 'reset'}",
                      flush=True)
            time.sleep(pause)
    finally:
        gateway.stop()
    print(f"fifth reset {fifth_reset}/{rounds} (in rounds whose four were served: "
          f"{clean_reset}/{clean}); of the four, {four_reset}/{4 * rounds} reset")


if __name__ == "__main__":
    main()
