//! Every board-specific choice, and nothing else: clocks, which USART is which line, which pin is
//! which signal, pin polarities. A second board (e.g. an STM32F103C8 with DE as a GPIO) gets a
//! module of its own with the same items; the rest of the firmware does not change.
//!
//! # B-L475E-IOT01A (STM32L475VG)
//!
//! Header names from ST's UM2153 (Arduino Uno V3 connectors CN1-CN4, PMOD connector CN10).
//!
//! | Signal | Pin | Header | Notes |
//! |---|---|---|---|
//! | RS485 **bus** TX | PA0 | Arduino D1 | UART4 (QEMU `-serial` #3) |
//! | RS485 bus RX | PA1 | Arduino D0 | |
//! | RS485 bus DE | PA15 | Arduino D9 | hardware driver enable (CR3.DEM), active high |
//! | RS485 **PLC** TX | PD5 | PMOD CN10 (UART) | USART2 (QEMU `-serial` #1) |
//! | RS485 PLC RX | PD6 | PMOD CN10 | |
//! | RS485 PLC DE | PD4 | PMOD CN10 (RTS) | hardware driver enable, active high |
//! | IN0 PC1 | PC5 | Arduino A0 | inputs: high = ON, pull-down (open = OFF) |
//! | IN1 PC2 | PC4 | Arduino A1 | |
//! | IN2 PC4 | PC3 | Arduino A2 | |
//! | IN3 PC8 | PC2 | Arduino A3 | |
//! | IN4 PC16 | PC1 | Arduino A4 | |
//! | IN5 PC32 | PC0 | Arduino A5 | |
//! | IN11 HOME | PD14 | Arduino D2 | |
//! | IN12 *STP | PB0 | Arduino D3 | |
//! | IN13 CSTR | PA3 | Arduino D4 | |
//! | IN14 RES | PB4 | Arduino D5 | |
//! | IN15 SON | PB1 | Arduino D6 | |
//! | Stop input | PA4 | Arduino D7 | safety: the stop is active while the input is OFF (open wire = stop) |
//! | OUT0 PM1 | PB2 | Arduino D8 | outputs: high = ON; every output low after reset, panic, HardFault |
//! | OUT1 PM2 | PA2 | Arduino D10 | |
//! | OUT2 PM4 | PA7 | Arduino D11 | |
//! | OUT3 PM8 | PA6 | Arduino D12 | |
//! | OUT6 MOVE | PB9 | Arduino D14 | |
//! | OUT7 ZONE1 | PB8 | Arduino D15 | |
//! | OUT10 HEND | PD0 | PMOD CN10 | the PMOD pins beside the UART: check UM2153's solder bridges |
//! | OUT11 PEND | PD1 | PMOD CN10 | |
//! | OUT12 SV | PD2 | PMOD CN10 | |
//! | OUT13 LINK | PD7 | PMOD CN10 | |
//! | OUT14 *ALM | PD3 | PMOD CN10 (CTS) | |
//! | LED run | PB14 | LED2 (green) | blinks 1 Hz while the gateway task runs |
//! | LED bus link | PA5 | LED1 (green), Arduino D13 | |
//! | LED alarm | PC9 | LED3 (yellow) | PC9 low lights LED4 (blue) instead |
//!
//! The 24 V input and output stages (opto-couplers, high-side drivers) are not on this board: the
//! table assumes non-inverting stages (3.3 V high = signal ON), hence `INPUT_ON` / `OUTPUT_ON`.
//!
//! # Emulator
//! QEMU's `b-l475e-iot01a` connects `-serial` #0..#4 to USART1, USART2, USART3, UART4, UART5
//! (#1 and #3 are proven by the emulator tests). The harness gives #1 (PLC) and #3 (bus) host
//! endpoints and `null` to the others; it drives
//! input pins with qtest `set_irq_in /machine/soc/gpioX unnamed-gpio-in N level` and reads
//! outputs from the GPIO registers. QEMU ignores DE (CR3.DEM) and does not wire USART TX to
//! its GPIO pin, so a break shows only as the pins' mode and output registers.

use embassy_stm32::gpio::{Input, Level, Output, Pin, Pull, Speed};
use embassy_stm32::peripherals::{UART4, USART2};
use embassy_stm32::usart::{self, BufferedInterruptHandler, BufferedUart, ConfigError};
use embassy_stm32::{bind_interrupts, Peri, Peripherals};
use static_cell::ConstStaticCell;

use crate::discrete::{opposite, Inputs, Leds, Outputs};
use crate::pins::{self, LineBreak, PinId};
use crate::serial::Rs485;

/// The flash pages `memory.x` keeps out of the program for the settings: the last four 2 KiB
/// pages of bank 2 (offsets from the start of flash). Erasing them does not stall the program,
/// which runs from bank 1.
#[cfg_attr(feature = "emulator", allow(dead_code))]
pub const SETTINGS_RANGE: core::ops::Range<u32> = 0x000F_E000..0x0010_0000;

/// The flash the settings store writes, as sequential-storage wants it (async over blocking).
#[cfg(feature = "hw")]
pub type SettingsFlash = embassy_embedded_hal::adapter::BlockingAsync<
    embassy_stm32::flash::Flash<'static, embassy_stm32::flash::Blocking>,
>;
/// No flash interface in QEMU.
#[cfg(feature = "emulator")]
pub type SettingsFlash = core::convert::Infallible;

/// Why the chip last started, from RCC_CSR's reset flags, which are then cleared so that the
/// next start reads its own.
pub fn reset_cause() -> protocol::plc::ResetCause {
    use protocol::plc::ResetCause;
    let rcc = embassy_stm32::pac::RCC;
    let csr = rcc.csr().read();
    let cause = if csr.iwdgrstf() || csr.wwdgrstf() {
        ResetCause::Watchdog
    } else if csr.sftrstf() {
        ResetCause::Software
    } else if csr.borrstf() {
        ResetCause::PowerOn
    } else if csr.pinrstf() {
        ResetCause::Pin
    } else if csr.lpwrrstf() || csr.oblrstf() || csr.fwrstf() {
        ResetCause::Other
    } else {
        ResetCause::PowerOn
    };
    rcc.csr().modify(|w| w.set_rmvf(true));
    cause
}

/// The board, as the gateway names it to the PLC (device identification).
pub const MODEL_NAME: &str = "B-L475E-IOT01A (STM32L475VG)";
/// System clock: HSI16 through the PLL (no crystal needed), the STM32L475's maximum.
pub const SYSCLK_HZ: u32 = 80_000_000;
/// The bus starts at the rate every controller has after a break (complete edition §7-2-1).
pub const BUS_INITIAL_BAUD: u32 = protocol::line::BAUD_AFTER_BREAK.bits_per_second();
/// Driver-enable lead and lag, in sample times (1/16 bit): half a bit either side of the
/// characters, ample for RS485 transceivers (enable times of a few hundred ns). Assertion and
/// de-assertion are equal because embassy-stm32 0.6.0 programs DEDT from the assertion time.
const DE_TIME: u8 = 8;
/// Level of an input pin while its signal is ON.
const INPUT_ON: Level = Level::High;
/// Level of an output pin while its signal is ON (OFF, the safe state, is the other level).
const OUTPUT_ON: Level = Level::High;
/// The gateway task must make progress at least this often, or the IWDG resets the chip.
/// Generous: a 256-byte reply at 9.6 kbit/s keeps the task in one `await` for 267 ms.
#[cfg(feature = "hw")]
const WATCHDOG_TIMEOUT_US: u32 = 1_000_000;

bind_interrupts!(struct Irqs {
    UART4 => BufferedInterruptHandler<UART4>;
    USART2 => BufferedInterruptHandler<USART2>;
});

// UART ring buffers, in .bss. Each holds at least what the task writes or may leave unread at
// once: a 16-byte bus frame, a Modbus RTU ADU (at most 256 bytes).
static BUS_TX: ConstStaticCell<[u8; 32]> = ConstStaticCell::new([0; 32]);
static BUS_RX: ConstStaticCell<[u8; 128]> = ConstStaticCell::new([0; 128]);
static PLC_TX: ConstStaticCell<[u8; 256]> = ConstStaticCell::new([0; 256]);
static PLC_RX: ConstStaticCell<[u8; 256]> = ConstStaticCell::new([0; 256]);

/// Everything the gateway task drives.
pub struct Board {
    /// The RS485 bus to the controllers.
    pub bus: Rs485,
    /// The RS485 line to the PLC (Modbus RTU).
    pub plc: Rs485,
    /// The PIO inputs and the stop input.
    pub inputs: Inputs,
    /// The PIO outputs.
    pub outputs: Outputs,
    /// Run, bus link and alarm LEDs.
    pub leds: Leds,
    /// Fed by the gateway task's progress.
    pub watchdog: Watchdog,
    /// The flash for the settings store, taken by the gateway task.
    pub settings_flash: Option<SettingsFlash>,
}

/// The clock tree of [`SYSCLK_HZ`].
pub fn clock_config() -> embassy_stm32::Config {
    use embassy_stm32::rcc::{Pll, PllMul, PllPreDiv, PllRDiv, PllSource, Sysclk};
    let mut config = embassy_stm32::Config::default();
    config.rcc.hsi = true;
    // HSI16 / 1 (DIVM) * 10 (N) / 2 (R) = 80 MHz (VCO 160 MHz).
    const _: () = assert!(16_000_000 * 10 / 2 == SYSCLK_HZ);
    config.rcc.pll = Some(Pll {
        source: PllSource::HSI,
        prediv: PllPreDiv::DIV1,
        mul: PllMul::MUL10,
        divp: None,
        divq: None,
        divr: Some(PllRDiv::DIV2),
    });
    config.rcc.sys = Sysclk::PLL1_R;
    config
}

impl Board {
    /// Takes the peripherals this board uses. Fails only if a UART rejects its configuration.
    pub fn new(p: Peripherals, plc_line: protocol::plc::PlcLine) -> Result<Board, ConfigError> {
        // Outputs first, driven OFF, so that nothing is ever ON before the gateway says so.
        let outputs = Outputs::new(
            [
                (0, output(p.PB2)),
                (1, output(p.PA2)),
                (2, output(p.PA7)),
                (3, output(p.PA6)),
                (6, output(p.PB9)),
                (7, output(p.PB8)),
                (10, output(p.PD0)),
                (11, output(p.PD1)),
                (12, output(p.PD2)),
                (13, output(p.PD7)),
                (14, output(p.PD3)),
            ],
            OUTPUT_ON,
        );
        let leds = Leds::new(output(p.PB14), output(p.PA5), indicator_on_fault(p.PC9));
        let inputs = Inputs::new(
            [
                (0, input(p.PC5)),
                (1, input(p.PC4)),
                (2, input(p.PC3)),
                (3, input(p.PC2)),
                (4, input(p.PC1)),
                (5, input(p.PC0)),
                (11, input(p.PD14)),
                (12, input(p.PB0)),
                (13, input(p.PA3)),
                (14, input(p.PB4)),
                (15, input(p.PB1)),
            ],
            input(p.PA4),
            INPUT_ON,
        );

        let line_break = LineBreak::new(PinId::of(&*p.PA0), PinId::of(&*p.PA15));
        pins::on_fault_release(PinId::of(&*p.PA15));
        let bus = BufferedUart::new_with_de(
            p.UART4,
            p.PA1,
            p.PA0,
            p.PA15,
            Irqs,
            BUS_TX.take(),
            BUS_RX.take(),
            rs485_config(BUS_INITIAL_BAUD),
        )?;
        pins::on_fault_release(PinId::of(&*p.PD4));
        let plc = BufferedUart::new_with_de(
            p.USART2,
            p.PD6,
            p.PD5,
            p.PD4,
            Irqs,
            PLC_TX.take(),
            PLC_RX.take(),
            line_config(plc_line.baud, plc_line.parity),
        )?;

        Ok(Board {
            bus: Rs485::new(bus, BUS_TX_CAPACITY, Some(line_break)),
            plc: Rs485::new(plc, PLC_TX_CAPACITY, None),
            inputs,
            outputs,
            leds,
            watchdog: Watchdog::new(p.IWDG),
            settings_flash: settings_flash(p.FLASH),
        })
    }
}

const BUS_TX_CAPACITY: usize = 32;
const PLC_TX_CAPACITY: usize = 256;

/// An RS485 line's UART settings: `baud`, 8 data bits, `parity`, one stop bit.
pub fn line_config(baud: u32, parity: protocol::plc::Parity) -> usart::Config {
    let mut config = rs485_config(baud);
    config.parity = match parity {
        protocol::plc::Parity::None => usart::Parity::ParityNone,
        protocol::plc::Parity::Even => usart::Parity::ParityEven,
        protocol::plc::Parity::Odd => usart::Parity::ParityOdd,
    };
    config
}

fn rs485_config(baud: u32) -> usart::Config {
    let mut config = usart::Config::default();
    config.baudrate = baud;
    // Wake the task for every byte: the protocol stamps arrival times (Modbus t3.5, §5 time-outs),
    // and QEMU never sets ISR.IDLE, which is the other wake-up.
    config.eager_reads = Some(1);
    config.de_assertion_time = DE_TIME;
    config.de_deassertion_time = DE_TIME;
    config
}

/// A PIO output, OFF, registered to be forced OFF on a fault.
fn output(pin: Peri<'static, impl Pin>) -> Output<'static> {
    pins::on_fault_drive(PinId::of(&*pin), OUTPUT_ON == Level::Low);
    Output::new(pin, opposite(OUTPUT_ON), Speed::Low)
}

/// An LED that a fault turns on (the alarm LED).
fn indicator_on_fault(pin: Peri<'static, impl Pin>) -> Output<'static> {
    pins::on_fault_drive(PinId::of(&*pin), true);
    Output::new(pin, Level::Low, Speed::Low)
}

fn input(pin: Peri<'static, impl Pin>) -> Input<'static> {
    // Pull toward OFF, so that an open wire reads OFF (and the stop input reads "stop").
    let pull = match INPUT_ON {
        Level::High => Pull::Down,
        Level::Low => Pull::Up,
    };
    Input::new(pin, pull)
}

#[cfg(feature = "hw")]
fn settings_flash(
    flash: Peri<'static, embassy_stm32::peripherals::FLASH>,
) -> Option<SettingsFlash> {
    Some(embassy_embedded_hal::adapter::BlockingAsync::new(
        embassy_stm32::flash::Flash::new_blocking(flash),
    ))
}

#[cfg(feature = "emulator")]
fn settings_flash(
    _flash: Peri<'static, embassy_stm32::peripherals::FLASH>,
) -> Option<SettingsFlash> {
    None
}

/// The independent watchdog on the board; nothing in the emulator (QEMU has no IWDG model).
pub struct Watchdog {
    #[cfg(feature = "hw")]
    iwdg: embassy_stm32::wdg::IndependentWatchdog<'static, embassy_stm32::peripherals::IWDG>,
}

impl Watchdog {
    #[cfg(feature = "hw")]
    fn new(iwdg: Peri<'static, embassy_stm32::peripherals::IWDG>) -> Watchdog {
        let mut iwdg = embassy_stm32::wdg::IndependentWatchdog::new(iwdg, WATCHDOG_TIMEOUT_US);
        iwdg.unleash();
        Watchdog { iwdg }
    }

    #[cfg(feature = "emulator")]
    fn new(_iwdg: Peri<'static, embassy_stm32::peripherals::IWDG>) -> Watchdog {
        Watchdog {}
    }

    /// The gateway task made progress.
    pub fn pet(&mut self) {
        #[cfg(feature = "hw")]
        self.iwdg.pet();
    }
}
