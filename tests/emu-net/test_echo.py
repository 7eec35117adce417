#!/usr/bin/env python3
"""Emulator test of the network side (emu-net, QEMU mps2-an386 with its LAN9118).

Starts QEMU with the rc-gateway-mps2 ELF, a free host port forwarded to the guest's TCP port 502,
waits until the guest echoes (up to 60 s), then:
  1. four connections open at once, each sending its own data, each must get exactly its own echo;
  2. a fifth connection opened while those four are still open (all five sockets busy);
  3. the round-trip time of a small echo (median and worst of 200, TCP_NODELAY).
QEMU is killed at the end whatever happens.

Plain python3, standard library only:
    python3 tests/emu-net/test_echo.py [ELF]        (scripts/emu-net.sh test builds the ELF first)
"""

import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEFAULT_ELF = os.path.join(ROOT, "target/thumbv7em-none-eabihf/release/rc-gateway-mps2")
QEMU = os.environ.get("QEMU", "qemu-system-arm")
READY_TIMEOUT = 60.0
IO_TIMEOUT = 10.0


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def qemu_command(elf, port):
    return [
        QEMU, "-M", "mps2-an386", "-nographic", "-monitor", "none", "-serial", "null",
        "-icount", "shift=auto",
        "-semihosting-config", "enable=on,target=native",
        "-nic", f"user,hostfwd=tcp:127.0.0.1:{port}-:502",
        "-kernel", elf,
    ]


def connect(port):
    s = socket.create_connection(("127.0.0.1", port), timeout=IO_TIMEOUT)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return s


def recv_exactly(s, n):
    data = b""
    while len(data) < n:
        chunk = s.recv(n - len(data))
        if not chunk:
            raise AssertionError(f"connection closed after {len(data)} of {n} bytes")
        data += chunk
    return data


def echo(s, payload):
    s.sendall(payload)
    return recv_exactly(s, len(payload))


def wait_ready(port, log_path, proc):
    """Until an echo comes back: slirp accepts the host side of a connection before the guest
    is up, so only an echo proves the guest serves."""
    deadline = time.monotonic() + READY_TIMEOUT
    last = None
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise AssertionError(f"QEMU exited with {proc.returncode}:\n{open(log_path).read()}")
        try:
            with connect(port) as s:
                s.settimeout(2.0)
                if echo(s, b"ping") == b"ping":
                    return time.monotonic() - (deadline - READY_TIMEOUT)
        except (OSError, AssertionError) as e:
            last = e
        time.sleep(0.5)
    raise AssertionError(f"no echo within {READY_TIMEOUT} s ({last!r}):\n{open(log_path).read()}")


def concurrent_echo(port):
    """Four connections at once, each with its own data, then a fifth while they stay open."""
    conns = [connect(port) for _ in range(4)]
    try:
        payloads = [bytes([0x41 + i]) * (50 + 300 * i) + b"|conn%d" % i for i in range(4)]
        results = [None] * 4
        errors = []

        def worker(i):
            try:
                # Several rounds each, interleaved with the other connections' rounds.
                for r in range(5):
                    data = payloads[i] + b"#%d" % r
                    got = echo(conns[i], data)
                    if got != data:
                        raise AssertionError(f"connection {i} round {r}: wrong echo {got[:40]!r}")
                results[i] = True
            except Exception as e:  # reported below
                errors.append((i, e))

        threads = [threading.Thread(target=worker, args=(i,)) for i in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(IO_TIMEOUT * 3)
        assert not errors, f"concurrent echo failed: {errors}"
        assert all(results), f"a connection did not finish: {results}"
        # The fifth, while the four are open: every socket is then busy.
        fifth = connect(port)
        conns.append(fifth)
        assert echo(fifth, b"fifth connection") == b"fifth connection"
        # And the first four still answer, each its own.
        for i in range(4):
            data = b"again %d" % i
            assert echo(conns[i], data) == data, f"connection {i} after the fifth"
    finally:
        for c in conns:
            c.close()


def connect_when_free(port, timeout=IO_TIMEOUT):
    """A connection that echoes. Right after clients close, every socket may still be finishing
    its close (FIN handshake): a connection arriving then finds no socket listening and is reset
    (slirp accepted the host side, so the reset shows on the first read). Retry until one is
    free again."""
    deadline = time.monotonic() + timeout
    while True:
        s = connect(port)
        try:
            if echo(s, b"hello") == b"hello":
                return s
        except (OSError, AssertionError):
            s.close()
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def round_trip(port, n=200):
    with connect_when_free(port) as s:
        times = []
        for i in range(n):
            data = b"rtt%04d" % i
            t = time.perf_counter()
            assert echo(s, data) == data
            times.append((time.perf_counter() - t) * 1000.0)
    return statistics.median(times), max(times)


def main():
    elf = sys.argv[1] if len(sys.argv) > 1 else DEFAULT_ELF
    if not os.path.exists(elf):
        sys.exit(f"no ELF at {elf}: build it with scripts/emu-net.sh build")
    port = free_port()
    log = tempfile.NamedTemporaryFile(prefix="emu-net-", suffix=".log", delete=False)
    proc = subprocess.Popen(qemu_command(elf, port), stdout=log, stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL)
    ok = False
    try:
        ready = wait_ready(port, log.name, proc)
        print(f"guest echoes on 127.0.0.1:{port} after {ready:.1f} s")
        concurrent_echo(port)
        print("ok: 4 concurrent connections each got their own echo, and a 5th at the same time")
        median, worst = round_trip(port)
        print(f"round trip of a 7-byte echo: median {median:.2f} ms, worst {worst:.2f} ms (200)")
        ok = True
    finally:
        proc.kill()
        proc.wait()
        log.close()
        if not ok:
            print(f"guest log ({log.name}):\n{open(log.name).read()}", file=sys.stderr)
        else:
            os.unlink(log.name)
    print("PASS")


if __name__ == "__main__":
    main()
