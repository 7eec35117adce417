//! The board: what the gateway task drives ([`Board`]) and every board-specific choice, in one
//! module per board (the build picks one with a Cargo feature):
//!
//! | Feature | Module | Board |
//! |---|---|---|
//! | `board-l475` (default) | [`l475`] | ST B-L475E-IOT01A (STM32L475VG, hardware driver enable); what QEMU emulates |
//! | `board-f103` | [`f103`] | an STM32F103C8 "blue pill" (driver enable as a GPIO) |
//! | `board-f429` | [`f429`] (its Ethernet: `f429/ethernet.rs`) | ST NUCLEO-F429ZI (STM32F429ZI, driver enable as a GPIO, Ethernet: Modbus TCP) |
//!
//! A board module supplies the pins and peripherals ([`board`]), the clock tree, this chip's
//! part of a UART's settings, the reset cause, the settings' flash range and the board's name;
//! everything else in the firmware is the same for both.

#[cfg(feature = "board-f103")]
pub mod f103;
#[cfg(feature = "board-f429")]
pub mod f429;
#[cfg(feature = "board-l475")]
pub mod l475;

#[cfg(feature = "board-f103")]
pub use f103::{
    board, clock_config, reset_cause, uart_config, BUS_UART_HZ, LED_ON, MODEL_NAME, PLC_UART_HZ,
    SETTINGS_RANGE,
};
#[cfg(feature = "board-f429")]
pub use f429::{
    board, clock_config, reset_cause, uart_config, Ethernet, EthernetDevice, BUS_UART_HZ,
    DFU_RANGE, LED_ON, MODEL_NAME, PLC_UART_HZ, SETTINGS_RANGE, STATE_RANGE,
};
#[cfg(feature = "board-l475")]
pub use l475::{
    board, clock_config, reset_cause, uart_config, BUS_UART_HZ, LED_ON, MODEL_NAME, PLC_UART_HZ,
};
/// The emulator has no settings store.
#[cfg(all(feature = "board-l475", feature = "hw"))]
pub use l475::{DFU_RANGE, SETTINGS_RANGE, STATE_RANGE};

use embassy_stm32::gpio::{AnyPin, Input, Level, Output, Pin, Pull, Speed};
use embassy_stm32::usart;
use embassy_stm32::Peri;
use static_cell::ConstStaticCell;

use crate::discrete::opposite;
use crate::pins::{self, PinId};
use crate::serial::Rs485;

/// The bus starts at the rate every controller has after a break (complete edition §7-2-1); the
/// gateway task switches it to the node's rate at once.
pub const BUS_INITIAL_BAUD: u32 = protocol::line::BAUD_AFTER_BREAK.bits_per_second();
/// Level of an input pin while its signal is ON (the 24 V input stage is non-inverting).
pub const INPUT_ON: Level = Level::High;
/// Level of an output pin while its signal is ON (OFF, the safe state, is the other level).
pub const OUTPUT_ON: Level = Level::High;
/// The gateway task must make progress at least this often, or the IWDG resets the chip: its
/// loop passes every 100 ms at least, and no await in it lasts longer than a bus frame, a rate
/// change or a flash write (a PLC reply is left to the UART: `gateway`). The longest stretch
/// without a pet is one flash erase: an F429 16 KiB sector, 0.5 s at most (the erase feeds the
/// watchdog before each sector: `f429::SettingsSectors`), against the shortest timeout below,
/// 0.68 s on that chip: 0.18 s to spare (0.63 s on the F103, whose page erase takes 40 ms at
/// most; 0.91 s on the L475, 25 ms).
const WATCHDOG_TIMEOUT_US: u32 = 1_000_000;
/// The shortest time [`WATCHDOG_TIMEOUT_US`] may really be: the IWDG counts the LSI, which the
/// firmware takes for its nominal 40 kHz (F103) or 32 kHz (L4, F4); it runs at 30-60 kHz on the
/// F103 (datasheet), so the timeout is 0.67-1.33 s there (29.5-34 kHz on the L4: 0.94-1.08 s;
/// 17-47 kHz on the F429: 0.68-1.88 s). The emulator's model of the watchdog expires after this
/// ([`crate::emu::watchdog_start`]).
const WATCHDOG_SHORTEST_US: u32 = WATCHDOG_TIMEOUT_US / 60 * 40;

// UART ring buffers, in .bss. Each holds at least what the task writes or may leave unread at
// once: a 16-byte bus frame (the task takes a bus frame once it is whole: four fit), a Modbus RTU
// ADU (at most 256 bytes).
pub(crate) static BUS_TX: ConstStaticCell<[u8; BUS_TX_LEN]> = ConstStaticCell::new([0; BUS_TX_LEN]);
pub(crate) static BUS_RX: ConstStaticCell<[u8; 64]> = ConstStaticCell::new([0; 64]);
pub(crate) static PLC_TX: ConstStaticCell<[u8; PLC_TX_LEN]> = ConstStaticCell::new([0; PLC_TX_LEN]);
pub(crate) static PLC_RX: ConstStaticCell<[u8; 256]> = ConstStaticCell::new([0; 256]);
const BUS_TX_LEN: usize = 32;
const PLC_TX_LEN: usize = 256;
/// A frame is written whole into an empty TX ring (`Rs485::start_send`; the driver refuses a
/// longer one): the longest of each line fits.
const _: () = assert!(
    protocol::frame::FRAME_LEN <= BUS_TX_LEN && protocol::modbus::MAX_ADU_LEN <= PLC_TX_LEN
);

/// Everything the gateway task drives.
pub struct Board {
    /// The RS485 bus to the controllers.
    pub bus: Rs485,
    /// The RS485 line to the PLC (Modbus RTU).
    pub plc: Rs485,
    /// Fed by the gateway task's progress.
    pub watchdog: Watchdog,
    /// The flash for the settings store, taken by the gateway task.
    pub settings_flash: Option<SettingsFlash>,
    /// The Ethernet MAC and PHY, taken at start-up for the network stack once the stored
    /// settings (the address) are loaded.
    #[cfg(feature = "net")]
    pub ethernet: Option<Ethernet>,
}

/// The chip's flash, blocking.
#[cfg(feature = "hw")]
type Flash = embassy_stm32::flash::Flash<'static, embassy_stm32::flash::Blocking>;
/// The flash the settings store writes (blocking: `settings_store` runs each operation to its
/// end); on the L475 with its data cache off while it writes ([`l475::DcacheOff`]).
#[cfg(all(feature = "hw", feature = "board-l475"))]
pub type SettingsFlash = l475::DcacheOff<Flash>;
#[cfg(all(feature = "hw", feature = "board-f103"))]
pub type SettingsFlash = Flash;
/// On the F429, bank 2 (offsets from 0x0810_0000): its erase page is a 16 KiB sector of its first
/// region, where the whole flash's is the largest sector, 128 KiB (`memory/f429zi.x` says why the
/// small sectors), erased with the interrupts running; DFU's 128 KiB sectors in steps
/// ([`f429::SettingsSectors`]).
#[cfg(all(feature = "hw", feature = "board-f429"))]
pub type SettingsFlash = f429::SettingsSectors;
/// No flash interface in QEMU.
#[cfg(feature = "emulator")]
pub type SettingsFlash = core::convert::Infallible;

/// An RS485 line's UART settings: `baud`, 8 data bits, `parity`, one stop bit.
pub fn line_config(baud: u32, parity: protocol::plc::Parity) -> usart::Config {
    let mut config = usart::Config::default();
    config.baudrate = baud;
    config.parity = match parity {
        protocol::plc::Parity::None => usart::Parity::ParityNone,
        protocol::plc::Parity::Even => usart::Parity::ParityEven,
        protocol::plc::Parity::Odd => usart::Parity::ParityOdd,
    };
    // Wake the task for every byte: the protocol stamps arrival times (Modbus t3.5, §5 time-outs),
    // and QEMU never sets ISR.IDLE, which is the other wake-up.
    config.eager_reads = Some(1);
    // The transceiver's receiver output is off (high impedance) while its driver is on: /RE is
    // tied to DE, during every transmission and the break. Pulled up, RX idles at the mark
    // level then instead of floating into junk bytes and framing errors.
    config.rx_pull = Pull::Up;
    uart_config(&mut config);
    config
}

/// Whether a UART clocked at `kernel_hz` makes `baud` as embassy-stm32 0.6.0 programs it
/// (`usart::find_and_set_brr`): the divider `kernel_hz / baud`, rounded, 16 to 0xFFFF with
/// 16-times oversampling (BRR is 16 bits on both chips), within 1 % of the rate (Modbus and the
/// controllers tolerate about 2 %). Out of that range the driver refuses the rate, after it has
/// disabled the UART.
pub const fn divider_fits(kernel_hz: u32, baud: u32) -> bool {
    if baud == 0 {
        return false;
    }
    let divider = (kernel_hz + baud / 2) / baud;
    if divider < 16 || divider > 0xFFFF {
        return false;
    }
    let made = kernel_hz / divider;
    let error = made.abs_diff(baud);
    error * 100 <= baud
}

/// Every rate the PLC (PLCBAUD) or the bus (BUSBAUD, and the rate after a break) may ask of this
/// board's UARTs is one they can make: checked when the firmware is built, for the board it is
/// built for. (A rate the PLC saved and the UART refused would leave the line dead at every
/// start.)
const _: () = {
    let plc = protocol::plc::settings::PLC_BAUDS;
    let mut i = 0;
    while i < plc.len() {
        assert!(
            divider_fits(PLC_UART_HZ, plc[i]),
            "a PLC rate this board's UART cannot make"
        );
        i += 1;
    }
    let bus = protocol::line::Baud::ALL;
    let mut i = 0;
    while i < bus.len() {
        assert!(
            divider_fits(BUS_UART_HZ, bus[i].bits_per_second()),
            "a bus rate this board's UART cannot make"
        );
        i += 1;
    }
};

/// A UART's registers, read below the driver to confirm the end of a transmission.
#[derive(Clone, Copy)]
pub struct UartRegs(pub embassy_stm32::pac::usart::Usart);

impl UartRegs {
    /// The driver's interrupt has nothing left to do for a transmission: it stopped taking bytes
    /// from its ring (TXEIE off: the ring is empty) and has handled the transmission-complete
    /// interrupt of the last byte (TCIE off). The TC flag itself cannot tell: the driver clears
    /// it when it handles it.
    pub fn transmission_complete(&self) -> bool {
        let cr1 = self.0.cr1().read();
        !cr1.txeie() && !cr1.tcie()
    }
}

// The pin helpers below take any pin and set it up in one function for all (`AnyPin`): the
// board sets up 30 pins, and one copy of each set-up per pin type cost about 1 KB of flash.

/// A PIO output, OFF, registered to be forced OFF on a fault.
pub(crate) fn output(pin: Peri<'static, impl Pin>) -> Output<'static> {
    let off = opposite(OUTPUT_ON);
    fault_driven(pin.into(), off, off, Speed::Low)
}

/// An LED, off, and off on a fault.
pub(crate) fn led(pin: Peri<'static, impl Pin>) -> Output<'static> {
    let off = opposite(LED_ON);
    fault_driven(pin.into(), off, off, Speed::Low)
}

/// An LED, off, that a fault turns on (the alarm LED).
pub(crate) fn indicator_on_fault(pin: Peri<'static, impl Pin>) -> Output<'static> {
    fault_driven(pin.into(), opposite(LED_ON), LED_ON, Speed::Low)
}

/// A driver-enable pin driven by software (a board without hardware DE), off, and off on a fault.
#[cfg_attr(feature = "board-l475", allow(dead_code))]
pub(crate) fn driver_enable(pin: Peri<'static, impl Pin>) -> Output<'static> {
    fault_driven(pin.into(), Level::Low, Level::Low, Speed::VeryHigh)
}

/// An output at `initial`, registered to be driven to `on_fault` on a fault.
#[inline(never)]
fn fault_driven(
    pin: Peri<'static, AnyPin>,
    initial: Level,
    on_fault: Level,
    speed: Speed,
) -> Output<'static> {
    pins::on_fault_drive(PinId::of(&*pin), on_fault == Level::High);
    Output::new(pin, initial, speed)
}

/// A PIO input, pulled toward OFF so that an open wire reads OFF (and the stop input "stop").
pub(crate) fn input(pin: Peri<'static, impl Pin>) -> Input<'static> {
    pulled_off(pin.into())
}

#[inline(never)]
fn pulled_off(pin: Peri<'static, AnyPin>) -> Input<'static> {
    let pull = match INPUT_ON {
        Level::High => Pull::Down,
        Level::Low => Pull::Up,
    };
    Input::new(pin, pull)
}

#[cfg(feature = "hw")]
pub(crate) fn settings_flash(
    flash: Peri<'static, embassy_stm32::peripherals::FLASH>,
) -> Option<SettingsFlash> {
    let flash = Flash::new_blocking(flash);
    #[cfg(feature = "board-l475")]
    let flash = l475::DcacheOff(flash);
    #[cfg(feature = "board-f429")]
    let flash = f429::SettingsSectors::new(flash);
    Some(flash)
}

#[cfg(feature = "emulator")]
pub(crate) fn settings_flash(
    _flash: Peri<'static, embassy_stm32::peripherals::FLASH>,
) -> Option<SettingsFlash> {
    None
}

/// The independent watchdog on the board; in the emulator (QEMU has no IWDG model) a model of
/// it on the SysTick interrupt ([`crate::emu::watchdog_start`]), with the shortest timeout the
/// board's may have.
///
/// On the board the IWDG runs from [`start_watchdog`], before the clocks and the PHY are brought
/// up: every wait there that is not bounded by the firmware itself (embassy-stm32's, for a clock
/// that never becomes ready) ends in a reset instead of a hang. This object only feeds it.
pub struct Watchdog {
    _private: (),
}

impl Watchdog {
    /// The watchdog, fed once: on the board it runs already ([`start_watchdog`]); the emulator's
    /// model starts here.
    pub(crate) fn new(_iwdg: Peri<'static, embassy_stm32::peripherals::IWDG>) -> Watchdog {
        #[cfg(feature = "hw")]
        pet_watchdog();
        crate::emu::watchdog_start(WATCHDOG_SHORTEST_US);
        Watchdog { _private: () }
    }

    /// The gateway task made progress.
    pub fn pet(&mut self) {
        #[cfg(feature = "hw")]
        pet_watchdog();
        crate::emu::watchdog_pet();
    }
}

/// The IWDG's prescaler: the LSI divided by 16 (PR = 2), 0.5 ms a count at the nominal 32 kHz.
#[cfg(feature = "hw")]
const WATCHDOG_PRESCALER: u32 = 16;
/// The IWDG's reload value for [`WATCHDOG_TIMEOUT_US`] at the LSI's nominal rate (embassy-stm32's
/// `LSI_FREQ`: 40 kHz on the F103, 32 kHz on the L4 and F4): 2,499 and 1,999, inside the 12-bit
/// counter.
#[cfg(feature = "hw")]
const WATCHDOG_RELOAD: u16 = {
    let counts =
        embassy_stm32::rcc::LSI_FREQ.0 / WATCHDOG_PRESCALER * (WATCHDOG_TIMEOUT_US / 1000) / 1000;
    assert!(counts >= 1 && counts <= 0x1000);
    (counts - 1) as u16
};

/// Starts the IWDG at [`WATCHDOG_TIMEOUT_US`], first thing at start-up (before
/// `embassy_stm32::init`): from here on a clock, PHY or peripheral that never becomes ready
/// resets the chip within the timeout instead of hanging it with the RS485 side dead. The
/// registers directly (the HAL's driver needs the peripherals `init` returns); the IWDG needs no
/// clock enable (it starts the LSI itself). Its prescaler and reload take effect within a few LSI
/// periods; until then the reset values (LSI / 4, 4,096 counts: 0.27 s at the fastest LSI, the
/// F103's) apply, far longer than that.
#[cfg(feature = "hw")]
pub fn start_watchdog() {
    use embassy_stm32::pac::iwdg::vals::{Key, Pr};
    freeze_watchdog_while_halted();
    let iwdg = embassy_stm32::pac::IWDG;
    iwdg.kr().write(|w| w.set_key(Key::START));
    iwdg.kr().write(|w| w.set_key(Key::ENABLE));
    const _: () = assert!(WATCHDOG_PRESCALER == 16);
    iwdg.pr().write(|w| w.set_pr(Pr::from_bits(2)));
    iwdg.rlr().write(|w| w.set_rl(WATCHDOG_RELOAD));
    pet_watchdog();
}

/// Reloads the IWDG's counter (its key register: no state, so any code that waits long on
/// purpose, such as the F429's sector erase, may feed it between steps).
#[cfg(feature = "hw")]
pub fn pet_watchdog() {
    embassy_stm32::pac::IWDG
        .kr()
        .write(|w| w.set_key(embassy_stm32::pac::iwdg::vals::Key::RESET));
}

/// The IWDG stops counting while a debug probe halts the core (DBGMCU, DBG_IWDG_STOP), so that a
/// breakpoint, or the state after a panic (`udf`, where `probe-rs run` stops), can be inspected
/// instead of being reset within a second. The bit acts only while a debugger holds the core
/// halted; without a probe nothing halts the core, so it is set in every build. It survives a
/// system reset (only a power-on reset clears DBGMCU).
#[cfg(feature = "hw")]
fn freeze_watchdog_while_halted() {
    #[cfg(feature = "board-f103")]
    embassy_stm32::pac::DBGMCU.cr().modify(|w| w.set_iwdg(true));
    #[cfg(feature = "board-f429")]
    embassy_stm32::pac::DBGMCU
        .apb1fzr()
        .modify(|w| w.set_iwdg(true));
    #[cfg(feature = "board-l475")]
    embassy_stm32::pac::DBGMCU
        .apb1fzr1()
        .modify(|w| w.set_iwdg(true));
}
