//! Fault injection: what can go wrong on the bus, how often, and the seeded generators that
//! decide when (see [`super::rng`]). Every injected fault is counted in
//! [`BusStats`](super::stats::BusStats) so that a test can check a bus master's counters against
//! what really happened.
//!
//! Besides the probabilities here, a [`Bus`](super::Bus) can make an axis silent (present, it
//! executes commands but never answers: a dead transmitter), power-cycle an axis at a given time,
//! inject an alarm, and put given noise bytes on the line.

use super::rng::Rng;

/// Probabilities and sizes of the random faults. All zero by default.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Faults {
    /// Each byte the host sends is corrupted (random bits flipped) with this probability.
    pub host_byte_corruption: f64,
    /// Each byte a controller sends is corrupted with this probability.
    pub reply_byte_corruption: f64,
    /// Each reply a controller prepares is dropped (never sent) with this probability.
    pub reply_drop: f64,
    /// Each reply is sent [`reply_delay_us`](Self::reply_delay_us) late with this probability.
    pub reply_delay: f64,
    /// The extra delay of a delayed reply (µs).
    pub reply_delay_us: u64,
    /// After each frame ends, a burst of noise follows with this probability (a transceiver
    /// releasing the bus without fail-safe bias reads as a spurious byte).
    pub noise: f64,
    /// Noise bytes per burst: 1 to this many (at least 1). Noise bytes are never STX, so a
    /// deframer counts each of them as a noise byte.
    pub noise_max_bytes: u8,
}

impl Faults {
    /// The same corruption probability in both directions.
    pub fn byte_corruption(p: f64) -> Faults {
        Faults {
            host_byte_corruption: p,
            reply_byte_corruption: p,
            ..Faults::default()
        }
    }
}

/// One generator per fault kind, so that the kinds are independent of each other.
#[derive(Clone, Debug)]
pub(super) struct FaultRngs {
    pub(super) corruption: Rng,
    pub(super) drop: Rng,
    pub(super) delay: Rng,
    pub(super) noise: Rng,
    pub(super) collision: Rng,
}

impl FaultRngs {
    pub(super) fn new(seed: u64) -> FaultRngs {
        FaultRngs {
            corruption: Rng::derive(seed, 1),
            drop: Rng::derive(seed, 2),
            delay: Rng::derive(seed, 3),
            noise: Rng::derive(seed, 4),
            collision: Rng::derive(seed, 5),
        }
    }
}
