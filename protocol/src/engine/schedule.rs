//! Polling: what the engine sends when no stop, resend or job frame is waiting.
//!
//! What a PLC waits for is the moment a move is seen complete, so axes that move (or have a job
//! running) are polled as often as the bus allows, and idle axes only as often as they must:
//!
//! - **Status (`n`), earliest deadline first.** An axis that moves or has a job is due again as
//!   soon as it has been polled; an idle axis is due [`IDLE_PERIOD_CYCLES`] all-axes cycles after
//!   its last poll (a cycle is one transaction per axis that answers, the wire limit). The axis
//!   due first goes; ties go to the one polled longest ago, then in axis order from a rotating
//!   cursor. Work-conserving: when all are idle nobody waits for a deadline, so the axes are
//!   polled round robin at the wire limit; when some move, each idle axis still gets its poll
//!   within [`IDLE_PERIOD_CYCLES`] cycles plus a few transactions (no axis starves), and the
//!   moving ones share everything else.
//! - **Position reads (R4 PNOW)**, oldest first, for axes that move, just stopped or just came
//!   online: at most [`Config::position_reads_per_cycle`] per all-axes cycle, so that they
//!   cannot crowd out the status polls that see a move end.
//! - **Offline axes** are probed when their probe is due, with a doubling back-off from
//!   [`FIRST_PROBE`] up to [`Config::probe_interval`], so that an axis lost to a burst of noise
//!   is back quickly and a dead one costs little. Now and then a probe is a rejoin try at the
//!   power-up settings instead ([`rejoin`](super::rejoin)): one such try costs up to 300 ms of
//!   bus time (9.6 kbit/s, RTIM 255 ms), so it is started only while no axis moves or runs a job
//!   (unless [`Config::rejoin_while_moving`]).
//!
//! [`Config::position_reads_per_cycle`]: super::Config::position_reads_per_cycle
//! [`Config::probe_interval`]: super::Config::probe_interval
//! [`Config::rejoin_while_moving`]: super::Config::rejoin_while_moving

use super::{timing, Engine, Link, Next, Origin, FIRST_PROBE};
use crate::axes::{AxisMap, AxisSet};
use crate::memory::PNOW;
use crate::time::{earliest, Duration, Instant};
use crate::{Axis, Command, Request};

/// An idle axis is due this many all-axes cycles after its last poll (as a fraction: 3/2).
pub const IDLE_PERIOD_CYCLES: (u64, u64) = (3, 2);

/// When an offline axis is probed next, and the wait after an unanswered probe.
#[derive(Clone, Copy, Debug)]
struct Probe {
    due: Instant,
    backoff: Duration,
}

/// The polling state.
#[derive(Clone, Copy, Debug)]
pub(super) struct Schedule {
    /// When each axis' last status poll started.
    last_poll: AxisMap<Instant>,
    /// Where ties start (the axis after the last one polled).
    cursor: u8,
    position_credit: u8,
    /// Position credits are given again then.
    credit_refill: Instant,
    position_due: AxisSet,
    probes: AxisMap<Probe>,
}

impl Schedule {
    pub(super) const fn new(position_reads_per_cycle: u8) -> Schedule {
        Schedule {
            last_poll: AxisMap::new(Instant::ZERO),
            cursor: 0,
            position_credit: position_reads_per_cycle,
            credit_refill: Instant::ZERO,
            position_due: AxisSet::EMPTY,
            probes: AxisMap::new(Probe {
                due: Instant::ZERO,
                backoff: FIRST_PROBE,
            }),
        }
    }

    /// The same as [`Schedule::new`], in place (see `Engine::reset`).
    pub(super) fn reset(&mut self, position_reads_per_cycle: u8) {
        self.last_poll.fill(Instant::ZERO);
        self.cursor = 0;
        self.position_credit = position_reads_per_cycle;
        self.credit_refill = Instant::ZERO;
        self.position_due = AxisSet::EMPTY;
        self.probes.fill(Probe {
            due: Instant::ZERO,
            backoff: FIRST_PROBE,
        });
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
    /// Whether the axis moves or has a job running or waiting: it is polled as often as the bus
    /// allows.
    pub(super) fn hot(&self, axis: Axis) -> bool {
        self.axes[axis].moving() || self.busy(axis)
    }

    /// One status poll of every axis that answers (or may), at the wire limit.
    fn cycle_time(&self) -> Duration {
        let polled = self
            .config
            .axes
            .iter()
            .filter(|&a| self.axes[a].link != Link::Offline)
            .count()
            .max(1);
        let transaction = timing::transaction_time(self.config.baud, self.config.rtim);
        Duration(transaction.0.saturating_mul(polled as u64))
    }

    pub(super) fn next_poll(&mut self, now: Instant) -> Option<Next> {
        let cycle = self.cycle_time();
        if now >= self.schedule.credit_refill {
            self.schedule.position_credit = self.config.position_reads_per_cycle;
            self.schedule.credit_refill = now + cycle;
        }
        if self.schedule.position_credit > 0 {
            if let Some(axis) = self.oldest_position_due() {
                self.schedule.position_credit -= 1;
                self.schedule.position_due = self.schedule.position_due.without(axis);
                let read = Command::ReadMemory { address: PNOW };
                return Some((Request::new(axis, read), Origin::Position, 0));
            }
        }
        if let Some(probe) = self.next_probe(now) {
            return Some(probe);
        }
        let (num, den) = IDLE_PERIOD_CYCLES;
        let idle_period = Duration(cycle.0.saturating_mul(num) / den);
        let cursor = self.schedule.cursor;
        let axis = self
            .config
            .axes
            .iter()
            .filter(|&a| self.axes[a].link != Link::Offline && !self.rejoining(a))
            .min_by_key(|&a| {
                let last = self.schedule.last_poll[a];
                let due = if self.hot(a) {
                    last
                } else {
                    last + idle_period
                };
                (due, last, a.get().wrapping_sub(cursor) % 16)
            })?;
        self.schedule.last_poll[axis] = now;
        self.schedule.cursor = (axis.get() + 1) % 16;
        Some((Request::new(axis, Command::Status), Origin::Poll, 0))
    }

    /// The probe (or rejoin try) of an offline axis whose time has come, earliest first.
    fn next_probe(&mut self, now: Instant) -> Option<Next> {
        loop {
            let axis = self
                .config
                .axes
                .iter()
                .filter(|&a| self.axes[a].link == Link::Offline && !self.rejoining(a))
                .filter(|&a| self.schedule.probes[a].due <= now)
                .min_by_key(|&a| self.schedule.probes[a].due)?;
            // A rejoin try holds the bus up to 300 ms: only while nothing moves, by default.
            let quiet =
                self.config.rejoin_while_moving || !self.config.axes.iter().any(|a| self.hot(a));
            if quiet && self.start_rejoin(now, axis) {
                let max = self.config.probe_interval;
                self.schedule.probe_failed(now, axis, max);
                continue;
            }
            return Some((Request::new(axis, Command::Status), Origin::Probe, 0));
        }
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
