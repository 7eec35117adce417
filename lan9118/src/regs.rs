//! The only `unsafe` of the crate: volatile 32-bit accesses to the LAN9118's register window.
//!
//! The LAN9118 maps its System Control and Status Registers (datasheet §5, "Register
//! Description", Table 5.1 "Direct Address Register Map") and its four FIFO ports into 256 bytes
//! of the host bus. All accesses here are 32-bit, as the datasheet requires for the 32-bit host
//! bus (§3.2 and §5; QEMU's model only knows 32-bit accesses unless built in 16-bit mode).

use core::ptr::{read_volatile, write_volatile};

/// RX Data FIFO port (§5.1; reads 0x00-0x1C are aliases of the same port).
pub const RX_DATA_FIFO: usize = 0x00;
/// TX Data FIFO port (§5.1; writes 0x20-0x3C are aliases of the same port).
pub const TX_DATA_FIFO: usize = 0x20;
/// RX Status FIFO port: reading pops one RX status word (§5.2, §3.13.3).
pub const RX_STATUS_FIFO: usize = 0x40;
/// TX Status FIFO port: reading pops one TX status word (§5.2, §3.12.6).
pub const TX_STATUS_FIFO: usize = 0x48;
/// ID_REV: chip ID (0x0118 for the LAN9118) and revision (§5.3.1).
pub const ID_REV: usize = 0x50;
/// IRQ_CFG: interrupt pin enable, polarity and buffer type (§5.3.2).
pub const IRQ_CFG: usize = 0x54;
/// INT_STS: interrupt status, write 1 to clear (§5.3.3).
pub const INT_STS: usize = 0x58;
/// INT_EN: interrupt enables, same bits as INT_STS (§5.3.4).
pub const INT_EN: usize = 0x5C;
/// BYTE_TEST: reads 0x8765_4321 whatever the bus endianness (§5.3.5).
pub const BYTE_TEST: usize = 0x64;
/// FIFO_INT: FIFO level interrupt thresholds (§5.3.6).
pub const FIFO_INT: usize = 0x68;
/// RX_CFG: RX end alignment, data offset, RX dump (§5.3.7).
pub const RX_CFG: usize = 0x6C;
/// TX_CFG: TX_ON, status overrun, dumps (§5.3.8).
pub const TX_CFG: usize = 0x70;
/// HW_CFG: soft reset SRST, TX FIFO size (§5.3.9).
pub const HW_CFG: usize = 0x74;
/// RX_FIFO_INF: RX status words used (RXSUSED) and RX data bytes used (RXDUSED) (§5.3.11).
pub const RX_FIFO_INF: usize = 0x7C;
/// TX_FIFO_INF: TX status words used (TXSUSED) and TX data bytes free (TDFREE) (§5.3.12).
pub const TX_FIFO_INF: usize = 0x80;
/// PMT_CTRL: power management; bit 0 READY says the chip is out of reset (§5.3.13).
pub const PMT_CTRL: usize = 0x84;
/// MAC_CSR_CMD: MAC CSR address, read/write and busy bits (§5.3.19).
pub const MAC_CSR_CMD: usize = 0xA4;
/// MAC_CSR_DATA: data of the MAC CSR access (§5.3.20).
pub const MAC_CSR_DATA: usize = 0xA8;

/// The LAN9118's register window at a fixed address.
///
/// Holds only the base address; it is `Copy` so that the driver and its tokens can each use it.
/// Constructing one is `unsafe` ([`Regs::new`]); every access after that is safe, because the
/// constructor's contract makes every offset below 0x100 a valid device register.
#[derive(Clone, Copy, Debug)]
pub struct Regs {
    base: usize,
}

impl Regs {
    /// The register window at `base` (0x4020_0000 on QEMU's `mps2-an385`/`mps2-an386`).
    ///
    /// # Safety
    /// `base` must be the address of a LAN9118's 256-byte register window, mapped as device
    /// memory for the whole life of the program, and nothing else may access the chip in a way
    /// that conflicts with the driver (the FIFO ports pop on read).
    pub const unsafe fn new(base: usize) -> Regs {
        Regs { base }
    }

    /// The base address given to [`Regs::new`].
    pub fn base(self) -> usize {
        self.base
    }

    /// Reads the 32-bit register at `offset` (one of the constants of this module).
    #[inline]
    pub fn read(self, offset: usize) -> u32 {
        // SAFETY: `new`'s contract: base + (offset masked into the window, word aligned) is a
        // device register.
        unsafe { read_volatile((self.base + (offset & 0xFC)) as *const u32) }
    }

    /// Writes the 32-bit register at `offset` (one of the constants of this module).
    #[inline]
    pub fn write(self, offset: usize, value: u32) {
        // SAFETY: as in `read`.
        unsafe { write_volatile((self.base + (offset & 0xFC)) as *mut u32, value) }
    }
}
