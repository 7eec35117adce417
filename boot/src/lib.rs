//! The bootloader's core for the gateway (issue 37): the flash layout embassy-boot works on,
//! the signed image format, and the application's check-and-mark step.
//!
//! * [`layout`]: the L475's partitions (BOOTLOADER, ACTIVE, DFU, STATE, and the settings pages
//!   left alone), with embassy-boot's size rules checked at compile time.
//! * [`image`]: the file sent over the PLC link: the application, then a trailer with the board,
//!   the version, the length and an Ed25519 signature that embassy-boot verifies. With the
//!   `sign` feature (std): signing and key generation for the host tools.
//! * [`update`]: reading the trailer back from DFU and calling embassy-boot's
//!   `verify_and_mark_updated` with it; or the same check in steps ([`update::Verifier`]).
//!
//! The bootloader binary and the application's use of this crate are built elsewhere; the
//! host tests (`boot/tests/`) drive embassy-boot's own `BootLoader` and
//! `BlockingFirmwareUpdater` over a RAM flash that can lose power mid-operation.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![deny(missing_docs)]
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing)]
#![cfg_attr(
    test,
    allow(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing)
)]

pub mod image;
pub mod layout;
pub mod update;

/// The TEST key's seed: public, in the repository, for the tests and the emulator only. An
/// image signed with it must never be accepted by a board in the field: a board build verifies
/// with the project's real public key, whose secret half is kept offline (see the README).
#[cfg(feature = "test-key")]
pub const TEST_KEY_SEED: [u8; 32] = *b"rc-gateway TEST KEY: never ship!";

/// The TEST key's public half ([`TEST_KEY_SEED`]'s): for the emulator build only.
#[cfg(feature = "test-key")]
pub const TEST_PUBLIC_KEY: [u8; 32] = [
    0x90, 0xc2, 0x18, 0x35, 0x48, 0x19, 0x00, 0xac, 0xcf, 0x37, 0x2f, 0xf4, 0x01, 0xd7, 0xaf, 0x31,
    0x43, 0xcd, 0x41, 0x93, 0xf2, 0xc7, 0xc5, 0xff, 0xc9, 0x2c, 0x86, 0x0d, 0xf6, 0x22, 0x5b, 0x86,
];

/// The gateway's board id for the L475 (the transfer's BEGIN and the image's trailer).
pub const BOARD_L475: u16 = 0x0475;
/// The gateway's board id for the NUCLEO-F429ZI.
pub const BOARD_F429: u16 = 0x0429;

/// The flash layout of the board with this id, if it has a bootloader.
pub const fn layout_of(board: u16) -> Option<&'static layout::Layout> {
    match board {
        BOARD_L475 => Some(&layout::L475),
        BOARD_F429 => Some(&layout::F429),
        _ => None,
    }
}

/// The length of the buffer to give embassy-boot's `prepare_boot`: one L475 page, so a page is
/// copied with one read and one write (an F429 sector of 128 KiB in 64 of them).
pub const BOOT_BUF_LEN: usize = layout::PAGE as usize;
