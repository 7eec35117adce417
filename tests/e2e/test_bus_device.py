"""The `--bus PATH` side of rc-gateway-host (the one a real RS485 adapter uses: termios rate
changes, TIOCSBRK/TIOCCBRK, the communication establishment procedure) against `rc-sim` behind a
pseudo-terminal. rc-sim cannot see a break through a pseudo-terminal, so it runs with
--slow-baud-is-break: the engine's switch to 9.6 kbit/s right before its break stands for it.
"""

import subprocess

import pytest

from conftest import (
    ALMC,
    BINARY,
    DONE,
    DRG1,
    DRG1_CSTR,
    DRG1_HOME,
    DRG1_SON,
    DSS1_ALMH,
    DSS1_HEND,
    FAILED,
    LINK,
    POSR,
    REASON_ALARM,
    ROOT,
    Gateway,
    _read_first_line,
    _stop,
    unit,
    wait_for,
)

RC_SIM = BINARY.parent / "rc-sim"


@pytest.fixture
def bus_gateway(tmp_path):
    if not RC_SIM.exists():
        pytest.skip(f"{RC_SIM} is missing: cargo build -p rc-tools --bin rc-sim")
    with open(tmp_path / "rc-sim.log", "wb") as log:
        sim = subprocess.Popen(
            [str(RC_SIM), "--pty", "--axes", "2", "--slow-baud-is-break"],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=log,
        )
    host = None
    gw = None
    try:
        line, _ = _read_first_line(sim, timeout=10)
        assert line.startswith("PTY /dev/"), line
        bus_path = line.split(" ", 1)[1]
        log_path = tmp_path / "rc-gateway-host.log"
        with open(log_path, "wb") as log:
            host = subprocess.Popen(
                [str(BINARY), "--plc-pty", "--bus", bus_path, "--axes", "2", "--control", "--log"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=log,
                cwd=ROOT,
            )
        line, rest = _read_first_line(host, timeout=10)
        gw = Gateway(host, line.split(" ", 1)[1], log_path)
        gw._stdout = rest
        yield gw
    finally:
        if gw is not None:
            gw.close()
        if host is not None:
            _stop(host)
        sim.terminate()
        try:
            sim.wait(timeout=5)
        except subprocess.TimeoutExpired:
            sim.kill()
            sim.wait(timeout=5)
        sim.stdout.close()


def test_establishment_then_motion_over_a_serial_line(bus_gateway):
    gw = bus_gateway
    # Break, configuration at 9.6 kbit/s, communication change, then 115.2 kbit/s.
    # Poll meanwhile, like a PLC (the watchdog); the axes answer during the set-up already.
    wait_for(
        lambda: gw.read(unit(0), LINK) and "SetBaud(B115200)" in gw.log_path.read_text(errors="replace"),
        10.0,
        "establishment done",
    )
    for axis in (0, 1):
        wait_for(lambda: gw.read(unit(axis), LINK)[0] == 1, 10.0, f"axis {axis} online")
    log = gw.log_path.read_text(errors="replace")
    assert "line: BreakStart" in log and "line: BreakEnd" in log, "a break was sent"
    assert "line: CommChange" in log
    assert "line: SetBaud(B115200)" in log
    stats = gw.stats()
    assert stats["axes"][0]["link"] == "online"
    assert "frames_received" not in stats["axes"][0], "no simulator in this process"
    # Servo on, home, a direct move.
    gw.write(unit(1), DRG1, DRG1_SON)
    assert gw.settle(1) == (DONE, 0)
    gw.write(unit(1), DRG1, DRG1_SON | DRG1_HOME)
    wait_for(lambda: gw.dss1(1) & DSS1_HEND, 20.0, "HEND")
    assert gw.settle(1) == (DONE, 0)
    gw.direct(1, 33_33, speed=200_00)
    assert gw.settle(1) == (DONE, 0)
    wait_for(lambda: gw.pnow(1) == 33_33, 5.0, "PNOW 33.33 mm")
    assert gw.stats()["axes"][1]["sent"].get("a", 0) == 1
    # A point that was never stored: the controller raises alarm B1 (abnormal position data);
    # CMST reports the failure, CMER reason 4 (alarm) with the code.
    gw.write(unit(1), POSR, 9)
    gw.write(unit(1), DRG1, DRG1_SON)
    gw.write(unit(1), DRG1, DRG1_SON | DRG1_CSTR)
    assert gw.settle(1) == (FAILED, REASON_ALARM << 8 | 0xB1)
    wait_for(lambda: gw.dss1(1) & DSS1_ALMH, 5.0, "ALMH")
    assert gw.read(unit(1), ALMC) == [0xB1]
