"""`rcgw update` against the real firmware in QEMU (issue 37): an image over the PLC line into the
emulator build's DFU partition (32 KiB of RAM: QEMU's b-l475e-iot01a cannot write its flash, so
the flash driver is not exercised here; src/dfu/), erased, written and read back in the gateway
task's bounded steps, and reported ready (UPDSTAT state 5); meanwhile the bus keeps being polled
and the stop input still stops. The image is signed with the public TEST key (`rcgw sign
--test-key`), which the emulator build verifies with. Then the refusals rcgw explains before
sending anything (exit 2): an unsigned file, another board's image and an image larger than the
partition."""

import json
import os
import random
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "pyshared"))

from emu import HWM_UPDATE_LOG, STOP_INPUT, Emulator, record_stack  # noqa: E402
from plc import wait_for  # noqa: E402

TARGET = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
RCGW = TARGET / "debug" / "rcgw"

# The emulator build's partition (`dfu::EMU_PARTITION`) and the L475's board id (`dfu::BOARD_ID`).
PARTITION = 32 * 1024
BOARD = "0x0475"
# The longest the bus may go without a frame to the axis while the image goes in: an idle axis is
# polled every few tens of ms; a DFU step holds the gateway task for far less than this.
MAX_BUS_GAP_S = 0.5


@pytest.fixture(scope="module", autouse=True)
def rcgw_built():
    result = subprocess.run(["cargo", "build", "--locked", "--quiet", "-p", "rc-tools", "--bin", "rcgw"],
                            cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]


def rcgw(pty, *args, timeout=180):
    return subprocess.run([str(RCGW), "--rtu", pty, *args], capture_output=True, text=True, timeout=timeout)


def rcgw_json(pty, *args):
    result = rcgw(pty, "--json", *args)
    assert result.returncode == 0, f"rcgw {' '.join(args)}: {result.returncode}\n{result.stdout}\n{result.stderr}"
    return json.loads(result.stdout)


def sign(tmp_path, name, app, *args):
    """`app` signed with the TEST key into tmp_path/name: the image's bytes."""
    app_path = tmp_path / (name + ".app")
    app_path.write_bytes(app)
    out = tmp_path / name
    result = subprocess.run([str(RCGW), "sign", str(app_path), "--test-key", "--version", "0.9.1",
                             "--out", str(out), *args], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, f"rcgw sign: {result.returncode}\n{result.stdout}\n{result.stderr}"
    assert "TEST key" in result.stderr, result.stderr
    return out.read_bytes()


def crc32(data):
    import zlib
    return zlib.crc32(data) & 0xFFFFFFFF


def test_rcgw_update_fills_the_partition_while_the_bus_is_served(elf, tmp_path):
    emu = Emulator(elf, tmp_path, "1", plc=False)
    try:
        emu.start(stop_closed=True)
        pty = emu.plc_pty()
        idle = rcgw_json(pty, "update", "--status")
        assert (idle["state"], idle["partition"], idle["board"]) == ("idle", PARTITION, int(BOARD, 16)), idle

        # Not a multiple of 8: the last chunk is padded to the flash word. Most of the partition.
        # A stretch without a transfer, to compare the bus' gaps with.
        quiet_from = time.monotonic() - emu.sim_started
        time.sleep(3.0)
        quiet = [c[0] for c in emu.bus_commands(0) if c[0] >= quiet_from]
        quiet_gaps = [b - a for a, b in zip(quiet, quiet[1:])]

        # The application not a multiple of 8: the trailer follows its padding.
        app = random.Random(37).randbytes(PARTITION - 4093 - 96)
        image = sign(tmp_path, "image.bin", app)
        path = tmp_path / "image.bin"
        assert len(image) < PARTITION
        started = time.monotonic() - emu.sim_started
        update = subprocess.Popen([str(RCGW), "--rtu", pty, "--json", "update", str(path)],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        # The stop chain opens while the image goes in: the axis gets its stop at once.
        time.sleep(1.0)
        assert update.poll() is None, "the transfer ended before the stop: make the image larger"
        opened = time.monotonic() - emu.sim_started
        emu.set_pin(STOP_INPUT, False)
        wait_for(lambda: any(c[2] == "CancelMotion" and c[0] >= opened for c in emu.bus_commands(0)), 5,
                 "the stop on the bus during the transfer")
        stop_at = next(c[0] for c in emu.bus_commands(0) if c[2] == "CancelMotion" and c[0] >= opened)
        out, err = update.communicate(timeout=180)
        ended = time.monotonic() - emu.sim_started
        assert update.returncode == 0, f"rcgw update: {update.returncode}\n{out}\n{err}"
        done = json.loads(out)
        assert update.poll() is not None and stop_at < ended, "the stop came after the transfer"

        # The bus was polled all along: no long gap between the frames to the axis.
        during = [c[0] for c in emu.bus_commands(0) if started <= c[0] <= ended]
        gaps = [b - a for a, b in zip(during, during[1:])]
        assert len(during) > 20 and max(gaps) < MAX_BUS_GAP_S, (len(during), max(gaps, default=None))
        print(f"transfer {ended - started:.1f} s, {len(during)} frames to the axis, largest gap "
              f"{max(gaps) * 1000:.0f} ms (without a transfer {max(quiet_gaps) * 1000:.0f} ms), "
              f"stop {1000 * (stop_at - opened):.0f} ms after the input opened")

        # UPDSTAT: state 5 (ready), every byte written, the image's CRC-32 checked on what the
        # firmware read back from its partition.
        s = rcgw_json(pty, "update", "--status")
        assert (s["state"], s["next"], s["size"]) == ("ready", len(image), len(image)), s
        assert s["crc32"] == f"{crc32(image):08x}" == done.get("crc32", s["crc32"]), (s, done)
        shown = rcgw(pty, "update", "--status")
        assert shown.returncode == 0, shown.stderr
        assert "state      ready" in shown.stdout, shown.stdout
        assert f"{len(image)} of {len(image)} bytes written" in shown.stdout, shown.stdout

        # An unsigned file: rcgw reads its trailer first, exit 2.
        unsigned = tmp_path / "unsigned.bin"
        unsigned.write_bytes(app)
        plain = rcgw(pty, "update", str(unsigned))
        assert plain.returncode == 2, (plain.returncode, plain.stdout, plain.stderr)
        assert "not a signed image" in plain.stderr and "rcgw sign" in plain.stderr, plain.stderr
        # Another board's image: rcgw reads the gateway's board id (UPDSTAT) and refuses it
        # before anything is sent, naming both, exit 2.
        sign(tmp_path, "other.bin", app, "--board", "0x0429")
        other = rcgw(pty, "update", str(tmp_path / "other.bin"))
        assert other.returncode == 2, (other.returncode, other.stdout, other.stderr)
        assert "0x0429" in other.stderr and "0x0475" in other.stderr, other.stderr
        # Larger than the partition: refused by rcgw before anything is sent, exit 2.
        large = sign(tmp_path, "large.bin", bytes(PARTITION + 1))
        too_large = rcgw(pty, "update", str(tmp_path / "large.bin"))
        assert too_large.returncode == 2, (too_large.returncode, too_large.stdout, too_large.stderr)
        assert str(len(large)) in too_large.stderr and str(PARTITION) in too_large.stderr, too_large.stderr
        # Neither touched the image that is there.
        after = rcgw_json(pty, "update", "--status")
        assert (after["state"], after["crc32"]) == ("ready", s["crc32"]), after
        assert "panicked" not in "\n".join(emu.log()), emu.log()[-20:]
    except BaseException:
        if emu.process is not None:
            print("firmware log:\n" + "\n".join(emu.log()[-80:]))
            print("rc-sim:\n" + "\n".join(emu.sim_log()[-40:]))
        raise
    finally:
        record_stack(emu.stop(), "test_rcgw_update_fills_the_partition_while_the_bus_is_served", HWM_UPDATE_LOG)
