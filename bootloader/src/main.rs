//! The bootloader of the gateways with room for two images (the L475, feature `board-l475`; the
//! F429, feature `board-f429`): embassy-boot's swap, then the application.
//!
//! At every reset it reads the state partition (`rc_boot::layout::L475` or `F429`): **Boot**, the application in
//! ACTIVE runs; **Swap**, an image the application checked and marked (its signature through
//! embassy-boot's `verify_and_mark_updated`) is swapped into ACTIVE page by page, the old one
//! kept in DFU, and the new one runs on trial; a trial the application never confirmed
//! (`mark_booted`) is swapped back at the next reset (a hang ends in the IWDG's reset, which
//! comes here). embassy-boot records the swap's progress in the state partition, so a power cut
//! at any instant resumes where it stopped (rc-boot's tests cut it at every flash operation).
//!
//! What this adds to embassy-boot, for a board in a cabinet:
//! - **The IWDG.** A firmware on trial that hangs before it starts its own watchdog would hang
//!   for good, and only a power cycle would reach the rollback: so the bootloader starts the IWDG
//!   (about 8 s) before it starts a firmware on trial ([`watchdog`]); the firmware sets its own
//!   timeout when it starts it. (The IWDG stops at a reset in software mode, its option bytes'
//!   default; with the hardware-watchdog option bit it runs from power-up.) Either way a swap of
//!   the whole ACTIVE partition erases and writes about 480 pages (L475: 25 ms each to erase) or
//!   12 sectors of 128 KiB (F429: 2 s each at most), far past its timeout: every flash operation
//!   is one page or sector (writes 2 KiB) and pets it first ([`Watched`]).
//! - **The flash's data cache** is off while the bootloader runs, so that a page read after its
//!   erase or write is read from the flash, not from a stale line; the caches are reset before the
//!   application starts, as it must not execute stale instructions of the old image. (The L4's
//!   and the F4's flash interfaces name these bits alike: FLASH_ACR's DCEN, DCRST, ICEN, ICRST.)
//! - **ECC errors** (the L475; the F4's flash has no ECC): a word a power cut tore reads with an
//!   ECC double error, which the flash raises as an NMI. One in the partitions is cleared and the
//!   read goes on (its data is whatever the torn word holds; embassy-boot rewrites every page it
//!   resumes), instead of the default handler's spin until the IWDG resets into the same read: a
//!   boot loop.
//! - **Partitions of two erase units** (the F429): ACTIVE and DFU in 128 KiB sectors, STATE in a
//!   16 KiB one; each partition is a [`Part`] with its own erase unit over the one flash.
//! - **A failure** (a flash operation that reports an error) resets the chip to try again; the
//!   swap resumes from its recorded progress.
#![no_std]
#![no_main]

use core::cell::RefCell;

use cortex_m::peripheral::SCB;
use cortex_m_rt::{entry, exception};
use embassy_boot_stm32::{BootLoader, BootLoaderConfig, State};
use embassy_stm32::flash::{Blocking, Flash};
use embassy_stm32::pac;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

use rc_boot::layout::{Layout, Region, FLASH_BASE};

/// This board's layout.
#[cfg(feature = "board-l475")]
const LAYOUT: Layout = rc_boot::layout::L475;
/// This board's layout.
#[cfg(feature = "board-f429")]
const LAYOUT: Layout = rc_boot::layout::F429;

/// ACTIVE's and DFU's erase unit: embassy-boot's page.
const PAGE: usize = LAYOUT.page as usize;
/// STATE's erase unit.
const SMALL_PAGE: usize = LAYOUT.small_page as usize;
/// The most bytes written between two pets of the IWDG (an L475 page).
const WRITE_CHUNK: usize = 2048;

#[entry]
fn main() -> ! {
    data_cache(false);
    // A watchdog that runs from power-up (the hardware-watchdog option) has its reset timeout,
    // about 0.5 s: shorter than one 128 KiB sector's erase. Its timeout is set to about 8 s at
    // once (it stays stopped in software mode until [`watchdog`] starts it).
    watchdog_timeout();
    pet();
    #[cfg(feature = "board-f429")]
    hold_pa12_low();
    // SAFETY: the bootloader is the only code running, and the flash is its only peripheral.
    let flash = Flash::new_blocking(unsafe { embassy_stm32::peripherals::FLASH::steal() });
    let flash = Mutex::<NoopRawMutex, _>::new(RefCell::new(Watched(flash)));
    let config = BootLoaderConfig {
        active: Part::<PAGE>::new(&flash, LAYOUT.active),
        dfu: Part::<PAGE>::new(&flash, LAYOUT.dfu),
        state: Part::<SMALL_PAGE>::new(&flash, LAYOUT.state),
    };
    let Ok(loader) = BootLoader::try_prepare::<_, _, _, { rc_boot::BOOT_BUF_LEN }>(config) else {
        // A flash operation failed: from the top, where the swap's progress says.
        SCB::sys_reset();
    };
    // A firmware on trial (the swap just done, or the trial's second start, which reverted):
    // a hang before its own watchdog runs ends in a reset, and the reset in the rollback.
    if loader.state == State::Swap {
        watchdog();
    }
    // The caches emptied: the application may have been rewritten under them.
    data_cache(true);
    instruction_cache_reset();
    // SAFETY: ACTIVE holds an application linked there (its vector table first), whole: the
    // swap is done or was never started.
    unsafe { loader.load(LAYOUT.active.start) }
}

/// A partition of the flash with its erase unit (embassy-embedded-hal's `BlockingPartition` has
/// the flash's one unit for all): offsets from its start, none outside it.
struct Part<'a, const ERASE: usize> {
    flash: &'a Mutex<NoopRawMutex, RefCell<Watched>>,
    region: Region,
}

impl<'a, const ERASE: usize> Part<'a, ERASE> {
    fn new(flash: &'a Mutex<NoopRawMutex, RefCell<Watched>>, region: Region) -> Self {
        Part { flash, region }
    }

    /// The flash's offset of `offset..offset + len`, if it lies inside the partition.
    fn at(&self, offset: u32, len: usize) -> Result<u32, PartError> {
        let end = offset.checked_add(len as u32).ok_or(PartError::Outside)?;
        if end > self.region.len() {
            return Err(PartError::Outside);
        }
        Ok(self.region.offset_from(FLASH_BASE) + offset)
    }
}

/// The flash's error, or an offset outside the partition.
#[derive(Debug)]
enum PartError {
    Outside,
    Flash(embassy_stm32::flash::Error),
}

impl NorFlashError for PartError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            PartError::Outside => NorFlashErrorKind::OutOfBounds,
            PartError::Flash(e) => e.kind(),
        }
    }
}

impl<const ERASE: usize> ErrorType for Part<'_, ERASE> {
    type Error = PartError;
}

impl<const ERASE: usize> ReadNorFlash for Part<'_, ERASE> {
    const READ_SIZE: usize = <Watched as ReadNorFlash>::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let at = self.at(offset, bytes.len())?;
        self.flash
            .lock(|f| f.borrow_mut().read(at, bytes))
            .map_err(PartError::Flash)
    }

    fn capacity(&self) -> usize {
        self.region.len() as usize
    }
}

impl<const ERASE: usize> NorFlash for Part<'_, ERASE> {
    const WRITE_SIZE: usize = <Watched as NorFlash>::WRITE_SIZE;
    const ERASE_SIZE: usize = ERASE;

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let at = self.at(offset, bytes.len())?;
        self.flash
            .lock(|f| f.borrow_mut().write(at, bytes))
            .map_err(PartError::Flash)
    }

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let at = self.at(from, to.saturating_sub(from) as usize)?;
        if from > to || !from.is_multiple_of(ERASE as u32) || !to.is_multiple_of(ERASE as u32) {
            return Err(PartError::Flash(embassy_stm32::flash::Error::Unaligned));
        }
        self.flash
            .lock(|f| {
                f.borrow_mut()
                    .erase_units(at, at + (to - from), ERASE as u32)
            })
            .map_err(PartError::Flash)
    }
}

/// The flash, one page at a time, the IWDG petted before each operation.
struct Watched(Flash<'static, Blocking>);

impl ErrorType for Watched {
    type Error = embassy_stm32::flash::Error;
}

impl ReadNorFlash for Watched {
    const READ_SIZE: usize = <Flash<'static, Blocking> as ReadNorFlash>::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.0.blocking_read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl NorFlash for Watched {
    const WRITE_SIZE: usize = <Flash<'static, Blocking> as NorFlash>::WRITE_SIZE;
    const ERASE_SIZE: usize = <Flash<'static, Blocking> as NorFlash>::ERASE_SIZE;

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let mut at = offset;
        for chunk in bytes.chunks(WRITE_CHUNK) {
            pet();
            self.0.blocking_write(at, chunk)?;
            at += chunk.len() as u32;
        }
        Ok(())
    }

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.erase_units(from, to, Self::ERASE_SIZE as u32)
    }
}

impl Watched {
    /// Erases `from..to` one erase unit (a page, or a sector of `unit` bytes) at a time, the
    /// IWDG petted before each.
    fn erase_units(
        &mut self,
        from: u32,
        to: u32,
        unit: u32,
    ) -> Result<(), embassy_stm32::flash::Error> {
        let mut at = from;
        while at < to {
            pet();
            x32();
            self.0.blocking_erase(at, at + unit)?;
            at += unit;
        }
        Ok(())
    }
}

/// The F4's erase at x32 (FLASH_CR.PSIZE, in the unlocked register; embassy-stm32 0.6 leaves it
/// as it finds it, and its writes leave it at x8): a 128 KiB sector in 1-2 s instead of 2-4 s
/// (STM32F429 datasheet, 2.7-3.6 V). The L4 has no PSIZE.
fn x32() {
    #[cfg(feature = "board-f429")]
    {
        let flash = pac::FLASH;
        if flash.cr().read().lock() {
            flash.keyr().write_value(0x4567_0123);
            flash.keyr().write_value(0xCDEF_89AB);
        }
        flash
            .cr()
            .modify(|w| w.set_psize(pac::flash::vals::Psize::PSIZE32));
    }
}

/// Starts the IWDG at about 8 s (LSI 32 kHz / 64, 4095 counts): long enough for any start-up,
/// short enough that a firmware on trial that hangs goes back to the old one by itself. The
/// firmware's own `start_watchdog` sets its timeout over this one.
fn watchdog() {
    use pac::iwdg::vals::Key;
    let iwdg = pac::IWDG;
    iwdg.kr().write(|w| w.set_key(Key::START));
    watchdog_timeout();
    // The new values reach the IWDG's clock domain within a few LSI cycles (a bounded wait:
    // QEMU models no IWDG and reads its registers as 0).
    for _ in 0..100_000 {
        let sr = iwdg.sr().read();
        if !sr.pvu() && !sr.rvu() {
            break;
        }
    }
    pet();
}

/// The IWDG's timeout, about 8 s (PR 4: LSI / 64; 4095 counts), written whether it runs or not.
fn watchdog_timeout() {
    use pac::iwdg::vals::{Key, Pr};
    let iwdg = pac::IWDG;
    iwdg.kr().write(|w| w.set_key(Key::ENABLE));
    iwdg.pr().write(|w| w.set_pr(Pr::from_bits(4)));
    iwdg.rlr().write(|w| w.set_rl(4095));
}

/// STM32F42x/43x errata 2.2.11: on silicon before revision 3 a read of bank 2 (STATE, DFU) may
/// return wrong data while PA12 toggles, and embassy-stm32 panics on such a read unless PA12 is
/// an output, low, pulled down (the application does the same: `src/board/f429.rs`). GPIOA's
/// clock first: the bootloader does not run `embassy_stm32::init`.
#[cfg(feature = "board-f429")]
fn hold_pa12_low() {
    use pac::gpio::vals::{Moder, Pupdr};
    const PIN: usize = 12;
    pac::RCC.ahb1enr().modify(|w| w.set_gpioaen(true));
    // Two AHB cycles before the port answers (RM0090, RCC): the read-back orders it.
    let _ = pac::RCC.ahb1enr().read();
    let gpioa = pac::GPIOA;
    gpioa.bsrr().write(|w| w.set_br(PIN, true));
    gpioa.pupdr().modify(|w| w.set_pupdr(PIN, Pupdr::PULL_DOWN));
    gpioa.moder().modify(|w| w.set_moder(PIN, Moder::OUTPUT));
}

/// Restarts the IWDG's count (nothing if it was never started).
fn pet() {
    pac::IWDG
        .kr()
        .write(|w| w.set_key(pac::iwdg::vals::Key::RESET));
}

/// The flash's data cache on (emptied first) or off.
fn data_cache(on: bool) {
    let acr = pac::FLASH.acr();
    acr.modify(|w| w.set_dcen(false));
    if on {
        acr.modify(|w| w.set_dcrst(true));
        acr.modify(|w| w.set_dcrst(false));
        acr.modify(|w| w.set_dcen(true));
    }
}

/// The flash's instruction cache emptied.
fn instruction_cache_reset() {
    let acr = pac::FLASH.acr();
    acr.modify(|w| w.set_icen(false));
    acr.modify(|w| w.set_icrst(true));
    acr.modify(|w| w.set_icrst(false));
    acr.modify(|w| w.set_icen(true));
}

/// An ECC double error in the partitions (a torn word) is cleared and the read goes on; any
/// other NMI (an error in the bootloader's own pages or the system flash, the clock security
/// system) resets the chip.
#[cfg(feature = "board-l475")]
#[exception]
unsafe fn NonMaskableInt() {
    let eccr = pac::FLASH.eccr();
    let ecc = eccr.read();
    // FLASH_ECCR gives the address within the bank.
    let offset = ecc.addr_ecc()
        + if ecc.bk_ecc() {
            LAYOUT.bank2 - FLASH_BASE
        } else {
            0
        };
    if ecc.eccd() && !ecc.sysf_ecc() && offset >= LAYOUT.bootloader.end - FLASH_BASE {
        eccr.modify(|w| w.set_eccd(true));
        return;
    }
    SCB::sys_reset();
}

/// The F4's flash has no ECC: any NMI (the clock security system) resets the chip.
#[cfg(feature = "board-f429")]
#[exception]
unsafe fn NonMaskableInt() {
    SCB::sys_reset();
}

#[exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    SCB::sys_reset()
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    SCB::sys_reset()
}
