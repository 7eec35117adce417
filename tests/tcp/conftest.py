"""The Modbus TCP side, end to end, against two targets (`--target` picks; both by default):

- `host`: rc-gateway-host --modbus-tcp 127.0.0.1:0 --sim 3 (the firmware's node on the PC, with
  simulated axes);
- `firmware`: the network build of the firmware (rc-gateway-mps2) in QEMU's mps2-an386, its
  LAN9118 forwarded to a free host port (`-nic user,hostfwd`): the same node and network task
  (rc-net) as the Ethernet board. It has no RS485 bus: its axes never come online.

Each test gets a fresh gateway. Every wait is bounded; nothing is timed but the generous limits
of what the gateway must do (close an idle connection, trip the watchdog).
"""

import os
import socket
import subprocess
import tempfile
import time

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TARGET = os.environ.get("CARGO_TARGET_DIR", os.path.join(ROOT, "target"))
HOST_BIN = os.path.join(TARGET, "debug", "rc-gateway-host")
MPS2_ELF = os.environ.get("RC_GATEWAY_MPS2_ELF", os.path.join(TARGET, "thumbv7em-none-eabihf", "release", "rc-gateway-mps2"))
QEMU = os.environ.get("QEMU", "qemu-system-arm")
READY_TIMEOUT = 120.0


def pytest_addoption(parser):
    parser.addoption("--target", default="all", choices=["host", "firmware", "all"])


def pytest_generate_tests(metafunc):
    if "gateway" in metafunc.fixturenames:
        chosen = metafunc.config.getoption("--target")
        targets = ["host", "firmware"] if chosen == "all" else [chosen]
        metafunc.parametrize("gateway", targets, indirect=True)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Gateway:
    """A running gateway: where it listens, what it is, and how to end it."""

    def __init__(self, kind, port, process, log, plc=None):
        self.kind = kind
        self.port = port
        self.plc = plc
        self.process = process
        self.log = log

    def alive(self):
        return self.process.poll() is None

    def stop(self):
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(10)

    def log_tail(self):
        self.log.flush()
        self.log.seek(0)
        return self.log.read().decode(errors="replace")[-4000:]


def start_host(extra=()):
    log = tempfile.TemporaryFile()
    process = subprocess.Popen(
        [HOST_BIN, "--modbus-tcp", "127.0.0.1:0", "--sim", "3", "--points", "--watchdog-ms", "0",
         "--no-control", *extra],
        stdout=subprocess.PIPE, stderr=log, stdin=subprocess.DEVNULL,
    )
    line = process.stdout.readline().decode().strip()
    plc = None
    if line.startswith("PLC "):
        # With a serial PLC line too: it comes first, then the TCP line.
        plc = line[4:]
        line = process.stdout.readline().decode().strip()
    if not line.startswith("TCP "):
        process.kill()
        raise RuntimeError(f"rc-gateway-host did not start: {line!r}")
    port = int(line.rsplit(":", 1)[1])
    return Gateway("host", port, process, log, plc)


def start_firmware():
    port = free_port()
    log = tempfile.TemporaryFile()
    process = subprocess.Popen(
        [QEMU, "-M", "mps2-an386", "-nographic", "-monitor", "none", "-serial", "null",
         "-icount", "shift=auto", "-semihosting-config", "enable=on,target=native",
         "-nic", f"user,hostfwd=tcp:127.0.0.1:{port}-:502", "-kernel", MPS2_ELF],
        stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + READY_TIMEOUT
    gateway = Gateway("firmware", port, process, log)
    while True:
        if not gateway.alive():
            raise RuntimeError(f"QEMU ended: {gateway.log_tail()}")
        if b"ready" in gateway.log_tail().encode():
            break
        if time.monotonic() > deadline:
            gateway.stop()
            raise RuntimeError(f"the firmware did not start: {gateway.log_tail()}")
        time.sleep(0.1)
    return gateway


@pytest.fixture
def gateway(request):
    g = start_host() if request.param == "host" else start_firmware()
    yield g
    alive = g.alive()
    g.stop()
    assert alive, f"the gateway ended during the test:\n{g.log_tail()}"


@pytest.fixture
def start_host_with():
    """Starts rc-gateway-host with extra arguments (stopped at the end)."""
    started = []

    def start(*extra):
        g = start_host(extra)
        started.append(g)
        return g

    yield start
    for g in started:
        g.stop()
