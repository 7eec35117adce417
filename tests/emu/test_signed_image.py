"""The signature check of a firmware image on the real firmware in QEMU (issue 37), with neither
our signer nor our Modbus master: images made by tests/pyshared/signed_image.py (OpenSSL's
Ed25519, Python's SHA-512 and CRC-32, from the format boot/src/image.rs documents), sent by
pymodbus through UPDCTL, UPDCHUNK and UPDSTAT (protocol/src/plc/update). The firmware reads each
image back from its DFU partition (RAM in the emulator), checks its trailer, its SHA-512 and its
signature with rc-boot's TEST key in bounded steps, and marks it with embassy-boot's
`mark_updated` (RAM STATE pages in the emulator): BOOTSTAT then shows the version marked. An
image with a flipped byte, another key's signature, another board's trailer, or no trailer at
all fails FINISH with its reason and is not marked."""

import random
import sys
import time
import zlib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "pyshared"))

from emu import HWM_UPDATE_LOG, Emulator, record_stack  # noqa: E402
from plc import ModbusError, crc16, wait_for  # noqa: E402
from signed_image import BOARD_L475, sign, version_word  # noqa: E402

GW = 63
UPDCTL, BOOTSTAT, UPDSTAT, UPDCHUNK = 0x0700, 0x0708, 0x0710, 0x0720
BEGIN, FINISH = 1, 2
MAX_CHUNK = 232
# UPDSTAT's states and UPDATE errors (protocol::plc::update).
ERASING, RECEIVING, FINISHING, READY, FAILED = 1, 2, 4, 5, 6
NOT_AN_IMAGE, SIGNATURE = 14, 15
# BOOTSTAT's states: confirmed (the emulator's STATE pages start erased: nothing swapped).
CONFIRMED = 1


def patiently(call, timeout=60):
    """Retries a request the gateway answers "busy" (04: the flash still at the last job)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return call()
        except ModbusError as e:
            if e.code != 4 or time.monotonic() > deadline:
                raise
            time.sleep(0.01)


def status(plc):
    state, error = plc.read(GW, UPDSTAT, 2)
    return state, error


def send(plc, image):
    """BEGIN, every chunk, FINISH: UPDSTAT's state and error once FINISH is done."""
    crc = zlib.crc32(image) & 0xFFFFFFFF
    n = len(image)
    patiently(lambda: plc.write(GW, UPDCTL, [BEGIN, n >> 16, n & 0xFFFF, crc >> 16, crc & 0xFFFF, BOARD_L475]))
    wait_for(lambda: status(plc)[0] != ERASING, 60, "the erase")
    assert status(plc)[0] == RECEIVING, status(plc)
    for offset in range(0, n, MAX_CHUNK):
        chunk = image[offset:offset + MAX_CHUNK]
        padded = chunk + b"\x00" * (len(chunk) % 2)
        words = [int.from_bytes(padded[i:i + 2], "big") for i in range(0, len(padded), 2)]
        check = int.from_bytes(crc16(chunk), "little")
        registers = [offset >> 16, offset & 0xFFFF, len(chunk), check] + words
        patiently(lambda: plc.write(GW, UPDCHUNK, registers))
    patiently(lambda: plc.write(GW, UPDCTL, [FINISH]))
    wait_for(lambda: status(plc)[0] != FINISHING, 60, "the check")
    return status(plc)


def bootstat(plc):
    state, hi, lo = plc.read(GW, BOOTSTAT, 3)
    return state, hi << 16 | lo


def test_the_firmware_takes_only_an_image_signed_with_its_key(elf, tmp_path):
    emu = Emulator(elf, tmp_path, "1")
    try:
        emu.start(stop_closed=True)
        plc = emu.plc
        assert bootstat(plc) == (CONFIRMED, 0)
        app = random.Random(37).randbytes(9_001)

        tampered = bytearray(sign(app))
        tampered[4_000] ^= 0x01
        other_key = sign(app, seed=b"another key, not the gateway's!!")
        other_board = sign(app, board=0x0429)
        for name, image, reason in [
            ("a flipped byte", bytes(tampered), SIGNATURE),
            ("another key", other_key, SIGNATURE),
            ("another board", other_board, NOT_AN_IMAGE),
            ("no trailer", app, NOT_AN_IMAGE),
        ]:
            assert send(plc, image) == (FAILED, reason), name
            assert bootstat(plc) == (CONFIRMED, 0), name

        good = sign(app, version=(2, 5, 17))
        assert send(plc, good) == (READY, 0)
        assert bootstat(plc) == (CONFIRMED, version_word(2, 5, 17))
        assert "panicked" not in "\n".join(emu.log()), emu.log()[-20:]
    except BaseException:
        if emu.process is not None:
            print("\n".join(emu.log()[-40:]))
        raise
    finally:
        record_stack(emu.stop(), "test_the_firmware_takes_only_an_image_signed_with_its_key", HWM_UPDATE_LOG)
