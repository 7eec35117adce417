//! The bootloader's core for the gateway (issue 37): the flash layout embassy-boot works on,
//! the signed image format, and the application's check-and-mark step.
//!
//! * [`layout`]: the L475's partitions (BOOTLOADER, ACTIVE, DFU, STATE, and the settings pages
//!   left alone), with embassy-boot's size rules checked at compile time.
//! * [`image`]: the file sent over the PLC link: the application, then a trailer with the board,
//!   the version, the length and an Ed25519 signature that embassy-boot verifies. With the
//!   `sign` feature (std): signing and key generation for the host tools.
//! * [`update`]: reading the trailer back from DFU and calling embassy-boot's
//!   `verify_and_mark_updated` with it.
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

/// The gateway's board id for the L475 (the transfer's BEGIN and the image's trailer).
pub const BOARD_L475: u16 = 0x0475;

/// The length of the buffer to give embassy-boot's `prepare_boot`: one page, so a page is
/// copied with one read and one write.
pub const BOOT_BUF_LEN: usize = layout::PAGE as usize;
