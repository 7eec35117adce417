//! Time as this crate sees it: numbers the caller passes in. Nothing here reads a clock
//! (smoltcp's `poll(timestamp)` model), so the same code runs on the MCU, on a PC and in
//! virtual-time tests. The bus engine, the Modbus receiver and the PIO all take these.

use core::num::NonZeroU32;
use core::ops::{Add, Sub};

use crate::div::{div, divisor};

/// Microseconds in a millisecond and in a second, as divisors for [`div`] (which keeps the
/// 64-bit division routine out of the firmware).
const US_PER_MS: NonZeroU32 = divisor(1000);
const US_PER_S: NonZeroU32 = divisor(1_000_000);

/// A point in time, in microseconds since an arbitrary origin chosen by the caller.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Instant(pub u64);

/// A span of time in microseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Duration(pub u64);

impl Duration {
    /// Zero.
    pub const ZERO: Duration = Duration(0);

    /// `ms` milliseconds.
    pub const fn from_millis(ms: u64) -> Duration {
        Duration(ms.saturating_mul(US_PER_MS.get() as u64))
    }

    /// `s` seconds.
    pub const fn from_secs(s: u64) -> Duration {
        Duration(s.saturating_mul(1_000_000))
    }

    /// `us` microseconds.
    pub const fn from_micros(us: u64) -> Duration {
        Duration(us)
    }

    /// Whole microseconds.
    pub const fn as_micros(self) -> u64 {
        self.0
    }

    /// Whole milliseconds.
    pub fn as_millis(self) -> u64 {
        div(self.0, US_PER_MS)
    }

    /// The sum, saturating.
    pub const fn plus(self, other: Duration) -> Duration {
        Duration(self.0.saturating_add(other.0))
    }
}

impl Instant {
    /// The origin.
    pub const ZERO: Instant = Instant(0);

    /// Whole seconds since the origin.
    pub fn as_secs(self) -> u64 {
        div(self.0, US_PER_S)
    }

    /// The time elapsed since `earlier` (zero if `earlier` is later).
    // Not inlined, as `Instant + Duration` below: 20 B less of the F103's flash.
    #[inline(never)]
    pub const fn since(self, earlier: Instant) -> Duration {
        Duration(self.0.saturating_sub(earlier.0))
    }
}

/// The earlier of two optional deadlines, where `None` means "no deadline" (not "now").
///
/// `Option::min` would take `None` as the smaller value and so lose every real deadline merged
/// with an empty one: a loop sleeping on the result would sleep forever.
// Not inlined: two 64-bit options compared at each use took 44 B more of the F103's flash.
#[inline(never)]
pub const fn earliest(a: Option<Instant>, b: Option<Instant>) -> Option<Instant> {
    match (a, b) {
        (Some(a), Some(b)) => Some(if a.0 <= b.0 { a } else { b }),
        (Some(t), None) | (None, Some(t)) => Some(t),
        (None, None) => None,
    }
}

impl Add<Duration> for Instant {
    type Output = Instant;
    // Not inlined: a 64-bit saturating add at each of its 28 uses took 340 B more of the
    // F103's flash (`scripts/size-report.sh`).
    #[inline(never)]
    fn add(self, d: Duration) -> Instant {
        Instant(self.0.saturating_add(d.0))
    }
}

impl Sub<Instant> for Instant {
    type Output = Duration;
    fn sub(self, earlier: Instant) -> Duration {
        self.since(earlier)
    }
}
