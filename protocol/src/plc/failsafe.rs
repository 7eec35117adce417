//! The fail-safe: what stops every axis when the PLC goes away or the stop input drops.
//!
//! Two causes, latched in FAILSAFE until the PLC writes 0:
//! - the **PLC watchdog**: no valid Modbus request to the gateway or any of its axes for longer
//!   than WATCHDOG (1 s by default; 0 turns it off). It re-arms with the next request;
//! - the **stop input** (a 24 V safety input, active when OFF): its activation trips at once,
//!   and no motion may start while it stays active.
//!
//! This type only decides; the gateway carries out the stops (before anything else on the bus).

use super::config::WatchdogAction;
use crate::time::{Duration, Instant};

/// FAILSAFE bit 0: the PLC watchdog tripped.
pub const CAUSE_WATCHDOG: u16 = 1 << 0;
/// FAILSAFE bit 1: the stop input was activated.
pub const CAUSE_STOP_INPUT: u16 = 1 << 1;

/// What the gateway must do about a trip.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Trip {
    /// Stop every axis now.
    StopAll,
    /// Only latched (watchdog action "latch only").
    Latched,
}

/// The fail-safe state.
#[derive(Clone, Copy, Debug)]
pub(super) struct FailSafe {
    /// The last PLC request; `None` until the first (the watchdog is armed by it).
    last_plc: Option<Instant>,
    /// The watchdog tripped and no request came since.
    tripped: bool,
    /// The stop input is active.
    stop_input: bool,
    /// Latched causes (FAILSAFE).
    latched: u16,
    /// Trips so far (FSCOUNT).
    count: u16,
}

impl FailSafe {
    pub(super) const fn new() -> FailSafe {
        FailSafe {
            last_plc: None,
            tripped: false,
            stop_input: false,
            latched: 0,
            count: 0,
        }
    }

    /// A valid request from the PLC arrived at `now`.
    pub(super) fn activity(&mut self, now: Instant) {
        self.last_plc = Some(now);
        self.tripped = false;
    }

    /// When the watchdog trips if no request comes (just after `limit` of silence); `None`
    /// while it is off, not armed yet, or tripped.
    pub(super) fn deadline(&self, limit: Duration) -> Option<Instant> {
        match self.last_plc {
            Some(last) if limit > Duration::ZERO && !self.tripped => {
                Some(last + limit + Duration::from_micros(1))
            }
            _ => None,
        }
    }

    /// Check the watchdog at `now`.
    pub(super) fn check(
        &mut self,
        now: Instant,
        limit: Duration,
        action: WatchdogAction,
    ) -> Option<Trip> {
        if self.deadline(limit).is_none_or(|deadline| now < deadline) {
            return None;
        }
        self.tripped = true;
        self.latch(CAUSE_WATCHDOG);
        Some(match action {
            WatchdogAction::StopAll => Trip::StopAll,
            WatchdogAction::LatchOnly => Trip::Latched,
        })
    }

    /// The stop input's level; whether this activation trips.
    pub(super) fn set_stop_input(&mut self, active: bool) -> bool {
        let rising = active && !self.stop_input;
        self.stop_input = active;
        if rising {
            self.latch(CAUSE_STOP_INPUT);
        }
        rising
    }

    fn latch(&mut self, cause: u16) {
        self.latched |= cause;
        self.count = self.count.wrapping_add(1);
    }

    /// The PLC cleared FAILSAFE.
    pub(super) fn clear(&mut self) {
        self.latched = 0;
    }

    /// The stop input is active: no motion may start.
    pub(super) fn stop_input(&self) -> bool {
        self.stop_input
    }

    /// A cause is latched or the watchdog has tripped: nothing is started on the PLC's
    /// behalf (the held SON is not re-applied).
    pub(super) fn engaged(&self) -> bool {
        self.latched != 0 || self.tripped
    }

    /// FAILSAFE.
    pub(super) fn latched(&self) -> u16 {
        self.latched
    }

    /// FSCOUNT.
    pub(super) fn count(&self) -> u16 {
        self.count
    }
}
