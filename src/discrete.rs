//! The 24 V discrete I/O as pins: PIO inputs sampled into a [`PioInputs`] word, the stop input,
//! [`PioOutputs`] written to pins, and the three LEDs. Which pin is which bit is the board's choice.

use embassy_stm32::exti::ExtiInput;
use embassy_stm32::gpio::{Input, Level, Output};
use embassy_stm32::mode::Async;
use embassy_time::{Duration, Instant};

use protocol::pio::{PioInputs, PioOutputs};

/// The PIO inputs (bit number, pin) and the stop input, which can wake a task when it changes
/// (its EXTI line).
pub struct Inputs {
    pins: [(u8, Input<'static>); 11],
    stop: ExtiInput<'static, Async>,
    on: Level,
}

impl Inputs {
    /// `on` is the pin level of a signal that is ON.
    pub fn new(
        pins: [(u8, Input<'static>); 11],
        stop: ExtiInput<'static, Async>,
        on: Level,
    ) -> Inputs {
        Inputs { pins, stop, on }
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
        let bits = self
            .pins
            .iter()
            .filter(|(_, pin)| pin.get_level() == self.on)
            .fold(0u16, |bits, (bit, _)| bits | 1 << (bit & 15));
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

/// The PIO outputs (bit number, pin).
pub struct Outputs {
    pins: [(u8, Output<'static>); 11],
    on: Level,
    shown: Option<PioOutputs>,
}

impl Outputs {
    /// `on` is the pin level of a signal that is ON. The pins must be OFF already.
    pub fn new(pins: [(u8, Output<'static>); 11], on: Level) -> Outputs {
        Outputs {
            pins,
            on,
            shown: Some(PioOutputs::SAFE),
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
        for (bit, pin) in &mut self.pins {
            let on = outputs.bits() & (1 << (*bit & 15)) != 0;
            pin.set_level(if on { self.on } else { opposite(self.on) });
        }
        self.shown = Some(outputs);
    }
}

/// Bit n set for each pin of port n.
fn ports<T>(pins: &[(u8, T)]) -> u16 {
    pins.iter().fold(0, |bits, (bit, _)| bits | 1 << (bit & 15))
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
