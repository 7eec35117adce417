//! # B-L475E-IOT01A (STM32L475VG): the board QEMU emulates
//!
//! Header names from ST's UM2153 (Arduino Uno V3 connectors CN1-CN4, PMOD connector CN10).
//!
//! | Signal | Pin | Header | Notes |
//! |---|---|---|---|
//! | RS485 **bus** TX | PA0 | Arduino D1 | UART4 (QEMU `-serial` #3) |
//! | RS485 bus RX | PA1 | Arduino D0 | |
//! | RS485 bus DE | PA15 | Arduino D9 | hardware driver enable (CR3.DEM), active high; **pull down externally** (≤ 4.7 kΩ): PA15 is JTDI, pulled up during reset |
//! | RS485 **PLC** TX | PD5 | PMOD CN10 (UART) | USART2 (QEMU `-serial` #1), clocked by HSI16 |
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
//! | LED run | PB14 | LED2 (green) | blinks 1 Hz while the gateway task runs; LEDs lit high |
//! | LED bus link | PA5 | LED1 (green), Arduino D13 | |
//! | LED alarm | PC9 | LED3 (yellow) | PC9 low lights LED4 (blue) instead |
//!
//! The 24 V input and output stages (opto-couplers, high-side drivers) are not on this board: the
//! table assumes non-inverting stages (3.3 V high = signal ON), hence `INPUT_ON` / `OUTPUT_ON`.
//!
//! **From reset until the firmware drives them**, every pin of the table is high-impedance (analog
//! mode on the L4), except PA15 and PB4, which are JTAG pins with internal pull-ups (30-50 kΩ)
//! until the firmware takes them: each output stage and the bus transceiver's DE need a pull-down
//! on the carrier (10 kΩ on an output stage's input; ≤ 4.7 kΩ on PA15, which then stays below
//! 0.6 V against the pull-up), or an output and the bus driver would be ON during reset.
//! PB4 is an input (RES): its pull-up during reset does nothing. The same holds while a debug
//! probe holds the core in reset; while a probe halts a running core, the pins keep their last
//! state (the hardware DE still drops at the end of a character).
//!
//! # Emulator
//! QEMU's `b-l475e-iot01a` connects `-serial` #0..#4 to USART1, USART2, USART3, UART4, UART5
//! (#1 and #3 are proven by the emulator tests). The harness gives #1 (PLC) and #3 (bus) host
//! endpoints and `null` to the others; it drives
//! input pins with qtest `set_irq_in /machine/soc/gpioX unnamed-gpio-in N level` and reads
//! outputs from the GPIO registers. QEMU ignores DE (CR3.DEM) and does not wire USART TX to
//! its GPIO pin, so a break shows only as the pins' mode and output registers.
//!
//! The table's 30 signals take every pin of the board's Arduino and PMOD connectors, so the
//! ports PIO patterns 4 and 1 add to pattern 0's (IN6-IN9, OUT4, OUT5, OUT9) have no pin on
//! this board: it runs patterns 0 and 5, and refuses PIOPAT 4 and 1 (exception 03). The emulator
//! build puts them on port E (IN6-IN9 on PE7-PE10, OUT4 PE11, OUT5 PE12, OUT9 PE13: pins the
//! board routes to no connector) so that the emulator suite runs those patterns on the real
//! firmware; a board with those terminals adds them to its table the same way.

#[cfg(feature = "hw")]
use core::sync::atomic::{AtomicU32, Ordering};

use embassy_stm32::exti::{self, ExtiInput};
use embassy_stm32::peripherals::{UART4, USART2};
use embassy_stm32::usart::{self, BufferedInterruptHandler, BufferedUart, ConfigError};
use embassy_stm32::{bind_interrupts, interrupt, Peripherals};

use super::{
    indicator_on_fault, input, led, line_config, output, settings_flash, Board, UartRegs, Watchdog,
    BUS_RX, BUS_TX, INPUT_ON, OUTPUT_ON, PLC_RX, PLC_TX,
};
use crate::discrete::{Inputs, Leds, Outputs};
use crate::io::Pins;
use crate::pins::{self, LineBreak, PinId};
use crate::serial::Rs485;
#[cfg(feature = "hw")]
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// The board, as the gateway names it to the PLC (device identification).
pub const MODEL_NAME: &str = "B-L475E-IOT01A (STM32L475VG)";
/// System clock: HSI16 through the PLL (no crystal needed), the STM32L475's maximum.
pub const SYSCLK_HZ: u32 = 80_000_000;
/// The bus UART's (UART4's) kernel clock: PCLK1, the system clock (APB1 not divided).
pub const BUS_UART_HZ: u32 = SYSCLK_HZ;
/// The PLC UART's (USART2's) kernel clock: HSI16, not PCLK1. At 80 MHz the divider for
/// 1.2 kbit/s (66,667) is over the 16-bit BRR, and the driver refuses the rate after it has
/// disabled the UART: the PLC line went dead until a factory reset. From 16 MHz every PLCBAUD
/// fits (13,333 at 1.2 kbit/s, 139 at 115.2 kbit/s: 0.08 % fast).
pub const PLC_UART_HZ: u32 = 16_000_000;
/// The LEDs are lit by a high level (the board's LED drivers).
pub const LED_ON: embassy_stm32::gpio::Level = embassy_stm32::gpio::Level::High;

/// The flash pages `memory/l475vg.x` keeps out of the program for the settings: the last four 2 KiB
/// pages of bank 2 (offsets from the start of flash). Erasing them does not stall the program,
/// which runs from bank 1.
#[cfg(feature = "hw")]
pub const SETTINGS_RANGE: core::ops::Range<u32> = 0x000F_E000..0x0010_0000;

/// Offsets from the start of flash of a region of the bootloader's layout.
#[cfg(feature = "hw")]
const fn offsets(region: rc_boot::layout::Region) -> core::ops::Range<u32> {
    let start = region.offset_from(rc_boot::layout::FLASH_BASE);
    start..start + region.len()
}

/// The DFU partition (offsets from the start of flash): where an image sent over the PLC link is
/// written, and the old firmware kept during a trial (`rc_boot::layout::L475.dfu`, bank 2).
#[cfg(feature = "hw")]
pub const DFU_RANGE: core::ops::Range<u32> = offsets(rc_boot::layout::L475.dfu);

/// embassy-boot's STATE pages (offsets from the start of flash): the mark for a swap, the
/// swap's progress (`rc_boot::layout::L475.state`, bank 2, below the settings).
#[cfg(feature = "hw")]
pub const STATE_RANGE: core::ops::Range<u32> = offsets(rc_boot::layout::L475.state);

// The settings pages are the layout's too.
#[cfg(feature = "hw")]
const _: () = assert!(
    offsets(rc_boot::layout::L475.settings).start == SETTINGS_RANGE.start
        && offsets(rc_boot::layout::L475.settings).end == SETTINGS_RANGE.end
);

/// The flash with the data cache off while it is read, written or erased, and a read that hit an
/// ECC double error failing.
///
/// The data cache: STM32L47x/L48x errata (ES0250), "Data cache might be corrupted during Flash
/// memory read-while-write operation" (the settings pages are in bank 2, the program runs from
/// bank 1). The workaround: the data cache off (ACR.DCEN) before each program or erase, reset
/// (DCRST) and on again after. embassy-stm32 0.6.0 does not do it (later versions do). Reads
/// too, so that every read reaches the flash and its ECC check (a cached line would not raise
/// the error again).
///
/// ECC: a double word whose programming a power cut interrupted (a save torn midway) can hold
/// two bad bits; reading it sets FLASH_ECCR.ECCD, which raises an NMI. The NMI handler
/// (`rt::DefaultHandler`, through [`settings_ecc_error`]) records the address when it lies in the
/// settings pages or the DFU partition, clears the flag and returns; the read then fails here
/// ([`FlashError::Ecc`]), which the settings store takes for a torn record (and the DFU's
/// read-back for a failed check). (Without the handler the NMI spun in
/// cortex-m-rt's default handler until the watchdog reset the chip, whose next start read the
/// same word: a boot loop.)
#[cfg(feature = "hw")]
pub struct DcacheOff<F>(pub F);

/// The flash offset (from the start of flash) of the ECC double error the NMI handler took in
/// the settings pages or the DFU partition since the last read began, [`NO_ECC_ERROR`] if none.
#[cfg(feature = "hw")]
static SETTINGS_ECC_ERROR: AtomicU32 = AtomicU32::new(NO_ECC_ERROR);
/// No error: offset 0 is the program's first word, never a settings page (and 0 keeps the static
/// in `.bss`, not in flash and RAM both).
#[cfg(feature = "hw")]
const NO_ECC_ERROR: u32 = 0;
#[cfg(feature = "hw")]
const _: () = assert!(SETTINGS_RANGE.start > NO_ECC_ERROR);
/// Bank 2's offset from the start of flash (the STM32L475VG's two 512 KiB banks, not swapped):
/// FLASH_ECCR gives the address within the bank (BK_ECC, ADDR_ECC).
#[cfg(feature = "hw")]
const BANK_2: u32 = 0x8_0000;

/// For the NMI handler: whether the NMI is an ECC double error (FLASH_ECCR.ECCD) in the settings
/// pages or the DFU partition ([`DFU_RANGE`]: a chunk's write a power cut tore), which this
/// records and clears (the handler then returns, and the read that hit it
/// fails). Anything else (an error in the program or the system flash, any other NMI) is left
/// to the handler: outputs safe, then a reset.
#[cfg(feature = "hw")]
pub fn settings_ecc_error() -> bool {
    let eccr = embassy_stm32::pac::FLASH.eccr();
    let ecc = eccr.read();
    if !ecc.eccd() || ecc.sysf_ecc() {
        return false;
    }
    let offset = ecc.addr_ecc() + if ecc.bk_ecc() { BANK_2 } else { 0 };
    if !SETTINGS_RANGE.contains(&offset)
        && !DFU_RANGE.contains(&offset)
        && !STATE_RANGE.contains(&offset)
    {
        return false;
    }
    SETTINGS_ECC_ERROR.store(offset, Ordering::Relaxed);
    // ECCD is cleared by writing 1 (ECCC too, if set: a corrected error, nothing to keep).
    eccr.modify(|w| w.set_eccd(true));
    true
}

/// A failed flash operation: the driver's error, or a read that took an ECC double error.
#[cfg(feature = "hw")]
#[derive(Debug)]
pub enum FlashError<E> {
    Driver(E),
    Ecc,
}

#[cfg(feature = "hw")]
impl<E: NorFlashError> NorFlashError for FlashError<E> {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            FlashError::Driver(e) => e.kind(),
            FlashError::Ecc => NorFlashErrorKind::Other,
        }
    }
}

#[cfg(feature = "hw")]
impl<F> DcacheOff<F> {
    fn without_dcache<T>(&mut self, op: impl FnOnce(&mut F) -> T) -> T {
        let acr = embassy_stm32::pac::FLASH.acr();
        let cached = acr.read().dcen();
        acr.modify(|w| w.set_dcen(false));
        let result = op(&mut self.0);
        if cached {
            acr.modify(|w| w.set_dcrst(true));
            acr.modify(|w| w.set_dcrst(false));
            acr.modify(|w| w.set_dcen(true));
        }
        result
    }
}

#[cfg(feature = "hw")]
impl<F: ErrorType> ErrorType for DcacheOff<F> {
    type Error = FlashError<F::Error>;
}

#[cfg(feature = "hw")]
impl<F: ReadNorFlash> ReadNorFlash for DcacheOff<F> {
    const READ_SIZE: usize = F::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        SETTINGS_ECC_ERROR.store(NO_ECC_ERROR, Ordering::Relaxed);
        self.without_dcache(|flash| flash.read(offset, bytes))
            .map_err(FlashError::Driver)?;
        // The NMI is taken right after the load that raised it; the barriers make sure that
        // has happened (the load completed, the pipeline refetched) before the check.
        cortex_m::asm::dsb();
        cortex_m::asm::isb();
        let at = SETTINGS_ECC_ERROR.swap(NO_ECC_ERROR, Ordering::Relaxed);
        if at != NO_ECC_ERROR {
            warn!("flash ECC error at {:#x}: a torn write", at);
            return Err(FlashError::Ecc);
        }
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

#[cfg(feature = "hw")]
impl<F: NorFlash> NorFlash for DcacheOff<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.without_dcache(|flash| flash.write(offset, bytes))
            .map_err(FlashError::Driver)
    }

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.without_dcache(|flash| flash.erase(from, to))
            .map_err(FlashError::Driver)
    }
}

/// Driver-enable lead and lag, in sample times (1/16 bit): half a bit either side of the
/// characters, ample for RS485 transceivers (enable times of a few hundred ns). Assertion and
/// de-assertion are equal because embassy-stm32 0.6.0 programs DEDT from the assertion time.
const DE_TIME: u8 = 8;

bind_interrupts!(struct Irqs {
    UART4 => BufferedInterruptHandler<UART4>;
    USART2 => BufferedInterruptHandler<USART2>;
    EXTI4 => exti::InterruptHandler<interrupt::typelevel::EXTI4>;
});

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
    // USART2 (the PLC line) from HSI16: see [`PLC_UART_HZ`].
    config.rcc.mux.usart2sel = embassy_stm32::rcc::mux::Usartsel::HSI;
    config
}

/// This chip's part of a UART's settings: the hardware driver enable's timing.
pub fn uart_config(config: &mut usart::Config) {
    config.de_assertion_time = DE_TIME;
    config.de_deassertion_time = DE_TIME;
}

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

/// Takes the peripherals this board uses. Fails only if a UART rejects its configuration.
pub fn board(
    p: Peripherals,
    plc_line: protocol::plc::PlcLine,
) -> Result<(Board, Pins), ConfigError> {
    // Outputs first, driven OFF, so that nothing is ever ON before the gateway says so.
    #[cfg_attr(not(feature = "emulator"), allow(unused_mut))]
    let mut outputs = Outputs::new(
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
    let leds = Leds::new(led(p.PB14), led(p.PA5), indicator_on_fault(p.PC9), LED_ON);
    #[cfg_attr(not(feature = "emulator"), allow(unused_mut))]
    let mut inputs = Inputs::new(
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
        ExtiInput::from_input(input(p.PA4), p.EXTI4, Irqs),
        INPUT_ON,
    );

    // The ports of PIO patterns 4 and 1 that no connector of the board has left (see
    // "Emulator" above): on port E in the emulator build only.
    #[cfg(feature = "emulator")]
    {
        inputs.add(6, input(p.PE7));
        inputs.add(7, input(p.PE8));
        inputs.add(8, input(p.PE9));
        inputs.add(9, input(p.PE10));
        outputs.add(4, output(p.PE11));
        outputs.add(5, output(p.PE12));
        outputs.add(9, output(p.PE13));
    }

    let line_break = LineBreak::new(PinId::of(&*p.PA0), Some(PinId::of(&*p.PA15)));
    pins::on_fault_release(PinId::of(&*p.PA15));
    let bus = BufferedUart::new_with_de(
        p.UART4,
        p.PA1,
        p.PA0,
        p.PA15,
        Irqs,
        BUS_TX.take(),
        BUS_RX.take(),
        line_config(super::BUS_INITIAL_BAUD, protocol::plc::Parity::None),
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
        line_config(plc_line.baud.bits_per_second(), plc_line.parity),
    )?;

    let plc = Rs485::new(
        plc,
        UartRegs(embassy_stm32::pac::USART2),
        (plc_line.baud.bits_per_second(), plc_line.parity),
        None,
        None,
    );
    let bus = Rs485::new(
        bus,
        UartRegs(embassy_stm32::pac::UART4),
        (super::BUS_INITIAL_BAUD, protocol::plc::Parity::None),
        Some(line_break),
        None,
    );
    let board = Board {
        bus,
        plc,
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
