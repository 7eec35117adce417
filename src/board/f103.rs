//! # STM32F103C8 "blue pill" (64 KiB flash, 20 KiB RAM, 8 MHz crystal)
//!
//! The common small board, and the hardest budget. Its USARTs (v1) have no hardware driver
//! enable: DE is a GPIO that [`Rs485`](crate::serial::Rs485) sets before a write and clears once
//! the last stop bit has left (`flush`, transmission complete). JTAG is turned off (SWD stays)
//! to free PA15, PB3 and PB4.
//!
//! | Signal | Pin | Notes |
//! |---|---|---|
//! | RS485 **bus** TX / RX / DE | PA2 / PA3 / PA1 | USART2 (36 MHz APB1); DE a GPIO, active high |
//! | RS485 **PLC** TX / RX / DE | PA9 / PA10 / PA8 | USART1 (72 MHz APB2); DE a GPIO, active high |
//! | IN0-IN3 PC1 PC2 PC4 PC8 | PB12 PB13 PB14 PB15 | inputs: high = ON, pull-down (open = OFF) |
//! | IN4, IN5 PC16 PC32 | PB4, PA15 | JTAG pins (pulled up only during reset, when no input is read) |
//! | IN11 HOME, IN12 *STP | PB10, PB11 | |
//! | IN13 CSTR, IN14 RES, IN15 SON | PB0, PB1, PA0 | |
//! | Stop input | PA4 | safety: the stop is active while the input is OFF (open wire = stop) |
//! | OUT0-OUT3 PM1 PM2 PM4 PM8 | PB5 PB6 PB7 PB8 | outputs: high = ON; every output low after reset, panic, HardFault |
//! | OUT6 MOVE, OUT7 ZONE1 | PB9, PA5 | |
//! | OUT10 HEND, OUT11 PEND, OUT12 SV | PA6, PA7, PB3 | |
//! | OUT13 LINK, OUT14 *ALM | PA11, PB2 | PA11 is USB D- (no pull-up); PB2 is BOOT1 (100 kΩ to the BOOT1 jumper: leave it at 0) |
//! | LED run / bus link / alarm | PC13 (on board) / PC14 / PC15 | lit **low** (the pin sinks): PC13-PC15 must not source current; LED from 3.3 V through 1 kΩ |
//! | (unused) | PA12 | USB D+: the board's 1.5 kΩ pull-up (R10) beats any internal pull-down, so it carries no signal |
//!
//! **Pins during reset.** Until the firmware drives them, every pin is a floating input, except
//! the JTAG pins PA15 and PB4 (pulled up) and PB3 (JTDO, floating): no output or driver enable is
//! on a JTAG pin, so a pull-down on each output stage's input and on each transceiver's DE (10 kΩ)
//! keeps every output OFF and both drivers off from power-up, while a probe holds the core in
//! reset, and until start-up drives them. (Before: OUT13 and OUT14 were on PB4 and PA15 and read ON
//! through every reset; IN5 on PA12 read ON with the input open and refused every CSTR.) While a
//! probe halts a running core, the pins keep their state: a DE that was on stays on.

use embassy_stm32::exti::{self, ExtiInput};
use embassy_stm32::peripherals::{USART1, USART2};
use embassy_stm32::usart::{self, BufferedInterruptHandler, BufferedUart, ConfigError};
use embassy_stm32::{bind_interrupts, interrupt, Peripherals};

use super::{
    driver_enable, indicator_on_fault, input, led, line_config, output, settings_flash, Board,
    UartRegs, Watchdog, BUS_RX, BUS_TX, INPUT_ON, OUTPUT_ON, PLC_RX, PLC_TX,
};
use crate::discrete::{Inputs, Leds, Outputs};
use crate::io::Pins;
use crate::pins::{LineBreak, PinId};
use crate::serial::Rs485;

/// The board, as the gateway names it to the PLC (device identification).
pub const MODEL_NAME: &str = "STM32F103C8";
/// System clock: the 8 MHz crystal through the PLL, the F103's maximum.
const SYSCLK_HZ: u32 = 72_000_000;
/// The bus UART's (USART2's) kernel clock: PCLK1, the system clock halved.
pub const BUS_UART_HZ: u32 = SYSCLK_HZ / 2;
/// The PLC UART's (USART1's) kernel clock: PCLK2, the system clock.
pub const PLC_UART_HZ: u32 = SYSCLK_HZ;
/// The LEDs are lit by a low level: PC13-PC15 may sink 3 mA but must not source current
/// (datasheet, "Pin definitions" note), and the board's own PC13 LED hangs from 3.3 V.
pub const LED_ON: embassy_stm32::gpio::Level = embassy_stm32::gpio::Level::Low;

/// The flash pages `memory/f103c8.x` keeps out of the program for the settings: the last four
/// 1 KiB pages (offsets from the start of flash).
pub const SETTINGS_RANGE: core::ops::Range<u32> = 0x0000_F000..0x0001_0000;

bind_interrupts!(struct Irqs {
    USART1 => BufferedInterruptHandler<USART1>;
    USART2 => BufferedInterruptHandler<USART2>;
    EXTI4 => exti::InterruptHandler<interrupt::typelevel::EXTI4>;
});

/// The clock tree of [`SYSCLK_HZ`]: HSE 8 MHz x 9, APB1 at 36 MHz (its maximum).
pub fn clock_config() -> embassy_stm32::Config {
    use embassy_stm32::rcc::{
        APBPrescaler, Hse, HseMode, Pll, PllMul, PllPreDiv, PllSource, Sysclk,
    };
    let mut config = embassy_stm32::Config::default();
    const HSE_HZ: u32 = 8_000_000;
    const _: () = assert!(HSE_HZ * 9 == SYSCLK_HZ);
    config.rcc.hse = Some(Hse {
        freq: embassy_stm32::time::Hertz(HSE_HZ),
        mode: HseMode::Oscillator,
    });
    config.rcc.pll = Some(Pll {
        src: PllSource::HSE,
        prediv: PllPreDiv::DIV1,
        mul: PllMul::MUL9,
    });
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.apb1_pre = APBPrescaler::DIV2;
    // PA15, PB3 and PB4 are outputs here: JTAG off, SWD (the debug probe) on.
    config.swj = embassy_stm32::gpio::SwjCfg::SwdOnly;
    config
}

/// This chip's part of a UART's settings: nothing (DE is a GPIO).
pub fn uart_config(_config: &mut usart::Config) {}

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
    } else if csr.porrstf() {
        ResetCause::PowerOn
    } else if csr.pinrstf() {
        ResetCause::Pin
    } else if csr.lpwrrstf() {
        ResetCause::Other
    } else {
        ResetCause::PowerOn
    };
    rcc.csr().modify(|w| w.set_rmvf(true));
    cause
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
            (0, output(p.PB5)),
            (1, output(p.PB6)),
            (2, output(p.PB7)),
            (3, output(p.PB8)),
            (6, output(p.PB9)),
            (7, output(p.PA5)),
            (10, output(p.PA6)),
            (11, output(p.PA7)),
            (12, output(p.PB3)),
            (13, output(p.PA11)),
            (14, output(p.PB2)),
        ],
        OUTPUT_ON,
    );
    let bus_de = driver_enable(p.PA1);
    let plc_de = driver_enable(p.PA8);
    let leds = Leds::new(led(p.PC13), led(p.PC14), indicator_on_fault(p.PC15), LED_ON);
    let inputs = Inputs::new(
        [
            (0, input(p.PB12)),
            (1, input(p.PB13)),
            (2, input(p.PB14)),
            (3, input(p.PB15)),
            (4, input(p.PB4)),
            (5, input(p.PA15)),
            (11, input(p.PB10)),
            (12, input(p.PB11)),
            (13, input(p.PB0)),
            (14, input(p.PB1)),
            (15, input(p.PA0)),
        ],
        ExtiInput::from_input(input(p.PA4), p.EXTI4, Irqs),
        INPUT_ON,
    );

    let line_break = LineBreak::new(PinId::of(&*p.PA2), None);
    let bus = BufferedUart::new(
        p.USART2,
        p.PA3,
        p.PA2,
        BUS_TX.take(),
        BUS_RX.take(),
        Irqs,
        line_config(super::BUS_INITIAL_BAUD, protocol::plc::Parity::None),
    )?;
    let plc = BufferedUart::new(
        p.USART1,
        p.PA10,
        p.PA9,
        PLC_TX.take(),
        PLC_RX.take(),
        Irqs,
        line_config(plc_line.baud.bits_per_second(), plc_line.parity),
    )?;

    let board = Board {
        bus: Rs485::new(
            bus,
            UartRegs(embassy_stm32::pac::USART2),
            (super::BUS_INITIAL_BAUD, protocol::plc::Parity::None),
            Some(line_break),
            Some(bus_de),
        ),
        plc: Rs485::new(
            plc,
            UartRegs(embassy_stm32::pac::USART1),
            (plc_line.baud.bits_per_second(), plc_line.parity),
            None,
            Some(plc_de),
        ),
        watchdog: Watchdog::new(p.IWDG),
        settings_flash: settings_flash(p.FLASH),
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
