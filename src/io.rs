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

use core::cell::RefCell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use embassy_futures::select::{select, Either};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Ticker, Timer};

use crate::discrete::{Inputs, Leds, Outputs};
use crate::emu;
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

/// Samples wait here for the gateway task, as runs: a run is one level of the pins and the
/// stamps of its first and last samples, taken when the pins were read. The gateway task takes
/// nothing while it awaits a bus command's send, a rate change or a flush (a command at 9.6
/// kbit/s keeps it 16.7 ms); stamped here and kept, the samples of that time reach the node as
/// they were taken, so a pulse longer than the debounce plus one sample period is neither lost
/// nor shortened. When the gateway task kept only the newest sample and stamped it as it took it,
/// 8 ms CSTR pulses at 9.6 kbit/s with four axes were taken 6 times of 20
/// (`tests/emu/test_discrete.py`).
///
/// [`RUNS`] levels fit: an input must hold a level for the debounce time (6 ms) to count, so a
/// PLC changes them far less often than the longest wait fills (a PC change, CSTR ON and CSTR
/// OFF within 17 ms are 4 levels). A fifth (a contact bouncing during a 2 s flush of a 1.2
/// kbit/s reply) replaces the newest run: that level is lost, and the one before it may look
/// held through it (a bounce the debouncer would have counted goes unseen).
static PENDING: Mutex<CriticalSectionRawMutex, RefCell<Runs>> = Mutex::new(RefCell::new(Runs {
    runs: [Run::EMPTY; RUNS],
    head: 0,
    len: 0,
}));

/// Wakes the gateway task when a sample is pending.
pub static SAMPLED: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// How many levels wait for the gateway task at most: see [`PENDING`].
const RUNS: usize = 4;

/// Samples of one level, in a row: see [`PENDING`].
#[derive(Clone, Copy)]
pub struct Run {
    /// The level.
    pub sample: Sample,
    /// The first sample's time: the low 32 bits of its µs since boot ([`Run::at`]).
    first: u32,
    /// The last sample's time, the same way.
    last: u32,
}

impl Run {
    const EMPTY: Run = Run {
        sample: Sample {
            stop: false,
            inputs: PioInputs::NONE,
        },
        first: 0,
        last: 0,
    };

    /// The first and the last sample's time in µs since boot, given `now` (µs, not earlier than
    /// them; they are at most minutes old, far less than the 71 minutes 32 bits count).
    pub fn at(&self, now: u64) -> (u64, u64) {
        let back = |stamp: u32| now.saturating_sub(u64::from((now as u32).wrapping_sub(stamp)));
        (back(self.first), back(self.last))
    }
}

/// A ring of [`RUNS`] runs: `len` of them from `head` on.
struct Runs {
    runs: [Run; RUNS],
    head: usize,
    len: usize,
}

/// Keeps `sample`, read at `now` (µs since boot; the low 32 bits are kept).
fn push(sample: Sample, now: u64) {
    let now = now as u32;
    PENDING.lock(|pending| {
        let mut pending = pending.borrow_mut();
        let Runs { runs, head, len } = &mut *pending;
        let newest = (*head + *len + RUNS - 1) % RUNS;
        match runs.get_mut(newest) {
            Some(run) if *len > 0 && run.sample == sample => run.last = now,
            _ => {
                // Full: the newest run is replaced.
                *len = (*len + 1).min(RUNS);
                if let Some(run) = runs.get_mut((*head + *len - 1) % RUNS) {
                    *run = Run {
                        sample,
                        first: now,
                        last: now,
                    };
                }
            }
        }
    });
    SAMPLED.signal(());
}

/// The oldest run the gateway task has not taken yet.
pub fn take() -> Option<Run> {
    PENDING.lock(|pending| {
        let mut pending = pending.borrow_mut();
        let Runs { runs, head, len } = &mut *pending;
        let run = runs.get(*head).copied().filter(|_| *len > 0)?;
        *head = (*head + 1) % RUNS;
        *len -= 1;
        Some(run)
    })
}

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
    // What the emulator harness reads of an input pulse (nothing on the board).
    let mut pulse = emu::PulseTimer::new();
    loop {
        // Stamped as read: the gateway task may take it much later.
        let now = embassy_time::Instant::now();
        let sample = Sample::of(inputs);
        let every_sample = EVERY_SAMPLE.load(Ordering::Relaxed);
        pulse.sample(now, sample.inputs);
        if sent != Some(sample) || every_sample {
            push(sample, now.as_micros());
            sent = Some(sample);
        }
        let shown = SHOWN.load(Ordering::Relaxed);
        outputs.write(PioOutputs::from_bits(shown as u16));
        let indicators = Indicators {
            link: shown & LINK != 0,
            alarm: shown & ALARM != 0,
        };
        leds.show(now, indicators, PROGRESS.load(Ordering::Relaxed));
        if every_sample {
            ticker.next().await;
        } else {
            let stop_moved = inputs.stop_other_than(sample.stop);
            if let Either::First(()) = select(stop_moved, Timer::after(INDICATORS_PERIOD)).await {
                emu::count_stop_wake();
            }
            // The millisecond samples, if a PIO axis comes, start from now, not in a burst
            // that catches up on the time spent here.
            ticker.reset();
        }
    }
}
