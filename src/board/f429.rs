//! # NUCLEO-F429ZI (STM32F429ZI, 2 MiB flash, 192 KiB SRAM, LAN8742A Ethernet PHY)
//!
//! The board with Ethernet: Modbus TCP on port 502 ([`crate::net`]) beside Modbus RTU on the PLC
//! line (both at once), and every PIO port, so patterns 0, 1, 4 and 5 all run. The F4's USARTs
//! have no hardware driver enable (CR3.DEM is an F0/F3/F7/L4/H7 feature): DE is a GPIO, set before
//! a write and cleared once the last stop bit has left, as on the F103 ([`Rs485`]). The Ethernet's
//! parts (the LAN8742A driver, the MAC's reference clock, its address, the DMA's frames) are in
//! [`ethernet`]; [`board`] brings them up.
//!
//! Arduino names are the Nucleo-144's (UM1974); every pin is also on the ST morpho connectors
//! CN11/CN12. Pins the board itself uses are left alone: the Ethernet (RMII), the ST-LINK's
//! virtual COM port (USART3, PD8/PD9), SWD (PA13/PA14, PB3), the 8 MHz clock from the ST-LINK
//! (PH0), the 32 kHz crystal (PC14/PC15), the user button (PC13) and the USB OTG connector
//! (PA8-PA12, PG6, PG7).
//!
//! | Signal | Pin | Header | Notes |
//! |---|---|---|---|
//! | RS485 **bus** TX / RX | PG14 / PG9 | Arduino D1 / D0 | USART6 (84 MHz APB2) |
//! | RS485 bus DE | PF15 | Arduino D2 | a GPIO, active high |
//! | RS485 **PLC** TX / RX | PD5 / PD6 | morpho | USART2 (42 MHz APB1) |
//! | RS485 PLC DE | PD4 | morpho | a GPIO, active high (USART2's RTS pin, unused as such) |
//! | IN0-IN5 PC1-PC32 | PE2 PE3 PE4 PE5 PE6 PE7 | morpho | inputs: high = ON, pull-down (open = OFF) |
//! | IN6 ST6, IN7 JISL, IN8 JOG+, IN9 JOG- | PE8 PE10 PE12 PE14 | morpho | patterns 1 and 4 |
//! | IN11 HOME, IN12 *STP, IN13 CSTR, IN14 RES, IN15 SON | PE15 PF0 PF1 PF2 PG0 | morpho | |
//! | Stop input | PA3 | Arduino A0 | safety: the stop is active while the input is OFF (open wire = stop) |
//! | OUT0-OUT3 PM1-PM8 | PD0 PD1 PG2 PG3 | morpho | outputs: high = ON; every output low after reset, panic, HardFault |
//! | OUT4 PE4, OUT5 PE5 | PD7 PD11 | morpho | pattern 4 |
//! | OUT6 MOVE, OUT7 ZONE1 | PD12 PD13 | morpho | |
//! | OUT9 MODES | PF7 | morpho | pattern 1 |
//! | OUT10 HEND, OUT11 PEND, OUT12 SV | PF8 PF9 PE9 | morpho, morpho, Arduino D6 | |
//! | OUT13 LINK, OUT14 *ALM | PE11 PE13 | Arduino D5, D3 | |
//! | LED run / bus link / alarm | PB0 / PB7 / PB14 | LD1 green / LD2 blue / LD3 red | on the board, lit high |
//! | Ethernet RMII | PA1 REF_CLK, PA2 MDIO, PC1 MDC, PA7 CRS_DV, PC4 RXD0, PC5 RXD1, PG11 TX_EN, PG13 TXD0, PB13 TXD1 | (on board) | LAN8742A at SMI address 0 |
//! | (held low) | PA12 | USB OTG D+ | STM32F42x errata 2.2.11: see [`hold_pa12_low`] |
//!
//! The 24 V input and output stages are not on this board: as on the others, the table assumes
//! non-inverting stages, and the carrier holds each output stage's input and each transceiver's
//! DE low with a 10 kΩ pull-down. **From reset until the firmware drives them** every pin of the
//! table is a floating input (none is a JTAG pin with a pull-up: PA15, PB4 stay unused), so those
//! pull-downs keep every output OFF and both drivers off meanwhile.

mod ethernet;

use core::sync::atomic::{AtomicBool, Ordering};

use embassy_stm32::eth::{self, Sma};
use embassy_stm32::exti::{self, ExtiInput};
use embassy_stm32::peripherals::{RNG, USART2, USART6};
use embassy_stm32::rng::{self, Rng};
use embassy_stm32::usart::{self, BufferedInterruptHandler, BufferedUart, ConfigError};
use embassy_stm32::{bind_interrupts, interrupt, Peripherals};

pub use ethernet::{Ethernet, EthernetDevice};

use super::{
    driver_enable, indicator_on_fault, input, led, line_config, output, settings_flash, Board,
    UartRegs, Watchdog, BUS_RX, BUS_TX, INPUT_ON, OUTPUT_ON, PLC_RX, PLC_TX,
};
use crate::discrete::{Inputs, Leds, Outputs};
use crate::io::Pins;
use crate::pins::{LineBreak, PinId};
use crate::serial::Rs485;

/// Bank 2 of the flash (0x0810_0000 to 0x0820_0000), as offsets from 0x0810_0000, through the
/// whole chip's blocking flash driver: the settings (sectors 12 and 13), embassy-boot's STATE
/// (sector 14) and the DFU partition (sectors 17-23; `rc_boot::layout::F429`).
///
/// - **Interrupts run during an erase.** embassy-stm32 0.6.0's per-region flash objects (such as
///   `Bank2Region1`) erase each sector and write each word inside a critical section
///   (`erase_sector_with_critical_section`): a 16 KiB sector masked every interrupt for 0.25-0.5 s
///   (UART bytes and Ethernet frames lost, the stop input's interrupt and embassy-time held). The
///   whole chip's object does neither (`erase_sector_unlocked`, `write_chunk_unlocked`), which is
///   safe here: the program, its vectors and every handler run from bank 1 while bank 2 is
///   erased or written (read-while-write between the banks), and no handler touches the flash
///   interface. The task that asked still waits for a blocking erase (the driver polls
///   FLASH_SR.BSY): the executor's other tasks, and the stop on the bus, wait for it too
///   (docs/plc.md, "Settings, SAVE and factory reset"). So the blocking [`NorFlash::erase`]
///   reaches only the four 16 KiB sectors (12-15: the settings and STATE).
/// - **DFU's 128 KiB sectors are erased without waiting** ([`SettingsSectors::erase_step`]): one
///   takes 1 s (2 s at most, x32), past the 1 s IWDG, and the gateway task must serve the lines
///   meanwhile. The first call starts the sector's erase and returns; later calls look at
///   FLASH_SR.BSY, until it is done. Any other operation first waits for it to end (a SAVE during
///   an update's erase: the watchdog fed meanwhile).
/// - **x32.** embassy-stm32 0.6.0 never sets FLASH_CR.PSIZE for an erase, and its writes leave
///   it at 0 (x8, the reset value), where a 16 KiB sector takes about 0.4 s (0.8 s at most)
///   instead of 0.25 s (0.5 s) at x32 (STM32F429 datasheet, flash characteristics; 2.7-3.6 V
///   allows x32). PSIZE is set in the unlocked FLASH_CR before each sector (embassy's own unlock
///   then finds it unlocked, and its lock after the sector keeps the field).
/// - **The watchdog is fed before each sector**: the longest stretch without a pet is one
///   sector's erase, 0.5 s, against the IWDG's shortest 0.68 s (`super::WATCHDOG_TIMEOUT_US`),
///   however many sectors an erase spans.
/// - **The data cache** is off while a sector of bank 2 is erased without waiting, and emptied
///   after (STM32F42x/43x errata 2.2.12, as embassy-stm32 does around its own erases).
/// - **Bounds**: the whole chip's driver takes any offset, the program's too; every offset here
///   is checked against bank 2 first.
///
/// [`NorFlash::erase`]: embedded_storage::nor_flash::NorFlash::erase
pub struct SettingsSectors {
    flash: embassy_stm32::flash::Flash<'static, embassy_stm32::flash::Blocking>,
    /// A DFU sector whose erase was started and not yet seen ended.
    erasing: Option<Erasing>,
}

/// A sector erase under way ([`SettingsSectors::erase_step`]).
#[derive(Clone, Copy)]
struct Erasing {
    /// Its offset in bank 2.
    offset: u32,
    /// The data cache was on before it (it is off while the erase runs).
    dcache: bool,
}

/// Bank 2's first sector (0x0810_0000) as an offset from the start of flash.
const BANK_2: u32 = rc_boot::layout::F429_BANK2 - rc_boot::layout::FLASH_BASE;
/// Bank 2's size.
const BANK_LEN: u32 = 0x10_0000;
/// A sector of bank 2's first region.
const SECTOR: u32 = rc_boot::layout::F429_SMALL_SECTOR;
/// The four sectors of bank 2's first region: what the blocking erase reaches.
const SECTORS_LEN: u32 = 4 * SECTOR;
/// Bank 2's 128 KiB sectors (17-23): from this offset.
const LARGE_FROM: u32 = 0x2_0000;
/// A 128 KiB sector.
const LARGE: u32 = rc_boot::layout::F429_SECTOR;
/// The index in its bank of the first 128 KiB sector (FLASH_CR.SNB: bank 2's have bit 4 set).
const LARGE_INDEX: u32 = 5;

impl SettingsSectors {
    /// Bank 2 through the whole chip's driver.
    pub fn new(
        flash: embassy_stm32::flash::Flash<'static, embassy_stm32::flash::Blocking>,
    ) -> Self {
        SettingsSectors {
            flash,
            erasing: None,
        }
    }

    /// `BANK_2 + offset`, if `offset..offset + len` lies inside bank 2.
    fn address(offset: u32, len: usize) -> Result<u32, embassy_stm32::flash::Error> {
        let len = u32::try_from(len).map_err(|_| embassy_stm32::flash::Error::Size)?;
        match offset.checked_add(len) {
            Some(end) if end <= BANK_LEN => Ok(BANK_2 + offset),
            _ => Err(embassy_stm32::flash::Error::Size),
        }
    }

    /// One step of the erase of the 128 KiB sector at `offset` (in bank 2: 0x2_0000 and every
    /// 128 KiB after): started at the first call, `WouldBlock` while the flash works, its result
    /// once it has ended. The gateway task calls it once a pass, between its other work.
    pub fn erase_step(&mut self, offset: u32) -> nb::Result<(), embassy_stm32::flash::Error> {
        use embassy_stm32::flash::Error;
        use embassy_stm32::pac::{flash::vals::Psize, FLASH};
        if let Some(erasing) = self.erasing {
            if FLASH.sr().read().bsy() {
                return Err(nb::Error::WouldBlock);
            }
            let ended = self.end_erase(erasing);
            if erasing.offset == offset {
                return ended.map_err(nb::Error::Other);
            }
        }
        // RM0090's sequence starts with no operation under way.
        if FLASH.sr().read().bsy() {
            return Err(nb::Error::WouldBlock);
        }
        if !(LARGE_FROM..BANK_LEN).contains(&offset) || !(offset - LARGE_FROM).is_multiple_of(LARGE)
        {
            return Err(nb::Error::Other(Error::Unaligned));
        }
        unlock();
        // Clears the error flags (written back as read: they clear on a 1).
        FLASH.sr().modify(|_| {});
        let dcache = FLASH.acr().read().dcen();
        FLASH.acr().modify(|w| w.set_dcen(false));
        let index = LARGE_INDEX + (offset - LARGE_FROM) / LARGE;
        FLASH.cr().write(|w| {
            w.set_ser(true);
            w.set_snb(0x10 | index as u8);
            w.set_psize(Psize::PSIZE32);
        });
        FLASH.cr().modify(|w| w.set_strt(true));
        self.erasing = Some(Erasing { offset, dcache });
        Err(nb::Error::WouldBlock)
    }

    /// The erase under way has ended (FLASH_SR.BSY clear): the interface locked, the data cache
    /// emptied and back, its result.
    fn end_erase(&mut self, erasing: Erasing) -> Result<(), embassy_stm32::flash::Error> {
        use embassy_stm32::flash::Error;
        use embassy_stm32::pac::FLASH;
        self.erasing = None;
        let sr = FLASH.sr().read();
        FLASH.cr().write(|w| w.set_lock(true));
        FLASH.sr().modify(|_| {});
        if erasing.dcache {
            let acr = FLASH.acr();
            acr.modify(|w| w.set_dcrst(true));
            acr.modify(|w| w.set_dcrst(false));
            acr.modify(|w| w.set_dcen(true));
        }
        if sr.pgserr() {
            Err(Error::Seq)
        } else if sr.pgperr() {
            Err(Error::Parallelism)
        } else if sr.pgaerr() {
            Err(Error::Unaligned)
        } else if sr.wrperr() {
            Err(Error::Protected)
        } else {
            Ok(())
        }
    }

    /// Waits for an erase under way to end, the watchdog fed (its result is not lost: the DFU
    /// job's next step starts the sector's erase again).
    fn settle(&mut self) {
        while let Some(erasing) = self.erasing {
            if embassy_stm32::pac::FLASH.sr().read().bsy() {
                super::pet_watchdog();
            } else {
                let _ = self.end_erase(erasing);
            }
        }
    }
}

impl embedded_storage::nor_flash::ErrorType for SettingsSectors {
    type Error = embassy_stm32::flash::Error;
}

impl embedded_storage::nor_flash::ReadNorFlash for SettingsSectors {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let at = Self::address(offset, bytes.len())?;
        self.settle();
        self.flash.blocking_read(at, bytes)
    }

    fn capacity(&self) -> usize {
        BANK_LEN as usize
    }
}

impl embedded_storage::nor_flash::NorFlash for SettingsSectors {
    const WRITE_SIZE: usize = embassy_stm32::flash::WRITE_SIZE;
    const ERASE_SIZE: usize = SECTOR as usize;

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let at = Self::address(offset, bytes.len())?;
        self.settle();
        self.flash.blocking_write(at, bytes)
    }

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        use embassy_stm32::flash::Error;
        use embassy_stm32::pac::{flash::vals::Psize, FLASH};
        if !from.is_multiple_of(SECTOR) || !to.is_multiple_of(SECTOR) || from > to {
            return Err(Error::Unaligned);
        }
        if to > SECTORS_LEN {
            // A 128 KiB sector blocks for up to 2 s: `erase_step`.
            return Err(Error::Size);
        }
        self.settle();
        let mut sector = BANK_2 + from;
        while sector < BANK_2 + to {
            super::pet_watchdog();
            unlock();
            FLASH.cr().modify(|w| w.set_psize(Psize::PSIZE32));
            let result = self.flash.blocking_erase(sector, sector + SECTOR);
            FLASH.cr().modify(|w| w.set_lock(true));
            result?;
            sector += SECTOR;
        }
        Ok(())
    }
}

/// Unlocks FLASH_CR (RM0090, "Unlocking the Flash control register": its two keys), if locked.
fn unlock() {
    let flash = embassy_stm32::pac::FLASH;
    if flash.cr().read().lock() {
        flash.keyr().write_value(0x4567_0123);
        flash.keyr().write_value(0xCDEF_89AB);
    }
}

/// Offsets in bank 2 of a region of the bootloader's layout.
const fn offsets(region: rc_boot::layout::Region) -> core::ops::Range<u32> {
    let start = region.offset_from(rc_boot::layout::F429_BANK2);
    start..start + region.len()
}

/// The DFU partition (offsets in bank 2): where an image sent over the PLC link is written, and
/// the old firmware kept during a trial (`rc_boot::layout::F429.dfu`, sectors 17-23).
pub const DFU_RANGE: core::ops::Range<u32> = offsets(rc_boot::layout::F429.dfu);

/// embassy-boot's STATE sector (offsets in bank 2): the mark for a swap, the swap's progress
/// (`rc_boot::layout::F429.state`, sector 14).
pub const STATE_RANGE: core::ops::Range<u32> = offsets(rc_boot::layout::F429.state);

// The settings sectors are the layout's too; STATE is erased with the blocking erase, DFU only
// in steps.
const _: () = assert!(
    offsets(rc_boot::layout::F429.settings).start == SETTINGS_RANGE.start
        && offsets(rc_boot::layout::F429.settings).end == SETTINGS_RANGE.end
        && STATE_RANGE.end <= SECTORS_LEN
        && DFU_RANGE.start == LARGE_FROM
        && DFU_RANGE.end == BANK_LEN
);

/// The board, as the gateway names it to the PLC (device identification).
pub const MODEL_NAME: &str = "NUCLEO-F429ZI (STM32F429ZI)";
/// System clock: 168 MHz, the highest the F429 runs without its over-drive mode, and one whose
/// PLL also makes the 48 MHz the RNG needs (180 MHz cannot: 360 MHz VCO / 48 MHz is not whole).
const SYSCLK_HZ: u32 = 168_000_000;
/// The bus UART's (USART6's) kernel clock: PCLK2, the system clock halved (APB2's maximum is
/// 90 MHz). 9.6 to 230.4 kbit/s: dividers 8,750 to 365.
pub const BUS_UART_HZ: u32 = SYSCLK_HZ / 2;
/// The PLC UART's (USART2's) kernel clock: PCLK1, a quarter of the system clock (APB1's maximum
/// is 45 MHz). 1.2 kbit/s needs a divider of 35,000, under the 16-bit BRR's 65,535; on APB2
/// (84 MHz) it would be 70,000, which the driver refuses.
pub const PLC_UART_HZ: u32 = SYSCLK_HZ / 4;
/// The board's LEDs LD1-LD3 are lit by a high level.
pub const LED_ON: embassy_stm32::gpio::Level = embassy_stm32::gpio::Level::High;

/// The settings: the first two 16 KiB sectors of bank 2 (sectors 12 and 13, 0x0810_0000 to
/// 0x0810_8000), as offsets in bank 2's first region, which is what the store's flash is
/// ([`super::SettingsFlash`]). `memory/f429zi.x` keeps the program in bank 1 and says why these
/// sectors.
pub const SETTINGS_RANGE: core::ops::Range<u32> = 0..0x8000;

bind_interrupts!(struct Irqs {
    USART2 => BufferedInterruptHandler<USART2>;
    USART6 => BufferedInterruptHandler<USART6>;
    EXTI3 => exti::InterruptHandler<interrupt::typelevel::EXTI3>;
    ETH => eth::InterruptHandler;
    HASH_RNG => rng::InterruptHandler<RNG>;
});

/// The clock tree of [`SYSCLK_HZ`]: the 8 MHz the ST-LINK feeds to PH0 (its MCO, HSE bypass)
/// / 4 × 168 = 336 MHz VCO; / 2 = 168 MHz system clock, / 7 = 48 MHz for the RNG. The Ethernet
/// needs HCLK of 25 MHz at least; here it is 168 MHz.
///
/// **Without the ST-LINK's clock** (the board powered from VIN or E5V with the ST-LINK not
/// running, or its MCO cut off by the solder bridges) the same tree from HSI, 16 MHz / 8:
/// embassy-stm32 0.6.0 waits for HSERDY without bound, so the HSE is tried here first, for
/// [`HSE_WAIT_MS`] at most ([`hse_runs`]). Every rate is the same; their accuracy is HSI's,
/// ±1 % at 25 °C but -4 to +4 % from -10 to 85 °C (datasheet), past what a UART tolerates (about
/// 2 %) at the ends of that range. The start logs it ([`board`]).
pub fn clock_config() -> embassy_stm32::Config {
    use embassy_stm32::rcc::{
        AHBPrescaler, APBPrescaler, Hse, HseMode, Pll, PllMul, PllPDiv, PllPreDiv, PllQDiv,
        PllSource, Sysclk,
    };
    let mut config = embassy_stm32::Config::default();
    const HSE_HZ: u32 = 8_000_000;
    const _: () = assert!(HSE_HZ / 4 * 168 / 2 == SYSCLK_HZ);
    const _: () = assert!(HSE_HZ / 4 * 168 / 7 == 48_000_000);
    const _: () = assert!(HSI_HZ / 8 * 168 / 2 == SYSCLK_HZ);
    const _: () = assert!(HSI_HZ / 8 * 168 / 7 == 48_000_000);
    let on_hse = hse_runs();
    ON_HSE.store(on_hse, Ordering::Relaxed);
    // The wait counts against the watchdog's start-up stretch no more.
    super::pet_watchdog();
    // The PLL's input at 2 MHz either way (the reference manual's advice against jitter).
    let prediv = if on_hse {
        config.rcc.hse = Some(Hse {
            freq: embassy_stm32::time::Hertz(HSE_HZ),
            mode: HseMode::Bypass,
        });
        config.rcc.pll_src = PllSource::HSE;
        PllPreDiv::DIV4
    } else {
        config.rcc.hsi = true;
        config.rcc.pll_src = PllSource::HSI;
        PllPreDiv::DIV8
    };
    config.rcc.pll = Some(Pll {
        prediv,
        mul: PllMul::MUL168,
        divp: Some(PllPDiv::DIV2),
        divq: Some(PllQDiv::DIV7),
        divr: None,
    });
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.ahb_pre = AHBPrescaler::DIV1;
    config.rcc.apb1_pre = APBPrescaler::DIV4;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config
}

/// HSI, the clock the chip runs from out of reset, until `embassy_stm32::init`.
const HSI_HZ: u32 = 16_000_000;
/// How long the start waits for the ST-LINK's clock: the time-out ST's own HAL gives the HSE
/// (`HSE_STARTUP_TIMEOUT`). An external clock is ready within a few of its cycles once it runs.
const HSE_WAIT_MS: u32 = 100;
/// Whether the start found the HSE ([`clock_config`]); read by [`board`].
static ON_HSE: AtomicBool = AtomicBool::new(false);

/// Turns the HSE on (bypass: a clock on PH0, not a crystal) and waits for it at most
/// [`HSE_WAIT_MS`] (counted in HSI cycles, before `init` changes the clock: cortex-m's
/// `asm::delay` loop takes three cycles a count on the Cortex-M4); off again if it did not come.
/// Runs with the watchdog already started (`super::start_watchdog`).
fn hse_runs() -> bool {
    use embassy_stm32::pac::RCC;
    // HSEBYP may be written only while the HSE is off (RM0090, RCC_CR), as it is after reset.
    RCC.cr().modify(|w| w.set_hseon(false));
    RCC.cr().modify(|w| w.set_hsebyp(true));
    RCC.cr().modify(|w| w.set_hseon(true));
    for _ in 0..HSE_WAIT_MS {
        if RCC.cr().read().hserdy() {
            return true;
        }
        cortex_m::asm::delay(HSI_HZ / 1000 / 3);
    }
    RCC.cr().modify(|w| w.set_hseon(false));
    RCC.cr().modify(|w| w.set_hsebyp(false));
    false
}

/// This chip's part of a UART's settings: nothing (DE is a GPIO).
pub fn uart_config(_config: &mut usart::Config) {}

/// Why the chip last started, from RCC_CSR's reset flags, which are then cleared so that the
/// next start reads its own. (A power-on sets BORRSTF too: POR is checked before it.)
pub fn reset_cause() -> protocol::plc::ResetCause {
    use protocol::plc::ResetCause;
    let rcc = embassy_stm32::pac::RCC;
    let csr = rcc.csr().read();
    let cause = if csr.wdgrstf() || csr.wwdgrstf() {
        ResetCause::Watchdog
    } else if csr.sftrstf() {
        ResetCause::Software
    } else if csr.porrstf() || csr.borrstf() {
        ResetCause::PowerOn
    } else if csr.padrstf() {
        ResetCause::Pin
    } else if csr.lpwrrstf() {
        ResetCause::Other
    } else {
        ResetCause::PowerOn
    };
    rcc.csr().modify(|w| w.set_rmvf(true));
    cause
}

/// STM32F42x/43x errata 2.2.11: on silicon before revision 3, reading flash bank 2 (where the
/// settings are) can return wrong data while PA12 toggles; the workaround is PA12 an output,
/// low, pulled down, and embassy-stm32 refuses (panics) to read bank 2 on such silicon unless
/// PA12 is so. PA12 is the USB OTG connector's D+, which this firmware does not use: held low,
/// the connector only looks unplugged to a host. Set through the registers, not a HAL pin
/// object, which would return the pin to an input when dropped.
fn hold_pa12_low() {
    use embassy_stm32::pac::gpio::vals::{Moder, Pupdr};
    let gpioa = embassy_stm32::pac::GPIOA;
    const PIN: usize = 12;
    critical_section::with(|_| {
        gpioa.bsrr().write(|w| w.set_br(PIN, true));
        gpioa.pupdr().modify(|w| w.set_pupdr(PIN, Pupdr::PULL_DOWN));
        gpioa.moder().modify(|w| w.set_moder(PIN, Moder::OUTPUT));
    });
}

/// Takes the peripherals this board uses. Fails only if a UART rejects its configuration.
pub fn board(
    p: Peripherals,
    plc_line: protocol::plc::PlcLine,
) -> Result<(Board, Pins), ConfigError> {
    // Outputs and driver enables first, driven OFF, so that nothing is ever ON (and no
    // transmitter drives a line) before the gateway says so.
    let outputs = Outputs::new(
        [
            (0, output(p.PD0)),
            (1, output(p.PD1)),
            (2, output(p.PG2)),
            (3, output(p.PG3)),
            (4, output(p.PD7)),
            (5, output(p.PD11)),
            (6, output(p.PD12)),
            (7, output(p.PD13)),
            (9, output(p.PF7)),
            (10, output(p.PF8)),
            (11, output(p.PF9)),
            (12, output(p.PE9)),
            (13, output(p.PE11)),
            (14, output(p.PE13)),
        ],
        OUTPUT_ON,
    );
    let bus_de = driver_enable(p.PF15);
    let plc_de = driver_enable(p.PD4);
    let leds = Leds::new(led(p.PB0), led(p.PB7), indicator_on_fault(p.PB14), LED_ON);
    hold_pa12_low();
    let inputs = Inputs::new(
        [
            (0, input(p.PE2)),
            (1, input(p.PE3)),
            (2, input(p.PE4)),
            (3, input(p.PE5)),
            (4, input(p.PE6)),
            (5, input(p.PE7)),
            (6, input(p.PE8)),
            (7, input(p.PE10)),
            (8, input(p.PE12)),
            (9, input(p.PE14)),
            (11, input(p.PE15)),
            (12, input(p.PF0)),
            (13, input(p.PF1)),
            (14, input(p.PF2)),
            (15, input(p.PG0)),
        ],
        ExtiInput::from_input(input(p.PA3), p.EXTI3, Irqs),
        INPUT_ON,
    );

    let line_break = LineBreak::new(PinId::of(&*p.PG14), None);
    let bus = BufferedUart::new(
        p.USART6,
        p.PG9,
        p.PG14,
        BUS_TX.take(),
        BUS_RX.take(),
        Irqs,
        line_config(super::BUS_INITIAL_BAUD, protocol::plc::Parity::None),
    )?;
    let plc = BufferedUart::new(
        p.USART2,
        p.PD6,
        p.PD5,
        PLC_TX.take(),
        PLC_RX.take(),
        Irqs,
        line_config(plc_line.baud.bits_per_second(), plc_line.parity),
    )?;

    if ON_HSE.load(Ordering::Relaxed) {
        // The clock security system: should the ST-LINK's clock stop (the ST-LINK reset or
        // unpowered), the chip falls back to HSI and raises an NMI, whose handler forces the
        // outputs safe and resets (`rt::DefaultHandler`); the next start runs on HSI. Without
        // it, the system clock would stop with the outputs as they were until the watchdog.
        embassy_stm32::pac::RCC.cr().modify(|w| w.set_csson(true));
    } else {
        warn!(
            "clock: no 8 MHz from the ST-LINK (HSE): on HSI, UART rates within 1 % only near 25 C"
        );
    }

    // The seed before the MAC: the RNG runs from the PLL's 48 MHz (`clock_config`).
    let seed = Rng::new(p.RNG, Irqs).next_u64();
    // A board whose PHY does not answer on the management interface (clocked from HCLK, not by
    // the PHY), or sends no reference clock, gets no Ethernet and keeps its RS485 side, instead
    // of hanging here (embassy-stm32 0.6.0 waits for the MAC's reset without bound).
    let mut sma = Sma::new(p.ETH_SMA, p.PA2, p.PC1);
    let phy = ethernet::phy_answers(&mut sma);
    if !phy {
        error!("net: no LAN8742A answers at SMI address 0: no Ethernet");
    }
    let clocked = phy && ethernet::mac_clock_runs();
    if phy && !clocked {
        error!("net: no 50 MHz reference clock from the PHY: no Ethernet");
    }
    let ethernet = if clocked {
        // The PHY's reset is waited for here (at most `ethernet::PHY_RESET_WAIT_MS`).
        let device = eth::Ethernet::new_with_phy(
            ethernet::PACKET_QUEUE.take(),
            p.ETH,
            Irqs,
            p.PA1,
            p.PA7,
            p.PC4,
            p.PC5,
            p.PG13,
            p.PB13,
            p.PG11,
            ethernet::mac_address(),
            ethernet::Lan8742a::new(sma, ethernet::PHY_ADDRESS),
        );
        Some(Ethernet { device, seed })
    } else {
        None
    };

    let board = Board {
        bus: Rs485::new(
            bus,
            UartRegs(embassy_stm32::pac::USART6),
            (super::BUS_INITIAL_BAUD, protocol::plc::Parity::None),
            Some(line_break),
            Some(bus_de),
        ),
        plc: Rs485::new(
            plc,
            UartRegs(embassy_stm32::pac::USART2),
            (plc_line.baud.bits_per_second(), plc_line.parity),
            None,
            Some(plc_de),
        ),
        watchdog: Watchdog::new(p.IWDG),
        settings_flash: settings_flash(p.FLASH),
        ethernet,
    };
    Ok((
        board,
        Pins {
            inputs,
            outputs,
            leds,
        },
    ))
}
