//! GPIO below the HAL, for two jobs: the fail-safe pin states and the bus break.
//!
//! On a panic or a HardFault the HAL's pin objects belong to a task that will never run again, and
//! during a break the bus TX and DE pins belong to the UART driver. Both cases write the GPIO
//! registers directly, through the register block (safe code: the PAC's accessors are volatile
//! register accesses). [`crate::board`] records each pin here when it makes the HAL object from it,
//! so no pin choice is repeated. This is the STM32 "GPIO v2" register layout (MODER/BSRR: L4, G0,
//! F4...); an F1 board needs its own version of this module (CRL/CRH).

use core::sync::atomic::{AtomicU16, Ordering};

use embassy_stm32::gpio::Pin;
use embassy_stm32::pac;
use embassy_stm32::pac::gpio::vals::Moder;

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

    fn block(self) -> Option<pac::gpio::Gpio> {
        Some(match self.port {
            0 => pac::GPIOA,
            1 => pac::GPIOB,
            2 => pac::GPIOC,
            3 => pac::GPIOD,
            4 => pac::GPIOE,
            5 => pac::GPIOF,
            6 => pac::GPIOG,
            7 => pac::GPIOH,
            _ => return None,
        })
    }

    fn set_level(self, high: bool) {
        if let Some(gpio) = self.block() {
            let n = usize::from(self.pin);
            gpio.bsrr().write(|w| {
                if high {
                    w.set_bs(n, true)
                } else {
                    w.set_br(n, true)
                }
            });
        }
    }

    fn set_mode(self, mode: Moder) {
        if let Some(gpio) = self.block() {
            let n = usize::from(self.pin);
            critical_section::with(|_| gpio.moder().modify(|w| w.set_moder(n, mode)));
        }
    }
}

/// Holds the bus low for a break: TX as a GPIO output at 0 and DE as a GPIO output at 1 (the
/// transceiver must drive the low level onto the pair), then hands both back to the UART.
/// embassy's `send_break` sends one break character only; §6-1 wants 200 ms.
pub struct LineBreak {
    tx: PinId,
    de: PinId,
}

impl LineBreak {
    /// The break of a UART whose TX and DE pins are these.
    pub fn new(tx: PinId, de: PinId) -> LineBreak {
        LineBreak { tx, de }
    }

    /// Starts holding the line low. Call only when the UART has finished transmitting.
    pub fn hold(&self) {
        self.tx.set_level(false);
        self.de.set_level(true);
        self.de.set_mode(Moder::OUTPUT);
        self.tx.set_mode(Moder::OUTPUT);
    }

    /// Back to the UART: TX idles high (mark), DE follows the UART (released when idle).
    pub fn release(&self) {
        self.tx.set_mode(Moder::ALTERNATE);
        self.de.set_mode(Moder::ALTERNATE);
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
            mask.fetch_or(1 << (pin.pin & 15), Ordering::Relaxed);
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

/// On a fault, `pin` (an alternate-function pin such as a DE) becomes a GPIO output at 0.
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
        if release != 0 {
            gpio.moder().modify(|w| {
                for n in 0..16 {
                    if release & (1 << n) != 0 {
                        w.set_moder(n, Moder::OUTPUT);
                    }
                }
            });
        }
    }
}
