//! Polling: what the engine sends when no stop, resend or job frame is waiting.
//!
//! - A bounded number of position reads (R4 PNOW, [`Config::position_reads_per_cycle`]) per
//!   status cycle, oldest first, for axes that move, just stopped or just came online.
//! - Status (`n`) round robin over the configured axes.
//! - Offline axes are probed with a doubling back-off, from [`FIRST_PROBE`] up to
//!   [`Config::probe_interval`], so that an axis lost to a burst of noise is back quickly and a
//!   dead one cannot starve live ones; now and then a probe is a rejoin try instead
//!   ([`rejoin`](super::rejoin)).
//!
//! [`Config::position_reads_per_cycle`]: super::Config::position_reads_per_cycle
//! [`Config::probe_interval`]: super::Config::probe_interval

use super::{Engine, Link, Next, Origin, FIRST_PROBE};
use crate::axes::{AxisMap, AxisSet};
use crate::memory::PNOW;
use crate::time::{earliest, Duration, Instant};
use crate::{Axis, Command, Request};

/// When an offline axis is probed next, and the wait after an unanswered probe.
#[derive(Clone, Copy, Debug)]
struct Probe {
    due: Instant,
    backoff: Duration,
}

/// The polling state.
#[derive(Clone, Copy, Debug)]
pub(super) struct Schedule {
    cursor: u8,
    position_credit: u8,
    position_due: AxisSet,
    probes: AxisMap<Probe>,
}

impl Schedule {
    pub(super) const fn new(position_reads_per_cycle: u8) -> Schedule {
        Schedule {
            cursor: 0,
            position_credit: position_reads_per_cycle,
            position_due: AxisSet::EMPTY,
            probes: AxisMap::new(Probe {
                due: Instant::ZERO,
                backoff: FIRST_PROBE,
            }),
        }
    }

    /// Read the axis' position soon.
    pub(super) fn position_due(&mut self, axis: Axis) {
        self.position_due = self.position_due.with(axis);
    }

    /// The axis stopped answering: probe it [`FIRST_PROBE`] from now.
    pub(super) fn went_offline(&mut self, now: Instant, axis: Axis) {
        self.probes[axis] = Probe {
            due: now + FIRST_PROBE,
            backoff: FIRST_PROBE,
        };
    }

    /// A probe went unanswered (or a rejoin try started): the next one after twice the last
    /// wait, up to `max`, counted from now (the end of the failed attempt).
    pub(super) fn probe_failed(&mut self, now: Instant, axis: Axis, max: Duration) {
        let probe = &mut self.probes[axis];
        probe.backoff = Duration(probe.backoff.0.saturating_mul(2)).min(max);
        probe.due = now + probe.backoff;
    }

    /// Probe the axis no sooner than `at`.
    pub(super) fn probe_at(&mut self, axis: Axis, at: Instant) {
        self.probes[axis].due = at;
    }
}

impl Engine {
    pub(super) fn next_poll(&mut self, now: Instant) -> Option<Next> {
        if self.schedule.position_credit > 0 {
            if let Some(axis) = self.oldest_position_due() {
                self.schedule.position_credit -= 1;
                self.schedule.position_due = self.schedule.position_due.without(axis);
                let read = Command::ReadMemory { address: PNOW };
                return Some((Request::new(axis, read), Origin::Position, 0));
            }
        }
        for _ in 0..16 {
            let axis = Axis::new(self.schedule.cursor)?;
            self.schedule.cursor = (self.schedule.cursor + 1) % 16;
            if self.schedule.cursor == 0 {
                self.schedule.position_credit = self.config.position_reads_per_cycle;
            }
            if !self.configured(axis) {
                continue;
            }
            if self.axes[axis].link == Link::Offline {
                if self.rejoining(axis) {
                    // Being reconfigured at the power-up rate: not there at ours.
                    continue;
                }
                if now < self.schedule.probes[axis].due {
                    continue;
                }
                if self.start_rejoin(now, axis) {
                    let max = self.config.probe_interval;
                    self.schedule.probe_failed(now, axis, max);
                    continue;
                }
                return Some((Request::new(axis, Command::Status), Origin::Probe, 0));
            }
            return Some((Request::new(axis, Command::Status), Origin::Poll, 0));
        }
        None
    }

    fn oldest_position_due(&self) -> Option<Axis> {
        self.schedule
            .position_due
            .iter()
            .filter(|&a| self.axes[a].link == Link::Online)
            .min_by_key(|&a| self.axes[a].position_at.map_or(0, |t| t.0))
    }

    /// The next moment something is due while nothing is to be sent: a probe of an offline
    /// axis, or the end of a job's wait.
    pub(super) fn next_deadline(&self) -> Option<Instant> {
        let probes = self
            .config
            .axes
            .iter()
            .filter(|&a| self.axes[a].link == Link::Offline)
            .map(|a| self.schedule.probes[a].due);
        let waits = self
            .active
            .values()
            .flatten()
            .filter_map(|a| a.wait_deadline);
        probes.chain(waits).map(Some).fold(None, earliest)
    }
}
