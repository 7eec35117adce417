//! An [`embassy_net_driver::Driver`] for the SMSC (Microchip) LAN9118 Ethernet controller,
//! written against the LAN9118 datasheet (SMSC, "LAN9118 High Performance single-chip 10/100
//! Non-PCI Ethernet Controller", rev. 1.5; section numbers below refer to it) and checked against
//! the model QEMU gives its `mps2-an385`/`mps2-an386` machines (hw/net/lan9118.c), where the chip
//! sits at 0x4020_0000 on interrupt 13.
//!
//! The chip is driven by programmed I/O: frames are written word by word into the TX data FIFO
//! behind two command words (§3.12), and read word by word from the RX data FIFO after their
//! status word has been popped from the RX status FIFO (§3.13). The MAC's own registers are
//! reached through MAC_CSR_CMD/MAC_CSR_DATA (§5.3.19-20), the internal PHY through the MAC's
//! MII_ACC/MII_DATA (§5.4.6-7). Received frames are copied into one buffer inside the driver
//! before the stack sees them, so a token dropped unused never leaves a half-read frame in the
//! FIFO.
//!
//! # Wake-ups: the chip's interrupt line
//! The driver wakes the stack from the chip's IRQ line (IRQ_CFG, INT_STS, INT_EN: §5.3.2-4), not
//! from a periodic tick: a tick either costs latency (a frame waits for the next tick) or CPU
//! (a fast tick), and under QEMU every needless wake-up is host CPU. The line is configured
//! push-pull, active high, and enabled for "RX status FIFO level" (RSFL: a frame has arrived)
//! and for the PHY's interrupt (link changes), and, while a frame waits for TX FIFO room, for
//! "TX data FIFO available" (TDFA). The application calls [`on_interrupt`] from the interrupt
//! handler: it masks the chip's interrupts (INT_EN = 0, so the level line drops and the handler
//! does not re-enter) and wakes the stack; the driver re-arms INT_EN when it next finds nothing
//! to do, after acknowledging INT_STS and looking at the FIFOs once more, so a frame arriving in
//! between still raises the line. The interrupt must be unmasked in the NVIC only after
//! [`Lan9118::new`] returned: before that the line's polarity is the reset default (active low),
//! which QEMU's model presents to the NVIC as a line held high.
//!
//! # QEMU's model (hw/net/lan9118.c) and the datasheet
//! What the model does differently (read in its source; the RX/TX paths, the interrupt line and
//! the MII are also exercised by emu-net on QEMU 10.0.2), and how the driver stays within what both agree on:
//! - RX_DP_CTRL's fast-forward moves the FIFO's read position without lowering its fill count;
//!   the driver drops unwanted frames by reading their words instead (allowed by §3.13.1).
//! - TX_FIFO_INF.TDFREE counts 32-bit words taken by the frame being written out of 4608, not
//!   bytes; frames leave the FIFO as soon as their last word is written, so it is never short.
//! - TX command A's end-alignment field is decoded from the wrong bits; the driver uses 4-byte
//!   alignment (field 0), which both agree on.
//! - Frames are not padded to 64 bytes on TX, no TX error is ever reported, and the busy bits of
//!   MAC_CSR_CMD, MII_ACC and HW_CFG.SRST are never seen set (accesses complete at once).
//! - Only the RSFL, PHY, TX status full and software interrupts are raised; the FIFO level ones
//!   (TDFA among them) are not ("TODO: Implement FIFO level IRQs"). TDFA is only needed when the
//!   TX FIFO is full, which the model never is.
//! - Unknown MAC CSRs (VLAN2, WUFF, WUCSR) are unimplemented; the driver never touches them.
//!
//! # Safety
//! All `unsafe` is in [`regs`]: volatile 32-bit reads and writes of the register window whose
//! base address the caller vouches for with [`Regs::new`].

#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]
#![deny(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::indexing_slicing,
    clippy::panic
)]

pub mod regs;
pub mod status;

use core::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use core::task::Context;

use embassy_net_driver::{Capabilities, HardwareAddress, LinkState};
use embassy_sync::waitqueue::AtomicWaker;

pub use regs::Regs;
use regs::*;
use status::{RxStatus, TxStatus, MAX_FRAME};

/// Size of the driver's RX and TX frame buffers: [`MAX_FRAME`] rounded up to whole words.
const BUF_LEN: usize = 1516;

/// How many times a busy bit is polled before giving up (MAC CSR, MII, soft reset). The chip
/// clears them within microseconds (§5.3.19: MAC CSR cycles; §6: reset completes in < 10 ms with
/// the PHY); QEMU's model never sets them.
const POLL_LIMIT: u32 = 1_000_000;

/// BYTE_TEST's fixed value (§5.3.5).
const BYTE_TEST_VALUE: u32 = 0x8765_4321;

// IRQ_CFG bits (§5.3.2).
/// IRQ_EN: the IRQ pin is driven.
const IRQ_EN: u32 = 1 << 8;
/// IRQ_POL: active high.
const IRQ_POL: u32 = 1 << 4;
/// IRQ_TYPE: push-pull (open drain otherwise).
const IRQ_TYPE: u32 = 1 << 0;

// INT_STS / INT_EN bits (§5.3.3-4).
/// PHY_INT: the PHY's interrupt (its own source register, PHY register 29).
const PHY_INT: u32 = 1 << 18;
/// TDFA: TX data FIFO free space above FIFO_INT.TDAL.
const TDFA_INT: u32 = 1 << 9;
/// RSFL: RX status FIFO above FIFO_INT.RSFL (0: any frame).
const RSFL_INT: u32 = 1 << 3;

/// HW_CFG.SRST, soft reset, self-clearing (§5.3.9).
const HW_CFG_SRST: u32 = 1 << 0;
/// PMT_CTRL.READY: the chip is out of reset and can be accessed (§5.3.13).
const PMT_READY: u32 = 1 << 0;
/// TX_CFG.TX_ON: the transmitter takes frames from the FIFO (§5.3.8).
const TX_ON: u32 = 1 << 1;
/// TX_CFG.TXSAO: TX status FIFO overrun allowed (the transmitter does not stop when it is full).
const TXSAO: u32 = 1 << 2;

// MAC_CSR_CMD bits (§5.3.19).
/// CSR Busy: set by the host to start the access, cleared by the chip when done.
const CSR_BUSY: u32 = 1 << 31;
/// R/nW: read.
const CSR_READ: u32 = 1 << 30;

// MAC CSR indices (§5.4, Table 5.5).
/// MAC_CR, the MAC control register (§5.4.1).
const MAC_CR: u32 = 1;
/// ADDRH, MAC address bytes 4-5 (§5.4.2).
const MAC_ADDRH: u32 = 2;
/// ADDRL, MAC address bytes 0-3 (§5.4.3).
const MAC_ADDRL: u32 = 3;
/// MII_ACC, PHY register access (§5.4.6).
const MAC_MII_ACC: u32 = 6;
/// MII_DATA, PHY register data (§5.4.7).
const MAC_MII_DATA: u32 = 7;

// MAC_CR bits (§5.4.1).
/// RXEN: receiver enabled.
const MAC_CR_RXEN: u32 = 1 << 2;
/// TXEN: transmitter enabled.
const MAC_CR_TXEN: u32 = 1 << 3;
/// FDPX: full duplex.
const MAC_CR_FDPX: u32 = 1 << 20;

// MII_ACC bits (§5.4.6).
/// MIIBZY: the access is under way.
const MII_BUSY: u32 = 1 << 0;
/// MIIWnR: write.
const MII_WRITE: u32 = 1 << 1;
/// The internal PHY's address on the MII management bus (§5.4.6: "PHY Address ... internal PHY
/// is 00001b").
const PHY_ADDR: u32 = 1;

// PHY registers (§5.5).
/// Basic Control Register (§5.5.1).
const PHY_BCR: u32 = 0;
/// Basic Status Register (§5.5.2).
const PHY_BSR: u32 = 1;
/// Interrupt Source Flags, cleared on read (§5.5.11).
const PHY_ISF: u32 = 29;
/// Interrupt Mask (§5.5.12).
const PHY_IMR: u32 = 30;
/// BCR: auto-negotiation enable and restart.
const BCR_ANEG: u16 = (1 << 12) | (1 << 9);
/// BSR bit 2: link up.
const BSR_LINK: u16 = 1 << 2;
/// ISF/IMR: INT4 link down and INT6 auto-negotiation complete.
const PHY_INT_LINK: u16 = (1 << 4) | (1 << 6);

/// What can go wrong while bringing the chip up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Error {
    /// BYTE_TEST did not read 0x8765_4321: no LAN9118 at that address (or a bus problem).
    NotFound(u32),
    /// A busy bit (soft reset, MAC CSR or MII access) did not clear in time.
    Timeout,
}

/// What the interrupt handler and the driver share: the wakers and the register base.
///
/// Lives in a `static` of the application (`State::new` is `const`), so that the interrupt
/// handler can reach it: see [`on_interrupt`].
pub struct State {
    /// The register window's base, 0 until [`Lan9118::new`] stored it.
    base: AtomicUsize,
    /// The stack's waker (embassy-net registers one waker, its runner's).
    waker: AtomicWaker,
    /// Set by [`on_interrupt`]: the PHY may have changed its link state.
    phy_event: AtomicBool,
}

impl State {
    /// An empty state, for a `static`.
    pub const fn new() -> State {
        State {
            base: AtomicUsize::new(0),
            waker: AtomicWaker::new(),
            phy_event: AtomicBool::new(true),
        }
    }
}

impl Default for State {
    fn default() -> State {
        State::new()
    }
}

/// To be called from the chip's interrupt handler (IRQ 13 on QEMU's mps2-an385/an386): masks
/// the chip's interrupts and wakes the driver's user, which re-arms them (see the crate's doc).
pub fn on_interrupt(state: &State) {
    let base = state.base.load(Ordering::Acquire);
    if base != 0 {
        // SAFETY: `base` was stored by `Lan9118::new` from a `Regs` whose contract the caller
        // of `Regs::new` fulfilled.
        let regs = unsafe { Regs::new(base) };
        regs.write(INT_EN, 0);
    }
    state.phy_event.store(true, Ordering::Release);
    state.waker.wake();
}

/// Counters for diagnostics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Stats {
    /// Frames handed to the stack.
    pub rx_frames: u32,
    /// Frames dropped: RX errors, filter failures, oversize.
    pub rx_dropped: u32,
    /// Frames written to the TX FIFO.
    pub tx_frames: u32,
    /// TX status words with the error bit set.
    pub tx_errors: u32,
}

/// The driver: owns the chip, and one frame buffer each way.
pub struct Lan9118 {
    regs: Regs,
    state: &'static State,
    mac: [u8; 6],
    link: LinkState,
    tx_tag: u16,
    stats: Stats,
    rx_buf: [u8; BUF_LEN],
    rx_len: usize,
    tx_buf: [u8; BUF_LEN],
}

impl Lan9118 {
    /// Resets the chip and brings it up with `mac` as its address: soft reset (HW_CFG.SRST,
    /// §6.2), the interrupt line push-pull active high, the MAC address, the PHY's
    /// auto-negotiation and link interrupts, then the transmitter (TX_CFG.TX_ON) and the MAC's
    /// receiver and transmitter (MAC_CR.RXEN/TXEN, full duplex, filtering on its own address
    /// and broadcast).
    pub fn new(regs: Regs, state: &'static State, mac: [u8; 6]) -> Result<Lan9118, Error> {
        let test = regs.read(BYTE_TEST);
        if test != BYTE_TEST_VALUE {
            return Err(Error::NotFound(test));
        }
        let mut this = Lan9118 {
            regs,
            state,
            mac,
            link: LinkState::Down,
            tx_tag: 0,
            stats: Stats::default(),
            rx_buf: [0; BUF_LEN],
            rx_len: 0,
            tx_buf: [0; BUF_LEN],
        };
        this.init()?;
        state.base.store(this.regs.base(), Ordering::Release);
        Ok(this)
    }

    fn init(&mut self) -> Result<(), Error> {
        let r = self.regs;
        r.write(HW_CFG, HW_CFG_SRST);
        poll(|| r.read(HW_CFG) & HW_CFG_SRST == 0)?;
        poll(|| r.read(PMT_CTRL) & PMT_READY != 0)?;
        // Quiet and push-pull active high before anything can raise the line.
        r.write(INT_EN, 0);
        r.write(INT_STS, u32::MAX);
        r.write(IRQ_CFG, IRQ_EN | IRQ_POL | IRQ_TYPE);
        let (addrl, addrh) = status::mac_to_regs(self.mac);
        self.mac_write(MAC_ADDRL, addrl)?;
        self.mac_write(MAC_ADDRH, addrh)?;
        self.phy_write(PHY_BCR, BCR_ANEG)?;
        self.phy_write(PHY_IMR, PHY_INT_LINK)?;
        // RX: end alignment 4 bytes, data offset 0 (RX_CFG = 0, §5.3.7): `RxStatus::fifo_words`.
        r.write(RX_CFG, 0);
        r.write(TX_CFG, TX_ON | TXSAO);
        self.mac_write(MAC_CR, MAC_CR_RXEN | MAC_CR_TXEN | MAC_CR_FDPX)?;
        r.write(INT_EN, RSFL_INT | PHY_INT);
        Ok(())
    }

    /// The MAC address as the chip holds it (ADDRL/ADDRH), e.g. to check [`Lan9118::new`].
    pub fn read_mac(&mut self) -> Result<[u8; 6], Error> {
        let l = self.mac_read(MAC_ADDRL)?;
        let h = self.mac_read(MAC_ADDRH)?;
        Ok(status::mac_from_regs(l, h))
    }

    /// The chip's ID_REV register (§5.3.1): 0x0118_xxxx for a LAN9118.
    pub fn id_rev(&self) -> u32 {
        self.regs.read(ID_REV)
    }

    /// The diagnostics counters.
    pub fn stats(&self) -> Stats {
        self.stats
    }

    /// Reads MAC CSR `index` through MAC_CSR_CMD/MAC_CSR_DATA (§5.3.19-20).
    fn mac_read(&mut self, index: u32) -> Result<u32, Error> {
        let r = self.regs;
        poll(|| r.read(MAC_CSR_CMD) & CSR_BUSY == 0)?;
        r.write(MAC_CSR_CMD, CSR_BUSY | CSR_READ | (index & 0xFF));
        poll(|| r.read(MAC_CSR_CMD) & CSR_BUSY == 0)?;
        Ok(r.read(MAC_CSR_DATA))
    }

    /// Writes MAC CSR `index` (§5.3.19-20).
    fn mac_write(&mut self, index: u32, value: u32) -> Result<(), Error> {
        let r = self.regs;
        poll(|| r.read(MAC_CSR_CMD) & CSR_BUSY == 0)?;
        r.write(MAC_CSR_DATA, value);
        r.write(MAC_CSR_CMD, CSR_BUSY | (index & 0xFF));
        poll(|| r.read(MAC_CSR_CMD) & CSR_BUSY == 0)
    }

    fn mii_wait(&mut self) -> Result<(), Error> {
        for _ in 0..POLL_LIMIT {
            if self.mac_read(MAC_MII_ACC)? & MII_BUSY == 0 {
                return Ok(());
            }
        }
        Err(Error::Timeout)
    }

    /// Reads PHY register `reg` through MII_ACC/MII_DATA (§5.4.6-7).
    fn phy_read(&mut self, reg: u32) -> Result<u16, Error> {
        self.mii_wait()?;
        self.mac_write(
            MAC_MII_ACC,
            (PHY_ADDR << 11) | ((reg & 0x1F) << 6) | MII_BUSY,
        )?;
        self.mii_wait()?;
        Ok(self.mac_read(MAC_MII_DATA)? as u16)
    }

    /// Writes PHY register `reg` (§5.4.6-7).
    fn phy_write(&mut self, reg: u32, value: u16) -> Result<(), Error> {
        self.mii_wait()?;
        self.mac_write(MAC_MII_DATA, u32::from(value))?;
        self.mac_write(
            MAC_MII_ACC,
            (PHY_ADDR << 11) | ((reg & 0x1F) << 6) | MII_WRITE | MII_BUSY,
        )?;
        self.mii_wait()
    }

    /// Pops the TX status words waiting (the transmitter does not need them, TX_CFG.TXSAO, but
    /// they carry the error bit).
    fn drain_tx_status(&mut self) {
        let used = status::tx_status_used(self.regs.read(TX_FIFO_INF));
        for _ in 0..used {
            if !TxStatus(self.regs.read(TX_STATUS_FIFO)).is_ok() {
                self.stats.tx_errors = self.stats.tx_errors.wrapping_add(1);
            }
        }
    }

    /// Whether the TX data FIFO has room for a frame of the largest size.
    fn tx_room(&self) -> bool {
        status::tx_data_free(self.regs.read(TX_FIFO_INF)) >= status::tx_fifo_bytes(MAX_FRAME)
    }

    /// Takes the next good frame out of the RX FIFOs into `rx_buf`, dropping bad ones on the
    /// way. Returns whether a frame is there.
    fn fetch_frame(&mut self) -> bool {
        loop {
            if status::rx_status_used(self.regs.read(RX_FIFO_INF)) == 0 {
                return false;
            }
            let st = RxStatus(self.regs.read(RX_STATUS_FIFO));
            let keep = if st.is_good() { st.frame_len() } else { 0 };
            // Every word of the frame is read, the FCS and any bad frame included. (RX_DP_CTRL's
            // fast-forward would skip them, but QEMU's model of it loses track of the FIFO
            // fill level: see "QEMU's model" in the crate's doc.)
            let mut dest = self
                .rx_buf
                .get_mut(..keep)
                .unwrap_or_default()
                .chunks_mut(4);
            for _ in 0..st.fifo_words() {
                let word = self.regs.read(RX_DATA_FIFO).to_le_bytes();
                if let Some(chunk) = dest.next() {
                    for (d, s) in chunk.iter_mut().zip(word) {
                        *d = s;
                    }
                }
            }
            if keep > 0 {
                self.rx_len = keep;
                self.stats.rx_frames = self.stats.rx_frames.wrapping_add(1);
                return true;
            }
            self.stats.rx_dropped = self.stats.rx_dropped.wrapping_add(1);
        }
    }

    /// Nothing to do for now: register the waker, acknowledge the interrupt sources, and enable
    /// them again, `tx_wait` adding the TX-room one. The caller checks the FIFOs once more after
    /// this (see the crate's doc: no lost wake-up).
    fn arm(&mut self, cx: &mut Context<'_>, tx_wait: bool) {
        self.state.waker.register(cx.waker());
        let r = self.regs;
        r.write(INT_STS, RSFL_INT | PHY_INT | TDFA_INT);
        let mut enable = RSFL_INT | PHY_INT;
        if tx_wait {
            // FIFO_INT.TDAL (bits 31:24) counts 64-byte units of free space (§5.3.6); keep the
            // RX status level (bits 7:0) at 0.
            let units = status::tx_fifo_bytes(MAX_FRAME).div_ceil(64) as u32;
            r.write(FIFO_INT, (units & 0xFF) << 24);
            enable |= TDFA_INT;
        }
        r.write(INT_EN, enable);
    }
}

/// Polls `done` up to [`POLL_LIMIT`] times.
fn poll(mut done: impl FnMut() -> bool) -> Result<(), Error> {
    for _ in 0..POLL_LIMIT {
        if done() {
            return Ok(());
        }
    }
    Err(Error::Timeout)
}

impl embassy_net_driver::Driver for Lan9118 {
    type RxToken<'a>
        = RxToken<'a>
    where
        Self: 'a;
    type TxToken<'a>
        = TxToken<'a>
    where
        Self: 'a;

    fn receive(&mut self, cx: &mut Context<'_>) -> Option<(RxToken<'_>, TxToken<'_>)> {
        self.drain_tx_status();
        if !self.tx_room() {
            self.arm(cx, true);
            if !self.tx_room() {
                return None;
            }
        }
        if !self.fetch_frame() {
            self.arm(cx, false);
            if !self.fetch_frame() {
                return None;
            }
        }
        let rx = RxToken {
            frame: self.rx_buf.get_mut(..self.rx_len).unwrap_or_default(),
        };
        let tx = TxToken {
            regs: self.regs,
            buf: &mut self.tx_buf,
            tag: &mut self.tx_tag,
            stats: &mut self.stats,
        };
        Some((rx, tx))
    }

    fn transmit(&mut self, cx: &mut Context<'_>) -> Option<TxToken<'_>> {
        self.drain_tx_status();
        if !self.tx_room() {
            self.arm(cx, true);
            if !self.tx_room() {
                return None;
            }
        }
        Some(TxToken {
            regs: self.regs,
            buf: &mut self.tx_buf,
            tag: &mut self.tx_tag,
            stats: &mut self.stats,
        })
    }

    fn link_state(&mut self, cx: &mut Context<'_>) -> LinkState {
        self.state.waker.register(cx.waker());
        // The PHY is asked only after an interrupt (or at start): two MII reads are a dozen
        // register accesses, and the stack asks for the link state on every poll.
        if self.state.phy_event.swap(false, Ordering::AcqRel) {
            // Reading the source flags clears them and with them INT_STS.PHY_INT (§5.5.11).
            let _ = self.phy_read(PHY_ISF);
            self.link = match self.phy_read(PHY_BSR) {
                Ok(bsr) if bsr & BSR_LINK != 0 => LinkState::Up,
                _ => LinkState::Down,
            };
        }
        self.link
    }

    fn capabilities(&self) -> Capabilities {
        let mut caps = Capabilities::default();
        caps.max_transmission_unit = MAX_FRAME;
        // One frame at a time through the driver's buffer.
        caps.max_burst_size = Some(1);
        caps
    }

    fn hardware_address(&self) -> HardwareAddress {
        HardwareAddress::Ethernet(self.mac)
    }
}

/// A received frame, already out of the chip (in the driver's RX buffer).
pub struct RxToken<'a> {
    frame: &'a mut [u8],
}

impl embassy_net_driver::RxToken for RxToken<'_> {
    fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, f: F) -> R {
        f(self.frame)
    }
}

/// Room for one frame in the TX data FIFO.
pub struct TxToken<'a> {
    regs: Regs,
    buf: &'a mut [u8; BUF_LEN],
    tag: &'a mut u16,
    stats: &'a mut Stats,
}

impl embassy_net_driver::TxToken for TxToken<'_> {
    /// Lets the stack build the frame in the driver's TX buffer, then writes TX command A and B
    /// and the frame's words to the TX data FIFO (§3.12.1, "TX Buffer Format"). `len` is at most
    /// [`MAX_FRAME`] (the stack keeps to [`Capabilities::max_transmission_unit`]); a larger one
    /// is cut to it.
    fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, len: usize, f: F) -> R {
        let len = len.min(MAX_FRAME);
        let frame = self.buf.get_mut(..len).unwrap_or_default();
        let result = f(frame);
        *self.tag = self.tag.wrapping_add(1);
        self.regs
            .write(TX_DATA_FIFO, status::tx_command_a(frame.len()));
        self.regs
            .write(TX_DATA_FIFO, status::tx_command_b(*self.tag, frame.len()));
        for chunk in frame.chunks(4) {
            let mut word = [0u8; 4];
            for (d, s) in word.iter_mut().zip(chunk) {
                *d = *s;
            }
            self.regs.write(TX_DATA_FIFO, u32::from_le_bytes(word));
        }
        self.stats.tx_frames = self.stats.tx_frames.wrapping_add(1);
        result
    }
}
