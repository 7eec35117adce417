//! The discrete I/O task: samples the inputs and drives the PIO outputs and the LEDs, so that the
//! gateway task wakes for what the node needs to see (a changed input, or every sample while a
//! PIO axis is configured: its logic debounces and times by samples), not for every sample. It
//! owns pins only; the node stays the gateway task's alone.
//!
//! How often it wakes depends on the discrete I/O:
//! - **A PIO axis configured**: every millisecond ([`SAMPLE_PERIOD`]), the PIO's resolution.
//! - **No PIO axis** (the PLC drives every axis over Modbus): the PIO inputs mean nothing and
//!   the outputs stay OFF, so it wakes when the stop input changes (its pin-change interrupt,
//!   EXTI) and every [`INDICATORS_PERIOD`] for the LEDs. It waits for the level other than the
//!   one it sampled, checked after the interrupt is armed, so a change in between is not lost.
//!
//! Measured by `scripts/cpu-load.sh` (16 axes, no PIO axis): a millisecond tick of the gateway
//! task cost about 1,600 instructions (the wake, re-arming both UART reads and its timers, the
//! pins); one of this task about 575, still 0.9 points of CPU load at 1 kHz.

use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use embassy_futures::select::{select, Either};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Ticker, Timer};

use crate::discrete::{Inputs, Leds, Outputs};
use protocol::node::Indicators;
use protocol::pio::{PioInputs, PioOutputs};

/// The inputs are sampled this often when the node wants every sample (the node debounces the
/// PIO inputs: `protocol::node::Node::sample_period`).
const SAMPLE_PERIOD: Duration = Duration::from_micros(protocol::pio::SAMPLE_PERIOD.0);

/// The input pins, as the node takes them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sample {
    /// The stop input asks for a stop (it is OFF: a cut wire stops too).
    pub stop: bool,
    /// The PIO inputs.
    pub inputs: PioInputs,
}

impl Sample {
    /// The pins now.
    pub fn of(inputs: &Inputs) -> Sample {
        Sample {
            stop: inputs.stop_active(),
            inputs: inputs.sample(),
        }
    }
}

/// Samples for the gateway task; a newer one replaces one not taken yet (the node acts on the
/// pins' state, and the time it sees them).
pub static SAMPLES: Signal<CriticalSectionRawMutex, Sample> = Signal::new();

/// What the gateway task wants on the pins: the PIO outputs in bits 0-15, the bus link LED in
/// bit 16, the alarm LED in bit 17. All OFF until it says otherwise.
static SHOWN: AtomicU32 = AtomicU32::new(0);
const LINK: u32 = 1 << 16;
const ALARM: u32 = 1 << 17;

/// Whether every sample goes to the gateway task, not only changes.
static EVERY_SAMPLE: AtomicBool = AtomicBool::new(false);

/// Passes of the gateway task's loop: the run LED blinks while this moves.
static PROGRESS: AtomicU32 = AtomicU32::new(0);

/// Called by the gateway task on every pass of its loop: the PIO outputs, and whether it needs
/// every sample (a PIO axis is configured) or only changes.
pub fn show_outputs(outputs: PioOutputs, every_sample: bool) {
    let indicators = SHOWN.load(Ordering::Relaxed) & (LINK | ALARM);
    SHOWN.store(indicators | u32::from(outputs.bits()), Ordering::Relaxed);
    EVERY_SAMPLE.store(every_sample, Ordering::Relaxed);
    PROGRESS.fetch_add(1, Ordering::Relaxed);
}

/// Called by the gateway task now and then ([`INDICATORS_PERIOD`]): what the LEDs show. (Working
/// them out looks at every axis: not on every pass.)
pub fn show_indicators(indicators: Indicators) {
    let mut shown = SHOWN.load(Ordering::Relaxed) & !(LINK | ALARM);
    if indicators.link {
        shown |= LINK;
    }
    if indicators.alarm {
        shown |= ALARM;
    }
    SHOWN.store(shown, Ordering::Relaxed);
}

/// How often the gateway task updates the LEDs: fast for an eye, slow for the CPU.
pub const INDICATORS_PERIOD: Duration = Duration::from_millis(20);

/// The pins, for [`run`].
pub struct Pins {
    /// The PIO inputs and the stop input.
    pub inputs: Inputs,
    /// The PIO outputs.
    pub outputs: Outputs,
    /// Run, bus link and alarm LEDs.
    pub leds: Leds,
}

/// The emulator build only: how many times the stop input's interrupt woke this task, read by
/// the emulator tests (through QEMU's qtest, by its symbol) to prove the interrupt path.
#[cfg(feature = "emulator")]
#[used]
static EMU_STOP_WAKES: AtomicU32 = AtomicU32::new(0);

/// Samples the inputs and drives the outputs and LEDs, forever: every millisecond while a PIO
/// axis is configured, else on a change of the stop input and every [`INDICATORS_PERIOD`].
#[embassy_executor::task]
pub async fn run(pins: &'static mut Pins) -> ! {
    let Pins {
        inputs,
        outputs,
        leds,
    } = pins;
    let mut ticker = Ticker::every(SAMPLE_PERIOD);
    let mut sent: Option<Sample> = None;
    loop {
        let sample = Sample::of(inputs);
        let every_sample = EVERY_SAMPLE.load(Ordering::Relaxed);
        if sent != Some(sample) || every_sample {
            SAMPLES.signal(sample);
            sent = Some(sample);
        }
        let shown = SHOWN.load(Ordering::Relaxed);
        outputs.write(PioOutputs::from_bits(shown as u16));
        let indicators = Indicators {
            link: shown & LINK != 0,
            alarm: shown & ALARM != 0,
        };
        leds.show(
            embassy_time::Instant::now(),
            indicators,
            PROGRESS.load(Ordering::Relaxed),
        );
        if every_sample {
            ticker.next().await;
        } else {
            let stop_moved = inputs.stop_other_than(sample.stop);
            if let Either::First(()) = select(stop_moved, Timer::after(INDICATORS_PERIOD)).await {
                #[cfg(feature = "emulator")]
                EMU_STOP_WAKES.fetch_add(1, Ordering::Relaxed);
            }
            // The millisecond samples, if a PIO axis comes, start from now, not in a burst
            // that catches up on the time spent here.
            ticker.reset();
        }
    }
}
