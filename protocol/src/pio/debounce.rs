//! Debounced inputs: each pin counts once it has read the same level for the debounce time
//! (IAI's input time constant; see the [module documentation](super)).

use super::PioInputs;
use crate::time::{Duration, Instant};

/// Debounced inputs: each pin counts once it has read the same level for the debounce time.
#[derive(Clone, Copy, Debug)]
pub(super) struct Debouncer {
    /// The last sample.
    raw: u16,
    /// When each pin last changed in the samples.
    since: [Instant; 16],
    /// The recognised levels.
    pub(super) stable: u16,
    /// The pins recognised at least once since start-up.
    pub(super) known: u16,
    /// Whether a sample has been taken.
    started: bool,
}

impl Debouncer {
    pub(super) const fn new() -> Debouncer {
        Debouncer {
            raw: 0,
            since: [Instant(0); 16],
            stable: 0,
            known: 0,
            started: false,
        }
    }

    /// Take a sample; returns the bits whose recognised level changed or that became known.
    pub(super) fn update(&mut self, now: Instant, raw: u16, debounce: Duration) -> u16 {
        let changed_raw = if self.started {
            self.raw ^ raw
        } else {
            PioInputs::MASK
        };
        self.started = true;
        self.raw = raw;
        let mut changed = 0;
        for (bit, since) in self.since.iter_mut().enumerate() {
            let m = 1u16 << bit;
            if m & PioInputs::MASK == 0 {
                continue;
            }
            if changed_raw & m != 0 {
                *since = now;
            }
            if now.since(*since) < debounce {
                continue;
            }
            let level = raw & m;
            if self.known & m == 0 || self.stable & m != level {
                changed |= m;
                self.known |= m;
                self.stable = (self.stable & !m) | level;
            }
        }
        changed
    }

    pub(super) fn on(&self, flag: PioInputs) -> bool {
        self.stable & flag.bits() != 0
    }

    pub(super) fn known(&self, flag: PioInputs) -> bool {
        self.known & flag.bits() != 0
    }

    /// Whether `flag` went from a recognised OFF to ON in the last update.
    pub(super) fn rose(&self, flag: PioInputs, changed: u16, known_before: u16) -> bool {
        changed & flag.bits() != 0 && known_before & flag.bits() != 0 && self.on(flag)
    }
}
