//! Placeholder until rc-boot's layout lands (then `pub use rc_boot::layout::*`).

/// Where the flash is mapped.
pub const FLASH_BASE: u32 = 0x0800_0000;
/// A bank of the STM32L475VG (two, not swapped).
pub const BANK_SIZE: u32 = 0x8_0000;
/// The erase unit.
pub const PAGE: u32 = 2048;
/// The bootloader.
pub const BOOTLOADER: core::ops::Range<u32> = 0x0800_0000..0x0800_8000;
/// The application.
pub const ACTIVE: core::ops::Range<u32> = 0x0800_8000..0x0808_0000;
/// The image to swap in.
pub const DFU: core::ops::Range<u32> = 0x0808_0000..0x080F_C000;
/// The swap's state and progress.
pub const STATE: core::ops::Range<u32> = 0x080F_C000..0x080F_E000;
