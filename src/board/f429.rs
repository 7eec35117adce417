//! # NUCLEO-F429ZI (STM32F429ZI, 2 MiB flash, 192 KiB SRAM, LAN8742A Ethernet PHY)
//!
//! The board with Ethernet: Modbus TCP on port 502 ([`crate::net`]) beside Modbus RTU on the PLC
//! line (both at once), and every PIO port, so patterns 0, 1, 4 and 5 all run. The F4's USARTs
//! have no hardware driver enable (CR3.DEM is an F0/F3/F7/L4/H7 feature): DE is a GPIO, set before
//! a write and cleared once the last stop bit has left, as on the F103 ([`Rs485`]).
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

use core::future::Future;
use core::sync::atomic::{AtomicBool, Ordering};
use core::task::Context;

use embassy_stm32::eth::{self, PacketQueue, Phy, Sma, StationManagement};
use embassy_stm32::exti::{self, ExtiInput};
use embassy_stm32::peripherals::{ETH, ETH_SMA, RNG, USART2, USART6};
use embassy_stm32::rng::{self, Rng};
use embassy_stm32::usart::{self, BufferedInterruptHandler, BufferedUart, ConfigError};
use embassy_stm32::{bind_interrupts, interrupt, Peripherals};
use static_cell::ConstStaticCell;

use super::{
    driver_enable, indicator_on_fault, input, led, line_config, output, settings_flash, Board,
    UartRegs, Watchdog, BUS_RX, BUS_TX, INPUT_ON, OUTPUT_ON, PLC_RX, PLC_TX,
};
use crate::discrete::{Inputs, Leds, Outputs};
use crate::io::Pins;
use crate::pins::{LineBreak, PinId};
use crate::serial::Rs485;

/// The settings' flash: bank 2's first four 16 KiB sectors (sectors 12-15, 0x0810_0000 to
/// 0x0811_0000), as offsets from 0x0810_0000, through the whole chip's blocking flash driver.
///
/// - **Interrupts run during an erase.** embassy-stm32 0.6.0's per-region flash objects (such as
///   `Bank2Region1`) erase each sector and write each word inside a critical section
///   (`erase_sector_with_critical_section`): a 16 KiB sector masked every interrupt for 0.25-0.5 s
///   (UART bytes and Ethernet frames lost, the stop input's interrupt and embassy-time held). The
///   whole chip's object does neither (`erase_sector_unlocked`, `write_chunk_unlocked`), which is
///   safe here: the program, its vectors and every handler run from bank 1 while bank 2 is
///   erased or written (read-while-write between the banks), and no handler touches the flash
///   interface. The task that asked still waits for the erase (the driver polls FLASH_SR.BSY):
///   the executor's other tasks, and the stop on the bus, wait for it too (docs/plc.md, "Settings, SAVE and factory reset").
/// - **x32.** embassy-stm32 0.6.0 never sets FLASH_CR.PSIZE for an erase, and its writes leave
///   it at 0 (x8, the reset value), where a 16 KiB sector takes about 0.4 s (0.8 s at most)
///   instead of 0.25 s (0.5 s) at x32 (STM32F429 datasheet, flash characteristics; 2.7-3.6 V
///   allows x32). PSIZE is set in the unlocked FLASH_CR before each sector (embassy's own unlock
///   then finds it unlocked, and its lock after the sector keeps the field).
/// - **The watchdog is fed before each sector**: the longest stretch without a pet is one
///   sector's erase, 0.5 s, against the IWDG's shortest 0.68 s (`super::WATCHDOG_TIMEOUT_US`),
///   however many sectors an erase spans.
/// - **Bounds**: the whole chip's driver takes any offset, the program's too; every offset here
///   is checked against these four sectors first.
pub struct SettingsSectors(
    pub embassy_stm32::flash::Flash<'static, embassy_stm32::flash::Blocking>,
);

/// Bank 2's first sector (0x0810_0000) as an offset from the start of flash.
const BANK_2: u32 = 0x10_0000;
/// A sector of bank 2's first region.
const SECTOR: u32 = 16 * 1024;
/// The four sectors of bank 2's first region.
const SECTORS_LEN: u32 = 4 * SECTOR;

impl SettingsSectors {
    /// `BANK_2 + offset`, if `offset..offset + len` lies inside the four sectors.
    fn address(offset: u32, len: usize) -> Result<u32, embassy_stm32::flash::Error> {
        let len = u32::try_from(len).map_err(|_| embassy_stm32::flash::Error::Size)?;
        match offset.checked_add(len) {
            Some(end) if end <= SECTORS_LEN => Ok(BANK_2 + offset),
            _ => Err(embassy_stm32::flash::Error::Size),
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
        self.0.blocking_read(at, bytes)
    }

    fn capacity(&self) -> usize {
        SECTORS_LEN as usize
    }
}

impl embedded_storage::nor_flash::NorFlash for SettingsSectors {
    const WRITE_SIZE: usize = embassy_stm32::flash::WRITE_SIZE;
    const ERASE_SIZE: usize = SECTOR as usize;

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let at = Self::address(offset, bytes.len())?;
        self.0.blocking_write(at, bytes)
    }

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        use embassy_stm32::flash::Error;
        use embassy_stm32::pac::{flash::vals::Psize, FLASH};
        if !from.is_multiple_of(SECTOR) || !to.is_multiple_of(SECTOR) || from > to {
            return Err(Error::Unaligned);
        }
        Self::address(from, (to - from) as usize)?;
        let mut sector = BANK_2 + from;
        while sector < BANK_2 + to {
            super::pet_watchdog();
            if FLASH.cr().read().lock() {
                FLASH.keyr().write_value(0x4567_0123);
                FLASH.keyr().write_value(0xCDEF_89AB);
            }
            FLASH.cr().modify(|w| w.set_psize(Psize::PSIZE32));
            let result = self.0.blocking_erase(sector, sector + SECTOR);
            FLASH.cr().modify(|w| w.set_lock(true));
            result?;
            sector += SECTOR;
        }
        Ok(())
    }
}

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

/// The LAN8742A's address on the SMI: its PHYAD0 strap, low on the NUCLEO-F429ZI (UM1974).
const PHY_ADDRESS: u8 = 0;

/// Ethernet frames the DMA holds, each way: 4 of 1.5 KiB each (12 KiB of RAM). Modbus TCP moves
/// small segments; four let a burst from several clients in while the stack is busy.
const PACKETS: usize = 4;

/// The Ethernet DMA's descriptors and frame buffers, in `.bss` (SRAM, which the DMA reaches:
/// `memory/f429zi.x`), built in place (`ConstStaticCell`: no 12 KiB temporary on the stack).
static PACKET_QUEUE: ConstStaticCell<PacketQueue<PACKETS, PACKETS>> =
    ConstStaticCell::new(PacketQueue::new());

bind_interrupts!(struct Irqs {
    USART2 => BufferedInterruptHandler<USART2>;
    USART6 => BufferedInterruptHandler<USART6>;
    EXTI3 => exti::InterruptHandler<interrupt::typelevel::EXTI3>;
    ETH => eth::InterruptHandler;
    HASH_RNG => rng::InterruptHandler<RNG>;
});

/// The Ethernet driver as the network stack takes it ([`crate::net`]).
pub type EthernetDevice = eth::Ethernet<'static, ETH, Lan8742a<Sma<'static, ETH_SMA>>>;

/// The Ethernet, brought up by [`board`], and what the network stack needs besides it.
pub struct Ethernet {
    /// The MAC and PHY.
    pub device: EthernetDevice,
    /// A random seed from the RNG: embassy-net takes its TCP initial sequence numbers and
    /// ephemeral ports from it, which must not be guessable (a guessed sequence number lets
    /// a third party inject into a connection).
    pub seed: u64,
}

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

/// The MAC address: locally administered (first octet 0x02: the "local" bit set, the multicast
/// bit clear), the other five octets a hash of the chip's 96-bit unique ID, so that each board
/// keeps its own address across starts and two boards on one network differ (but for a hash
/// collision, one in 2⁴⁰ per pair) without an OUI of our own.
fn mac_address() -> [u8; 6] {
    // FNV-1a, 64 bits: small and good enough to spread the ID's lot, wafer and X/Y fields.
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for byte in embassy_stm32::uid::uid() {
        hash ^= u64::from(byte);
        hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
    }
    let [a, b, c, d, e, ..] = hash.to_le_bytes();
    [0x02, a, b, c, d, e]
}

/// The LAN8742A's identifier, PHY ID 1 (register 2): Microchip's OUI bits 3-18 (LAN8742A data
/// sheet, 4.2.3); ID 2 (register 3) holds the model, 0xC13x.
const PHY_ID1: u16 = 0x0007;

/// Whether the PHY answers at [`PHY_ADDRESS`] with its identifier within
/// [`PHY_RESET_WAIT_MS`] (it leaves its own power-on reset with the board's; no PHY reads
/// 0xFFFF: MDIO floats high with its pull-up).
fn phy_answers(sma: &mut impl StationManagement) -> bool {
    for _ in 0..PHY_RESET_WAIT_MS {
        let (id1, id2) = (sma.smi_read(PHY_ADDRESS, 2), sma.smi_read(PHY_ADDRESS, 3));
        if id1 == PHY_ID1 && id2 & 0xFFF0 == 0xC130 {
            return true;
        }
        embassy_time::block_for(embassy_time::Duration::from_millis(1));
    }
    false
}

/// The LAN8742A through its SMI: reset, auto-negotiation advertising 10 and 100 Mbit/s, half and
/// full duplex, and the MAC set to the speed and duplex the link came up at.
///
/// Why not embassy's `GenericPhy`: its automatic address search panics when no PHY answers
/// (a damaged PHY would then stop the RS485 gateway, which needs no network), and waits for a
/// reset without bound at a fixed address. And embassy-stm32 0.6.0's MAC (eth v1) is set to
/// 100 Mbit/s full duplex once and never follows the link: a link at 10 Mbit/s or half duplex
/// would be up and pass nothing (or collide), so [`Phy::poll_link`] here sets the MAC's speed
/// (MACCR.FES) and duplex (MACCR.DM) to what the PHY resolved, whenever that changes.
///
/// **A partner that does not negotiate** (a switch port with its speed and duplex fixed): the PHY
/// finds the speed by parallel detection, which can only report half duplex (IEEE 802.3 clause
/// 28); the port itself is then almost always fixed at full duplex, so the MAC runs full duplex:
/// a port forced to 100 Mbit/s full duplex works (it never linked before: only 100 Mbit/s full
/// duplex was advertised and accepted). A port forced to *half* duplex would run mismatched
/// (late collisions, lost frames): README says to let such a port negotiate.
pub struct Lan8742a<S> {
    sma: S,
    address: u8,
    /// The speed (100 Mbit/s?) and duplex (full?) the MAC was last set to while the link was up.
    mode: Option<(bool, bool)>,
}

/// IEEE 802.3 clause 22 registers and the LAN8742A's own.
mod reg {
    /// Basic Control.
    pub const BCR: u8 = 0;
    pub const BCR_RESET: u16 = 1 << 15;
    pub const BCR_AUTONEG: u16 = 1 << 12;
    pub const BCR_RESTART_AUTONEG: u16 = 1 << 9;
    /// Basic Status.
    pub const BSR: u8 = 1;
    pub const BSR_LINK: u16 = 1 << 2;
    pub const BSR_AUTONEG_DONE: u16 = 1 << 5;
    /// Auto-negotiation advertisement: selector 802.3, 10BASE-T and 100BASE-TX, half and full
    /// duplex.
    pub const ANAR: u8 = 4;
    pub const ANAR_ALL: u16 = 1 << 8 | 1 << 7 | 1 << 6 | 1 << 5 | 0x0001;
    /// Auto-negotiation expansion: bit 0, the link partner negotiates.
    pub const ANER: u8 = 6;
    pub const ANER_PARTNER_NEGOTIATES: u16 = 1 << 0;
    /// LAN8742A PHY Special Control/Status: bits 4:2 the speed and duplex resolved (001 10 Mbit/s
    /// half, 101 10 full, 010 100 half, 110 100 full).
    pub const PSCSR: u8 = 31;
    pub const PSCSR_100: u16 = 1 << 3;
    pub const PSCSR_FULL: u16 = 1 << 4;
}

impl<S: StationManagement> Lan8742a<S> {
    /// The PHY at `address` on `sma`.
    pub fn new(sma: S, address: u8) -> Lan8742a<S> {
        Lan8742a {
            sma,
            address,
            mode: None,
        }
    }

    fn read(&mut self, register: u8) -> u16 {
        self.sma.smi_read(self.address, register)
    }

    fn write(&mut self, register: u8, value: u16) {
        self.sma.smi_write(self.address, register, value)
    }
}

/// Sets the MAC's speed and duplex (MACCR.FES, MACCR.DM), which embassy-stm32 0.6.0 sets to
/// 100 Mbit/s full duplex once. Called as the link comes up, before frames flow.
fn set_mac_mode(fast: bool, full: bool) {
    use embassy_stm32::pac::eth::vals::{Dm, Fes};
    embassy_stm32::pac::ETH.ethernet_mac().maccr().modify(|w| {
        w.set_fes(if fast { Fes::FES100 } else { Fes::FES10 });
        w.set_dm(if full {
            Dm::FULL_DUPLEX
        } else {
            Dm::HALF_DUPLEX
        });
    });
}

/// How long the PHY may take to leave its reset (the LAN8742A takes well under a millisecond;
/// an absent PHY reads all ones, the reset bit included, and is waited for this long only).
const PHY_RESET_WAIT_MS: u32 = 100;

/// How often the link is read while the stack waits for it.
const LINK_POLL: embassy_time::Duration = embassy_time::Duration::from_millis(500);

impl<S: StationManagement> Phy for Lan8742a<S> {
    fn phy_reset(&mut self) {
        self.write(reg::BCR, reg::BCR_RESET);
        for _ in 0..PHY_RESET_WAIT_MS {
            if self.read(reg::BCR) & reg::BCR_RESET == 0 {
                return;
            }
            embassy_time::block_for(embassy_time::Duration::from_millis(1));
        }
        warn!("Ethernet: the PHY did not answer");
    }

    fn phy_init(&mut self) {
        self.write(reg::ANAR, reg::ANAR_ALL);
        self.write(reg::BCR, reg::BCR_AUTONEG | reg::BCR_RESTART_AUTONEG);
    }

    fn poll_link(&mut self, cx: &mut Context) -> bool {
        // Read again after LINK_POLL: the stack polls the link only when woken.
        let _ = core::pin::pin!(embassy_time::Timer::after(LINK_POLL)).poll(cx);
        let bsr = self.read(reg::BSR);
        // All ones: no PHY answers (MDIO idles high).
        let up = reg::BSR_LINK | reg::BSR_AUTONEG_DONE;
        if bsr == u16::MAX || bsr & up != up {
            self.mode = None;
            return false;
        }
        let resolved = self.read(reg::PSCSR);
        let fast = resolved & reg::PSCSR_100 != 0;
        // Parallel detection (a partner that does not negotiate) says half duplex: see above.
        let full = resolved & reg::PSCSR_FULL != 0
            || self.read(reg::ANER) & reg::ANER_PARTNER_NEGOTIATES == 0;
        if self.mode != Some((fast, full)) {
            set_mac_mode(fast, full);
            self.mode = Some((fast, full));
            info!(
                "net: link up, {} Mbit/s, {} duplex",
                if fast { 100 } else { 10 },
                if full { "full" } else { "half" }
            );
        }
        true
    }
}

/// How long the MAC's DMA may take to leave its software reset once the PHY's reference clock
/// runs (a few of its cycles; [`mac_clock_runs`]).
const REF_CLK_WAIT_MS: u32 = 10;

/// Whether the PHY's 50 MHz reference clock (RMII REF_CLK, PA1) reaches the MAC. The MAC's DMA
/// leaves its software reset (ETH_DMABMR.SR) only once every clock of its interface runs, and
/// embassy-stm32 0.6.0 waits for that without bound in `Ethernet::new_with_phy`: a PHY that
/// answers on the management interface (clocked by the MCU) but sends no reference clock (its
/// crystal or its REF_CLK strap faulty) would hang the start there. So the same reset first,
/// bounded ([`REF_CLK_WAIT_MS`]); embassy's then passes at once. Also done in the order the
/// reference manual asks (RM0090, SYSCFG_PMC.MII_RMII_SEL: set while the MAC is held in reset,
/// before its clocks), which embassy's is not. Without the clock: the MAC's clocks off again,
/// `false`.
fn mac_clock_runs() -> bool {
    use embassy_stm32::pac::gpio::vals::Moder;
    use embassy_stm32::pac::{ETH, GPIOA, RCC, SYSCFG};
    const REF_CLK_PIN: usize = 1;
    const AF_ETH: u8 = 11;
    critical_section::with(|_| {
        RCC.ahb1rstr().modify(|w| w.set_ethrst(true));
        SYSCFG.pmc().modify(|w| w.set_mii_rmii_sel(true));
        RCC.ahb1rstr().modify(|w| w.set_ethrst(false));
        RCC.ahb1enr().modify(|w| {
            w.set_ethen(true);
            w.set_ethtxen(true);
            w.set_ethrxen(true);
        });
        GPIOA.afr(0).modify(|w| w.set_afr(REF_CLK_PIN, AF_ETH));
        GPIOA
            .moder()
            .modify(|w| w.set_moder(REF_CLK_PIN, Moder::ALTERNATE));
    });
    let dma = ETH.ethernet_dma();
    dma.dmabmr().modify(|w| w.set_sr(true));
    for _ in 0..REF_CLK_WAIT_MS {
        if !dma.dmabmr().read().sr() {
            return true;
        }
        embassy_time::block_for(embassy_time::Duration::from_millis(1));
    }
    RCC.ahb1enr().modify(|w| {
        w.set_ethen(false);
        w.set_ethtxen(false);
        w.set_ethrxen(false);
    });
    false
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
        line_config(plc_line.baud, plc_line.parity),
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
    let phy = phy_answers(&mut sma);
    if !phy {
        error!("net: no LAN8742A answers at SMI address 0: no Ethernet");
    }
    let clocked = phy && mac_clock_runs();
    if phy && !clocked {
        error!("net: no 50 MHz reference clock from the PHY: no Ethernet");
    }
    let ethernet = if clocked {
        // The PHY's reset is waited for here (at most `PHY_RESET_WAIT_MS`).
        let device = eth::Ethernet::new_with_phy(
            PACKET_QUEUE.take(),
            p.ETH,
            Irqs,
            p.PA1,
            p.PA7,
            p.PC4,
            p.PC5,
            p.PG13,
            p.PB13,
            p.PG11,
            mac_address(),
            Lan8742a::new(sma, PHY_ADDRESS),
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
            (plc_line.baud, plc_line.parity),
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
