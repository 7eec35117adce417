"""rcgw against the real firmware in QEMU (issue 23's round trip): commission with `config
apply` (APPLY and all), seed two point rows with a restore, back up, factory-reset the gateway
(the firmware restarts with its defaults: QEMU has no flash to keep anything), restore the backup,
back up again: the two backups are identical. rcgw reaches the firmware's PLC line through a
pseudo-terminal bridged to QEMU's socket (as libmodbus and mbpoll do in scripts/interop.sh)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "pyshared"))

from emu import Emulator  # noqa: E402
from plc import wait_for  # noqa: E402

TARGET = Path(__import__("os").environ.get("CARGO_TARGET_DIR", ROOT / "target"))
RCGW = TARGET / "debug" / "rcgw"

CONFIG = """
[gateway]
watchdog_ms = 0
pio_axis = "none"

[axis.0]
enabled = true
lead_mm = 8.00
home = "motor"

[axis.1]
enabled = true
lead_mm = 8.00
home = "motor"
"""

POINTS = """
[[axis.1.point]]
point = 2
position_mm = 33.50
speed_mm_s = 120.00
accel_g = 0.30
band_mm = 0.10

[[axis.1.point]]
point = 7
position_mm = 80.00
speed_mm_s = 50.00
accel_g = 0.20
band_mm = 0.50
"""


@pytest.fixture(scope="module", autouse=True)
def rcgw_built():
    result = subprocess.run(["cargo", "build", "--locked", "--quiet", "-p", "rc-tools", "--bin", "rcgw"],
                            cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]


def rcgw(pty, *args, timeout=120):
    """rcgw on the firmware's PLC line; its JSON answer (exit status 0 required)."""
    result = subprocess.run([str(RCGW), "--rtu", pty, "--json", *args], capture_output=True, text=True,
                            timeout=timeout)
    assert result.returncode == 0, f"rcgw {' '.join(args)}: {result.returncode}\n{result.stdout}\n{result.stderr}"
    return json.loads(result.stdout) if result.stdout.strip() else None


def test_apply_backup_factory_reset_restore_backup_is_identical(elf, tmp_path):
    emu = Emulator(elf, tmp_path, "0-1", plc=False)
    try:
        emu.start(stop_closed=True)
        pty = emu.plc_pty()
        config = tmp_path / "config.toml"
        config.write_text(CONFIG)
        applied = rcgw(pty, "config", "apply", str(config))
        assert applied["applied"] is True, applied
        status = rcgw(pty, "status")
        assert [a["link"] for a in status["axes"]] == ["online", "online"], status

        # Two point rows on axis 1 (a restore of the backup with them added: what a user editing
        # a backup does), then the backup that is the reference.
        b0 = tmp_path / "b0.toml"
        rcgw(pty, "backup", str(b0))
        seeded = tmp_path / "seeded.toml"
        seeded.write_text(b0.read_text() + POINTS)
        rcgw(pty, "restore", str(seeded))
        b1 = tmp_path / "b1.toml"
        rcgw(pty, "backup", str(b1))
        first = b1.read_text()
        assert "point = 7" in first and "lead_mm = 8.00" in first, first

        # Factory reset: the firmware restarts with its defaults (axis 0 only, watchdog 1 s).
        starts = sum("starting" in line for line in emu.log())
        rcgw(pty, "factory-reset", "--yes")
        wait_for(lambda: sum("starting" in line for line in emu.log()) > starts, 30, "the firmware restarting")
        wait_for(lambda: sum("INFO  ready" in line for line in emu.log()) > starts, 30, "ready again")
        shown = subprocess.run([str(RCGW), "--rtu", pty, "config", "show"], capture_output=True, text=True,
                               timeout=60)
        assert shown.returncode == 0, shown.stderr
        assert "[axis.1]\nenabled = false" in shown.stdout, shown.stdout

        # The controllers kept their point tables (they are the controllers'); the gateway's
        # settings come back from the backup, and the rows are checked (unchanged: not written).
        report = rcgw(pty, "restore", str(b1))
        assert report["settings"], report
        b2 = tmp_path / "b2.toml"
        rcgw(pty, "backup", str(b2))
        assert b2.read_text() == first
    except BaseException:
        # What a failure needs to be understood (pytest shows it with the failure): the
        # firmware's log, the bus as rc-sim saw it, and the gateway's own counters (a CRC error
        # on the PLC line is a request it did not take whole).
        print("firmware log:\n" + "\n".join(emu.log()[-150:]))
        print("rc-sim:\n" + "\n".join(emu.sim_log()[-80:]))
        if emu.plc_port is not None and "pty" in locals():
            diag = subprocess.run([str(RCGW), "--rtu", pty, "diag"], capture_output=True, text=True, timeout=60)
            print("rcgw diag:\n" + diag.stdout + diag.stderr)
        raise
    finally:
        emu.stop()
