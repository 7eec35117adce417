"""A signed firmware image, made without our Rust code: the format as boot/src/image.rs documents
it, with Python's hashlib, zlib and the `cryptography` package's Ed25519 (OpenSSL's). The tests
that send these to the real firmware check our reading of the format against another
implementation, not against itself."""

import hashlib
import struct
import zlib

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

MAGIC = b"RCGWIMG1"
# rc-boot's TEST key (`rc_boot::TEST_KEY_SEED`): public, for tests and the emulator only.
TEST_SEED = b"rc-gateway TEST KEY: never ship!"
BOARD_L475 = 0x0475


def version_word(major, minor, patch):
    return major << 24 | minor << 16 | patch


def sign(app, board=BOARD_L475, version=(1, 2, 3), seed=TEST_SEED):
    """The image file: the application padded with 0xFF to 8 bytes, then the 96-byte trailer
    (header, Ed25519 over SHA-512 of the padded application and the header, CRC-32, zero)."""
    body = app + b"\xff" * (-len(app) % 8)
    header = MAGIC + struct.pack("<HHIII", board, 0, version_word(*version), len(app), 0)
    assert len(header) == 24
    digest = hashlib.sha512(body + header).digest()
    signature = Ed25519PrivateKey.from_private_bytes(seed).sign(digest)
    crc = zlib.crc32(header + signature) & 0xFFFFFFFF
    return body + header + signature + struct.pack("<II", crc, 0)
