//! GPIO below the HAL, for two jobs: the fail-safe pin states and the bus break.
//!
//! On a panic or a HardFault the HAL's pin objects belong to a task that will never run again, and
//! during a break the bus TX and DE pins belong to the UART driver. Both cases write the GPIO
//! registers directly, through the register block (safe code: the PAC's accessors are volatile
//! register accesses). [`crate::board`] records each pin here when it makes the HAL object from it,
//! so no pin choice is repeated. BSRR is the same on every STM32; the pin mode is MODER on "GPIO
//! v2" chips (L4, G0, F4...) and CRL/CRH on the F1, each behind [`PinId::set_mode`].

use core::sync::atomic::{AtomicU16, Ordering};

use embassy_stm32::gpio::Pin;
use embassy_stm32::pac;

/// What a pin is switched to below the HAL.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    /// A GPIO output (push-pull).
    Output,
    /// Back to its peripheral (alternate function, push-pull).
    Alternate,
}

/// A pin as (port, number): port 0 = GPIOA.
#[derive(Clone, Copy)]
pub struct PinId {
    port: u8,
    pin: u8,
}

impl PinId {
    /// The port and number of a HAL pin.
    pub fn of(pin: &impl Pin) -> PinId {
        PinId {
            port: pin.port(),
            pin: pin.pin(),
        }
    }

    /// The pin's number in its port, 0-15 on every STM32. Masked, so that the register
    /// accessors' range checks are known to pass: the fail-safe (panic, HardFault) has no
    /// panic path of its own (`scripts/stack_depth.py` showed one under the HardFault handler).
    fn number(self) -> usize {
        usize::from(self.pin & 0xF)
    }

    fn block(self) -> Option<pac::gpio::Gpio> {
        Some(match self.port {
            0 => pac::GPIOA,
            1 => pac::GPIOB,
            2 => pac::GPIOC,
            3 => pac::GPIOD,
            4 => pac::GPIOE,
            #[cfg(not(feature = "board-f103"))]
            5 => pac::GPIOF,
            #[cfg(not(feature = "board-f103"))]
            6 => pac::GPIOG,
            #[cfg(not(feature = "board-f103"))]
            7 => pac::GPIOH,
            _ => return None,
        })
    }

    fn set_level(self, high: bool) {
        if let Some(gpio) = self.block() {
            let n = self.number();
            gpio.bsrr().write(|w| {
                if high {
                    w.set_bs(n, true)
                } else {
                    w.set_br(n, true)
                }
            });
        }
    }

    #[cfg(not(feature = "board-f103"))]
    fn set_mode(self, mode: Mode) {
        use pac::gpio::vals::Moder;
        if let Some(gpio) = self.block() {
            let n = self.number();
            let moder = match mode {
                Mode::Output => Moder::OUTPUT,
                Mode::Alternate => Moder::ALTERNATE,
            };
            critical_section::with(|_| gpio.moder().modify(|w| w.set_moder(n, moder)));
        }
    }

    #[cfg(feature = "board-f103")]
    fn set_mode(self, mode: Mode) {
        use pac::gpio::vals::{CnfOut, Mode as Speed};
        if let Some(gpio) = self.block() {
            let n = self.number();
            let cnf = match mode {
                Mode::Output => CnfOut::PUSH_PULL,
                Mode::Alternate => CnfOut::ALT_PUSH_PULL,
            };
            critical_section::with(|_| {
                gpio.cr(n / 8).modify(|w| {
                    w.set_mode(n % 8, Speed::OUTPUT50MHZ);
                    w.set_cnf_out(n % 8, cnf);
                })
            });
        }
    }
}

/// Holds the bus low for a break: TX as a GPIO output at 0 and a hardware DE as a GPIO output at
/// 1 (the transceiver must drive the low level onto the pair), then hands both back to the UART.
/// A DE that is a GPIO already is the line's own business ([`crate::serial`]). embassy's
/// `send_break` sends one break character only; §6-1 wants 200 ms.
pub struct LineBreak {
    tx: PinId,
    de: Option<PinId>,
}

impl LineBreak {
    /// The break of a UART whose TX pin is `tx`, and whose DE pin is `de` if the UART drives it.
    pub fn new(tx: PinId, de: Option<PinId>) -> LineBreak {
        LineBreak { tx, de }
    }

    /// Starts holding the line low. Call only when the UART has finished transmitting.
    pub fn hold(&self) {
        self.tx.set_level(false);
        if let Some(de) = self.de {
            de.set_level(true);
            de.set_mode(Mode::Output);
        }
        self.tx.set_mode(Mode::Output);
    }

    /// Back to the UART: TX idles high (mark), DE follows the UART (released when idle).
    pub fn release(&self) {
        self.tx.set_mode(Mode::Alternate);
        if let Some(de) = self.de {
            de.set_mode(Mode::Alternate);
        }
    }
}

/// GPIOA..GPIOH.
const PORTS: usize = 8;

/// One bit per pin, per port (atomics, no lock: read in fault handlers).
struct PortMasks([AtomicU16; PORTS]);

impl PortMasks {
    const fn new() -> PortMasks {
        PortMasks([const { AtomicU16::new(0) }; PORTS])
    }

    fn add(&self, pin: PinId) {
        if let Some(mask) = self.0.get(usize::from(pin.port)) {
            mask.fetch_or(1 << pin.number(), Ordering::Relaxed);
        }
    }

    fn get(&self, port: usize) -> u16 {
        self.0.get(port).map_or(0, |m| m.load(Ordering::Relaxed))
    }
}

/// Driven low on a fault.
static SAFE_LOW: PortMasks = PortMasks::new();
/// Driven high on a fault.
static SAFE_HIGH: PortMasks = PortMasks::new();
/// Taken from their peripheral and driven low on a fault (the RS485 driver enables).
static SAFE_RELEASE: PortMasks = PortMasks::new();

/// On a fault, `pin` is driven to `high` (an output pin).
pub fn on_fault_drive(pin: PinId, high: bool) {
    if high {
        SAFE_HIGH.add(pin);
    } else {
        SAFE_LOW.add(pin);
    }
}

/// On a fault, `pin` (an alternate-function pin such as a hardware DE) becomes a GPIO output
/// at 0. (A board whose DE pins are GPIOs registers them with [`on_fault_drive`].)
#[cfg_attr(any(feature = "board-f103", feature = "board-f429"), allow(dead_code))]
pub fn on_fault_release(pin: PinId) {
    SAFE_RELEASE.add(pin);
}

/// Puts every recorded pin into its fault state: outputs OFF, alarm LED on, RS485 drivers
/// disabled. For the panic and HardFault handlers: touches only registers, takes no lock, and may
/// run at any moment (before the pins are recorded it changes nothing: after reset every pin is an
/// input, which is OFF for the 24 V stages).
pub fn force_safe() {
    for port in 0..PORTS {
        let (low, high, release) = (
            SAFE_LOW.get(port),
            SAFE_HIGH.get(port),
            SAFE_RELEASE.get(port),
        );
        if low | high | release == 0 {
            continue;
        }
        let Some(gpio) = (PinId {
            port: port as u8,
            pin: 0,
        })
        .block() else {
            continue;
        };
        let low = low | release;
        gpio.bsrr().write(|w| {
            for n in 0..16 {
                if low & (1 << n) != 0 {
                    w.set_br(n, true);
                } else if high & (1 << n) != 0 {
                    w.set_bs(n, true);
                }
            }
        });
        for n in 0..16u8 {
            if release & (1 << n) != 0 {
                PinId {
                    port: port as u8,
                    pin: n,
                }
                .set_mode(Mode::Output);
            }
        }
    }
}
