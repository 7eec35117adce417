//! The fail-safe: what stops every axis when the PLC goes away or the stop input drops.
//!
//! Two causes, latched in FAILSAFE until acknowledged:
//! - the **PLC watchdog**: no valid Modbus request to the gateway or any of its axes for longer
//!   than WATCHDOG (1 s by default; 0 turns it off). It re-arms with the next request;
//! - the **stop input** (a 24 V safety input, active when OFF): its activation trips at once,
//!   and no motion may start while it stays active.
//!
//! The latch is acknowledged as a manual reset is: once its cause is gone, and until then no
//! motion starts. A PLC acknowledges by writing 0 to FAILSAFE, a machine wired by 24 V only by a
//! RES pulse on the discrete inputs; either is refused while the stop input is still active.
//! A latched watchdog cause holds motion only when the watchdog's action stops the axes: with
//! "latch only" the PLC chose to keep them running.
//!
//! **No latch a wire-only machine cannot clear.** The watchdog is armed by the first request of
//! any master, a commissioning PC's included; when that PC is unplugged at hand-over, the
//! watchdog trips and its silence never ends on a machine driven by wires alone. So a RES
//! pulse acknowledges a watchdog latch while the silence lasts, and **disarms** the watchdog
//! until a master speaks again (its next request arms it, as at start). Nothing driven over
//! Modbus can start meanwhile: that needs a master's write, which re-arms it. (A Modbus write
//! of 0 to FAILSAFE ends the silence by being a request.)
//!
//! These are functional stops of the gateway's own, not a safety function: see the Fail-safe
//! section of docs/plc.md.
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

    /// Whether the latch may be acknowledged now: the stop input is not active (the watchdog's
    /// silence does not refuse it: see the module documentation).
    pub(super) fn may_acknowledge(&self) -> bool {
        !self.stop_input
    }

    /// Acknowledge the latch ([`may_acknowledge`](Self::may_acknowledge)); nothing changes while
    /// the stop input is active. `by_request`: by a Modbus write (a request: the watchdog is
    /// armed by it); else by a RES pulse, which disarms a watchdog that tripped until a master
    /// speaks again.
    pub(super) fn acknowledge(&mut self, by_request: bool) {
        if !self.may_acknowledge() {
            return;
        }
        self.latched = 0;
        if !by_request && self.tripped {
            self.tripped = false;
            self.last_plc = None;
        }
    }

    /// Whether the latch holds motion (see the module documentation).
    pub(super) fn holds_motion(&self, action: WatchdogAction) -> bool {
        let holding = match action {
            WatchdogAction::StopAll => CAUSE_WATCHDOG | CAUSE_STOP_INPUT,
            WatchdogAction::LatchOnly => CAUSE_STOP_INPUT,
        };
        self.stop_input || self.latched & holding != 0
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

#[cfg(test)]
mod tests {
    use super::*;

    const LIMIT: Duration = Duration::from_millis(1000);

    fn tripped() -> FailSafe {
        let mut f = FailSafe::new();
        f.activity(Instant::ZERO);
        let trip = f.check(Instant(2_000_000), LIMIT, WatchdogAction::StopAll);
        assert_eq!(trip, Some(Trip::StopAll));
        f
    }

    #[test]
    fn the_stop_input_cause_is_acknowledged_only_once_it_is_gone() {
        let mut f = FailSafe::new();
        assert!(f.set_stop_input(true));
        for by_request in [true, false] {
            f.acknowledge(by_request);
            assert_eq!(f.latched(), CAUSE_STOP_INPUT, "refused while active");
        }
        f.set_stop_input(false);
        assert!(f.holds_motion(WatchdogAction::LatchOnly), "latched: held");
        f.acknowledge(false);
        assert_eq!(f.latched(), 0);
        assert!(!f.holds_motion(WatchdogAction::StopAll));
    }

    #[test]
    fn a_res_pulse_acknowledges_a_silent_watchdog_and_disarms_it_until_a_master_speaks() {
        // The commissioning PC armed it and was unplugged: a wire-only machine's way out.
        let mut f = tripped();
        assert!(f.engaged());
        f.acknowledge(false);
        assert_eq!(f.latched(), 0, "acknowledged while the silence lasts");
        assert!(!f.engaged());
        assert_eq!(f.deadline(LIMIT), None, "disarmed");
        let late = Instant(3_600_000_000);
        assert_eq!(f.check(late, LIMIT, WatchdogAction::StopAll), None);
        // The next master's request arms it again, as at start.
        f.activity(late);
        assert_eq!(
            f.check(Instant(late.0 + 2_000_000), LIMIT, WatchdogAction::StopAll),
            Some(Trip::StopAll)
        );
        // A Modbus write acknowledges and is itself a request (armed).
        let mut f = tripped();
        f.activity(Instant(2_100_000));
        f.acknowledge(true);
        assert_eq!(f.latched(), 0);
        assert!(f.deadline(LIMIT).is_some());
    }

    #[test]
    fn a_watchdog_latch_holds_motion_only_when_its_action_stops_the_axes() {
        let f = tripped();
        assert!(f.holds_motion(WatchdogAction::StopAll));
        assert!(!f.holds_motion(WatchdogAction::LatchOnly));
    }
}
