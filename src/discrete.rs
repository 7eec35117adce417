//! The 24 V discrete I/O as pins: PIO inputs sampled into a [`PioInputs`] word, the stop input,
//! [`PioOutputs`] written to pins, and the three LEDs. Which pin is which bit is the board's choice.

use embassy_stm32::exti::ExtiInput;
use embassy_stm32::gpio::{Input, Level, Output};
use embassy_stm32::mode::Async;
use embassy_time::{Duration, Instant};

use protocol::pio::{PioInputs, PioOutputs};

/// The PIO inputs (the pin of port INn at index n, if the board has it) and the stop input,
/// which can wake a task when it changes (its EXTI line).
pub struct Inputs {
    pins: [Option<Input<'static>>; 16],
    stop: ExtiInput<'static, Async>,
    on: Level,
}

impl Inputs {
    /// `pins` are (port number, pin); `on` is the pin level of a signal that is ON.
    pub fn new<const N: usize>(
        pins: [(u8, Input<'static>); N],
        stop: ExtiInput<'static, Async>,
        on: Level,
    ) -> Inputs {
        let mut inputs = Inputs {
            pins: [const { None }; 16],
            stop,
            on,
        };
        for (port, pin) in pins {
            inputs.add(port, pin);
        }
        inputs
    }

    /// Port INn on `pin`.
    pub fn add(&mut self, port: u8, pin: Input<'static>) {
        if let Some(slot) = self.pins.get_mut(usize::from(port)) {
            *slot = Some(pin);
        }
    }

    /// Until the stop input is no longer as sampled (`stop_active`, [`Inputs::stop_active`]).
    /// The level is checked after the interrupt is armed, so a change between the sample and
    /// this call is not lost (an edge would be: arming clears the pending one).
    pub async fn stop_other_than(&mut self, stop_active: bool) {
        // Active = the input OFF.
        if stop_active == (self.on == Level::High) {
            self.stop.wait_for_high().await
        } else {
            self.stop.wait_for_low().await
        }
    }

    /// The inputs now, bit n = port INn.
    pub fn sample(&self) -> PioInputs {
        let bits = (0..)
            .zip(&self.pins)
            .filter(|(_, pin)| pin.as_ref().is_some_and(|p| p.get_level() == self.on))
            .fold(0u16, |bits, (bit, _)| bits | 1 << bit);
        PioInputs::from_bits(bits)
    }

    /// The ports these pins are (bit n = INn): the PIO patterns the board can run.
    pub fn ports(&self) -> u16 {
        ports(&self.pins)
    }

    /// Whether the stop is requested: the stop input is OFF (so a broken wire stops too).
    pub fn stop_active(&self) -> bool {
        self.stop.get_level() != self.on
    }
}

/// The PIO outputs (the pin of port OUTn at index n, if the board has it).
pub struct Outputs {
    pins: [Option<Output<'static>>; 16],
    on: Level,
    shown: Option<PioOutputs>,
}

impl Outputs {
    /// `pins` are (port number, pin); `on` is the pin level of a signal that is ON. The pins
    /// must be OFF already.
    pub fn new<const N: usize>(pins: [(u8, Output<'static>); N], on: Level) -> Outputs {
        let mut outputs = Outputs {
            pins: [const { None }; 16],
            on,
            shown: Some(PioOutputs::SAFE),
        };
        for (port, pin) in pins {
            outputs.add(port, pin);
        }
        outputs
    }

    /// Port OUTn on `pin` (OFF already).
    pub fn add(&mut self, port: u8, pin: Output<'static>) {
        if let Some(slot) = self.pins.get_mut(usize::from(port)) {
            *slot = Some(pin);
        }
    }

    /// The ports these pins are (bit n = OUTn).
    pub fn ports(&self) -> u16 {
        ports(&self.pins)
    }

    /// Drives the pins to `outputs` (bit n = port OUTn).
    pub fn write(&mut self, outputs: PioOutputs) {
        if self.shown == Some(outputs) {
            return;
        }
        for (bit, pin) in (0..).zip(&mut self.pins) {
            if let Some(pin) = pin {
                let on = outputs.bits() & 1 << bit != 0;
                pin.set_level(if on { self.on } else { opposite(self.on) });
            }
        }
        self.shown = Some(outputs);
    }
}

/// Bit n set for each port n that has a pin.
fn ports<T>(pins: &[Option<T>; 16]) -> u16 {
    (0..)
        .zip(pins)
        .filter(|(_, pin)| pin.is_some())
        .fold(0, |bits, (bit, _)| bits | 1 << bit)
}

/// The other level.
pub const fn opposite(level: Level) -> Level {
    match level {
        Level::High => Level::Low,
        Level::Low => Level::High,
    }
}

/// Half period of the run LED's blink.
const RUN_BLINK: Duration = Duration::from_millis(500);

/// Run (blinks while the gateway task makes progress), bus link and alarm LEDs, lit at the
/// board's `LED_ON` level.
pub struct Leds {
    run: Output<'static>,
    link: Output<'static>,
    alarm: Output<'static>,
    on: Level,
    next_blink: Instant,
    /// The gateway task's progress count at the last blink.
    progress: u32,
}

impl Leds {
    /// The LEDs, all off; `on` is the pin level that lights one.
    pub fn new(
        run: Output<'static>,
        link: Output<'static>,
        alarm: Output<'static>,
        on: Level,
    ) -> Leds {
        Leds {
            run,
            link,
            alarm,
            on,
            next_blink: Instant::from_ticks(0),
            progress: 0,
        }
    }

    /// Shows (bus link good, alarm), and blinks the run LED if the gateway task's `progress`
    /// count moved since the last blink (a stuck task leaves it as it is).
    pub fn show(&mut self, now: Instant, indicators: protocol::node::Indicators, progress: u32) {
        let level = |lit: bool| if lit { self.on } else { opposite(self.on) };
        self.link.set_level(level(indicators.link));
        self.alarm.set_level(level(indicators.alarm));
        if now >= self.next_blink && progress != self.progress {
            self.run.toggle();
            self.next_blink = now + RUN_BLINK;
            self.progress = progress;
        }
    }
}
