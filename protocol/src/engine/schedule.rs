//! Polling: the status polls, position reads and probes that go between stops, resends and job frames.
//!
//! What a PLC waits for is the moment a move is seen complete, so the bus goes where that moment
//! is near, and idle axes get only as much as their bound needs. In this order (after stops and
//! resends, `Engine::next_transaction`):
//!
//! 1. **Arriving movers**, even before job frames. A mover whose arrival is estimated
//!    ([`approach`](super::approach): its start, target and acceleration time, and one position
//!    read) is polled from that moment on, for up to a cycle, the one with the oldest news of
//!    it first (its last poll in its window, or the window's opening if none since: a mover
//!    seen moving just after its estimate is nearer its band than one whose window opens now);
//!    at most [`ARRIVAL_RUN`] polls in a row before one other frame.
//! 2. Job frames, at most [`JOB_RUN`] in a row before one frame of the rules below (when
//!    they have one; never between the attempts of a frame being resent); a rejoining axis'
//!    next step (the engine), then the polls below.
//! 3. **Urgent position reads (R4 PNOW)**, not counted in the share below: a mover's estimate
//!    (half an acceleration into its cruise: a read nearer its start tells the speed least
//!    well, [`approach`](super::approach)), and an axis
//!    whose position was never read (every position register of the axis waits for it).
//! 4. **Idle axes that are due**: [`IDLE_PERIOD_CYCLES`] cycles after their last poll (a cycle
//!    is one transaction per axis that answers, at the transaction time measured on this bus:
//!    a pseudo-terminal answers faster than the wire, a slow converter slower), the longest
//!    waiting first; but not more than [`IDLE_RUN`] in a row before one of the rest.
//! 5. **Offline axes** are probed when their probe is due, with a doubling back-off from
//!    [`FIRST_PROBE`] up to [`Config::probe_interval`], so that an axis lost to a burst of noise
//!    is back quickly and a dead one costs little; the probe of an axis owed a stop is that
//!    stop. Before the movers: with one axis online its cycle is one transaction, a mover
//!    without an estimate is always due (rule 7), and the others were never probed while it
//!    moved. Now and then a
//!    probe is a rejoin try at the power-up settings instead ([`rejoin`](super::rejoin)): one
//!    such try costs up to 300 ms of bus time (9.6 kbit/s, RTIM 255 ms), so it is started only
//!    while no axis moves or runs a job (unless [`Config::rejoin_while_moving`]).
//! 6. **Other position reads**: movers (each as often as its part of the share allows, once a
//!    cycle at least; one whose arrival is or will be estimated every two cycles, the bound of
//!    an idle axis' status, as its estimate needs no more), axes that just stopped (unless their move job reads it), and axes that
//!    stopped until two reads agree (they stop in their position band, short of where they
//!    rest: [`approach`](super::approach)); at most [`Config::position_reads_per_cycle`] per
//!    cycle.
//! 7. **Status (`n`), earliest deadline first**, among the others: an idle axis, and a mover
//!    whose arrival is estimated but not near, are due [`IDLE_PERIOD_CYCLES`] cycles after
//!    their last poll; a mover whose estimate is a read away (the read goes first, rule 3)
//!    twice a cycle (a move too short to reach its speed may end before the read); a mover
//!    expected within two cycles of its last poll not before its arrival (a poll before it
//!    would only see it moving, and its status age stays within an idle axis' bound; rule 4
//!    passes it over too), and until then every other axis goes before it, due or not: the bus
//!    free now goes to idle axes, which then have a poll behind them when the movers arrive
//!    together and take the bus (it went to the mover whose arrival was nearest, five polls in
//!    a row before each arrival: `rt-bench`, 2.5 status polls a move, now 1.3); a mover whose
//!    arrival cannot be estimated (a home, a point the gateway holds no row of, a move before
//!    any `v`, one too short to reach its speed, a job without a move) or is overdue as soon
//!    as it has been polled. Ties go to the one polled longest ago, then in axis order from a
//!    rotating cursor. Work-conserving: when all are idle nobody waits for a deadline, so the
//!    axes are polled round robin at the wire limit. A job frame's answer carries the axis'
//!    status as a poll's does (complete edition §3-1-2), so it counts as one: a mover whose job
//!    sends frames is polled that much less. (A rule that polled every mover and axis with a
//!    job once a cycle, before the idle axes' deadlines, was dropped: it gave four movers four
//!    polls a cycle more than their deadlines need, which the idle axes' bound paid for.)
//!
//! Measured by `scripts/bench.sh` (scenario 5: four of 16 axes moving at 115.2 kbit/s).
//!
//! **Where the bus is short** (issue 34, `rt-bench` in docs/performance.md, its rounds from
//! "Polls that only saw a mover moving" on): direct moves at RTIM 7. A move there costs about
//! 5.2 T (`v`, `a`, the estimate's read, a status poll, the read at rest), a round of four movers
//! and the PLC's reaction about 37 T, and twelve idle axes within two cycles need 12 of every
//! 32 T, while the movers' ends and starts come together. Both targets are met there (movers
//! 2.1-2.4 T at p99, idle axes 1.88-1.90 cycles) since a mover's arrival poll finds PFIN the
//! first time in most moves ([`approach`](super::approach): it is aimed a transaction before the
//! band's edge). Before that, at 1.3 polls a move, the idle axes waited 2.03-2.13 cycles, and
//! three rules were measured and not taken; they stay out:
//! - idle axes 7/4 cycles old before job frames: every idle p99 under 1.9, but movers at RTIM 3
//!   at 3.6-3.8 T (a move's start waits, and arrivals meet);
//! - no `v` when the axis' execution area holds that velocity already (an experiment): idle 1.9
//!   at RTIM 7. The gateway would have to know the area for certain: a point move, a servo-on
//!   after a reset, a power cycle between two polls, a teaching pendant all change it, and a
//!   wrong guess moves the axis at a speed the PLC did not ask for;
//! - an idle axis 15/8 cycles old before a job frame: idle 1.90-1.94 at RTIM 7, but the virtual
//!   bench's movers 3.18 T (it moved two movers' windows onto others').
//!
//! [`Config::position_reads_per_cycle`]: super::Config::position_reads_per_cycle
//! [`Config::probe_interval`]: super::Config::probe_interval
//! [`Config::rejoin_while_moving`]: super::Config::rejoin_while_moving

use super::approach::{Approach, SETTLE_GAP};
use super::{timing, Engine, Link, Next, Origin, FIRST_PROBE};
use crate::axes::{least, AxisMap, AxisSet};
use crate::div::{div, divisor};
use crate::line::Baud;
use crate::memory::PNOW;
use crate::time::{earliest, Duration, Instant};
use crate::{Axis, Command, Request, Rtim};

/// An idle axis is due this many all-axes cycles after its last poll (as a fraction: 5/4); once
/// due, it goes before every other poll and read. The three quarters of a cycle left to its
/// bound (an idle axis' status age within two cycles) are for what still goes first (stops,
/// resends, job frames, runs of arrival polls) and for the idle axes due at the same moment:
/// with 3/2, 12 idle axes beside four movers to points overran the bound by two transactions
/// (`scripts/bench.sh`, scenario 6).
pub const IDLE_PERIOD_CYCLES: (u64, u64) = (5, 4);

/// Idle axes that are due are polled at most this many times in a row before one frame of the
/// rules after them (position reads, probes, the rest): 12, every idle
/// axis of the benchmark's four movers among 16 (scenario 6: 8 left the last ones over their
/// bound).
pub const IDLE_RUN: u8 = 12;

/// A mover is polled first from its expected arrival on, for at most this many status polls in
/// a row (among the arriving axes); then one other frame goes.
pub const ARRIVAL_RUN: u8 = 3;

/// Job frames go before polls, at most this many in a row; then polling has one turn (what the
/// rules below give, when they have anything to send). Jobs of several axes back to back (a PLC writing point rows, each
/// some twenty frames) would otherwise take the whole bus: the soak saw an axis stopped among
/// them go 4 s without a position read, and every axis' status age grew as long. With 4, a
/// fifth of a bus full of jobs is polling's: a row's write takes a quarter longer.
pub const JOB_RUN: u8 = 4;

/// When an offline axis is probed next, and the wait after an unanswered probe.
#[derive(Clone, Copy, Debug)]
struct Probe {
    due: Instant,
    backoff: Duration,
}

/// What a pass of the schedule works from ([`Engine::pass`]).
struct Pass {
    now: Instant,
    /// One status poll of every axis that answers.
    cycle: Duration,
    /// Axes that move, have a job, or were just told to move.
    hot: AxisSet,
    /// Axes whose status says they move.
    moving: AxisSet,
    /// Movers at their expected arrival (for up to a cycle), polled first.
    arriving: AxisSet,
    /// Axes that answer (or may) and are not rejoining: the ones status polls go to.
    polled: AxisSet,
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
    /// Each mover's expected arrival.
    approach: AxisMap<Approach>,
    /// Status polls in a row that went to arriving axes.
    arrival_run: u8,
    /// Polls of idle axes that were due, in a row.
    idle_run: u8,
    /// Job frames in a row ([`JOB_RUN`]).
    job_run: u8,
    /// What an answered transaction takes on this bus, measured ([`MEASURE_SHIFT`]), and the
    /// line (rate, RTIM) it was measured on: a pseudo-terminal or a USB adapter answers faster
    /// than the wire's time, a slow converter slower, and a cycle is what the bus really does.
    transaction: Duration,
    measured_on: Option<(Baud, Rtim)>,
}

/// A new transaction time counts for 1/2^3 = 1/8 of the measured one (an average over about the
/// last eight transactions: a late reply moves it little, a different bus within a cycle).
// A shift, not a division: a 64-bit division would pull 1 KB of the compiler's routines into
// the F103's flash.
pub const MEASURE_SHIFT: u32 = 3;

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
            approach: AxisMap::new(Approach::NONE),
            arrival_run: 0,
            idle_run: 0,
            job_run: 0,
            transaction: Duration::ZERO,
            measured_on: None,
        }
    }

    /// An answered transaction took `took` (command handed over to answer in, plus the host
    /// gap) on the line `on` (rate, RTIM). Another line starts the measurement again. (The line,
    /// not its nominal time, is compared: that takes two 64-bit divisions, on every answer.)
    pub(super) fn transaction_measured(&mut self, on: (Baud, Rtim), took: Duration) {
        if self.measured_on != Some(on) {
            self.measured_on = Some(on);
            self.transaction = took;
            return;
        }
        let was = self.transaction.0;
        self.transaction = Duration(was - (was >> MEASURE_SHIFT) + (took.0 >> MEASURE_SHIFT));
    }

    /// One transaction on the line `on`: as measured, or its nominal time until one is (or
    /// after the line changed).
    pub(super) fn transaction(&self, on: (Baud, Rtim)) -> Duration {
        if self.measured_on == Some(on) {
            self.transaction
        } else {
            timing::transaction_time(on.0, on.1)
        }
    }

    /// The axis' status came in at `now` in the answer to something other than a poll: its
    /// status age counts from then.
    pub(super) fn reported(&mut self, now: Instant, axis: Axis) {
        self.last_poll[axis] = now;
    }

    /// Count every axis' status age from `now` (the bus was busy with something else before).
    pub(super) fn start_cycle(&mut self, now: Instant) {
        self.last_poll.fill(now);
    }

    pub(super) fn eta(&self, axis: Axis) -> Option<Instant> {
        self.approach[axis].eta()
    }

    /// The expected arrival of the axis' move.
    pub(super) fn approach(&mut self, axis: Axis) -> &mut Approach {
        &mut self.approach[axis]
    }

    /// Read the axis' position soon.
    pub(super) fn position_due(&mut self, axis: Axis) {
        self.position_due = self.position_due.with(axis);
    }

    /// The axis left the bus: no position read of it is due and no arrival of it expected
    /// (probes and status polls go only to the axes on the bus).
    pub(super) fn forget(&mut self, axis: Axis) {
        self.position_due = self.position_due.without(axis);
        self.approach[axis].clear();
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
        self.axes[axis].moving() || self.busy(axis) || self.schedule.approach[axis].unseen()
    }

    /// One status poll of every axis that answers (or may), at the measured transaction time
    /// (the wire limit until one is measured).
    pub(super) fn cycle_time(&self) -> Duration {
        let polled = self
            .config
            .axes
            .iter()
            .filter(|&a| self.axes[a].link != Link::Offline)
            .count()
            .max(1);
        let transaction = self
            .schedule
            .transaction((self.config.baud, self.config.rtim));
        Duration(transaction.0.saturating_mul(polled as u64))
    }

    /// What one pass of the schedule looks at, worked out once (every rule below looks at every
    /// axis: this keeps a pass to a few passes over 16 axes).
    fn pass(&self, now: Instant) -> Pass {
        let cycle = self.cycle_time();
        let mut pass = Pass {
            now,
            cycle,
            hot: AxisSet::EMPTY,
            moving: AxisSet::EMPTY,
            arriving: AxisSet::EMPTY,
            polled: AxisSet::EMPTY,
        };
        for a in self.config.axes.iter() {
            if self.axes[a].link != Link::Offline && !self.rejoining(a) {
                pass.polled = pass.polled.with(a);
            }
            if self.axes[a].moving() {
                pass.moving = pass.moving.with(a);
            }
            if self.hot(a) {
                pass.hot = pass.hot.with(a);
            }
        }
        pass.arriving = self.arriving_set(now, cycle);
        pass
    }

    /// Movers at their expected arrival (for up to a `cycle`) that a status poll may go to now.
    fn arriving_set(&self, now: Instant, cycle: Duration) -> AxisSet {
        let mut set = AxisSet::EMPTY;
        for a in self.config.axes.iter() {
            // The estimate first: most axes have none, and the rest is dearer.
            let window = self.schedule.approach[a]
                .eta()
                .is_some_and(|eta| now >= eta && now <= eta + cycle);
            if window && self.hot(a) && self.axes[a].link == Link::Online && !self.job_resending(a)
            {
                set = set.with(a);
            }
        }
        set
    }

    pub(super) fn next_poll(&mut self, now: Instant) -> Option<Next> {
        let pass = self.pass(now);
        let cycle = pass.cycle;
        if now >= self.schedule.credit_refill {
            self.schedule.position_credit = self.config.position_reads_per_cycle;
            self.schedule.credit_refill = now + cycle;
        }
        let (num, den) = IDLE_PERIOD_CYCLES;
        let idle_period = Duration(cycle.0.saturating_mul(num) / den);
        // Found once, taken below by its rule: urgent first, the others after idle axes due.
        let read = self.oldest_position_due(&pass);
        if let Some((axis, true)) = read {
            return Some(self.position_read(axis));
        }
        if self.schedule.idle_run < IDLE_RUN {
            if let Some(axis) = self.idle_due(&pass, idle_period) {
                self.schedule.idle_run += 1;
                return Some(self.status_poll(now, axis));
            }
        }
        // Not forever: on a bus slower than its nominal transaction time every idle axis is
        // always due, and nothing below would ever go.
        self.schedule.idle_run = 0;
        // Before the movers: with few axes online the cycle is a transaction or two, a mover is
        // always due, and an offline axis (one owed a stop among them) was never
        // probed while another moved.
        if let Some(probe) = self.next_probe(&pass) {
            return Some(probe);
        }
        if let Some((axis, false)) = read {
            if let Some(credit) = self.schedule.position_credit.checked_sub(1) {
                self.schedule.position_credit = credit;
                return Some(self.position_read(axis));
            }
        }
        let cursor = self.schedule.cursor;
        // Arriving axes had their turn above; this is the other one.
        let others = AxisSet(pass.polled.0 & !pass.arriving.0).iter();
        let axis = least(others, |a| {
            let last = self.schedule.last_poll[a];
            let due = if !pass.hot.contains(a) {
                last + idle_period
            } else {
                let approach = &self.schedule.approach[a];
                match approach.eta() {
                    // Arriving within the idle bound: its arrival's poll is its next (above, as
                    // arriving), and one before it would only see it moving: any other axis
                    // first, even one not due (the bus is free now, and will be short when the
                    // movers arrive together).
                    Some(eta) if now < eta && self.awaited(a, cycle) => Instant(u64::MAX),
                    // Arriving later: supervised as an idle axis until then.
                    Some(eta) if now < eta => last + idle_period,
                    // Its estimate is a position read away (that goes first, half an
                    // acceleration into the cruise): meanwhile twice a cycle (a move too short
                    // to reach its speed may end before the read).
                    None if approach.needs_read() => last + Duration(cycle.0 / 2),
                    // No estimate possible (a home, a point the gateway holds no row of, a move
                    // too short to reach its speed, a job without a move: `approach`), or past
                    // its estimate: as often as the bus allows.
                    _ => last,
                }
            };
            (due, last, a.get().wrapping_sub(cursor) % 16)
        })
        .or_else(|| self.arriving(pass.arriving))?;
        Some(self.status_poll(now, axis))
    }

    /// Whether the job frame there is (`ready`) goes now: not after [`JOB_RUN`] in a row
    /// (then polling goes once, if it has anything to send), unless a frame is being resent (its
    /// attempts go with nothing else to its axis between them, §5: the axis is offline after
    /// 1 + Nrt of them). No frame ends a run.
    pub(super) fn job_turn(&mut self, ready: bool) -> bool {
        let turn = ready
            && (self.schedule.job_run < JOB_RUN
                || self.active.values().flatten().any(|a| a.attempt > 0));
        self.schedule.job_run = if turn {
            self.schedule.job_run.saturating_add(1)
        } else {
            0
        };
        turn
    }

    /// The status poll of an arriving mover, unless [`ARRIVAL_RUN`] went in a row: it goes
    /// before job frames (of other axes: a frame of its own job waits at most that long too), since
    /// it is what shows a move complete, and a new command is no later than that.
    pub(super) fn arrival_poll(&mut self, now: Instant) -> Option<Next> {
        // Most transactions have no mover past its estimate: that is found without the cycle
        // time (a pass over every axis' link, before every transaction).
        let past_estimate = |a| {
            self.schedule.approach[a]
                .eta()
                .is_some_and(|eta| now >= eta)
        };
        if self.schedule.arrival_run < ARRIVAL_RUN && self.config.axes.iter().any(past_estimate) {
            if let Some(axis) = self.arriving(self.arriving_set(now, self.cycle_time())) {
                self.schedule.arrival_run += 1;
                return Some(self.status_poll(now, axis));
            }
        }
        self.schedule.arrival_run = 0;
        None
    }

    /// The axis' status poll, counted as its last. Not inlined: four rules end in it (one
    /// call per transaction at most).
    #[inline(never)]
    fn status_poll(&mut self, now: Instant, axis: Axis) -> Next {
        self.schedule.last_poll[axis] = now;
        self.schedule.cursor = (axis.get() + 1) % 16;
        (Request::new(axis, Command::Status), Origin::Poll, 0)
    }

    /// The key that puts the axis polled longest ago first, ties in turn from the cursor.
    fn waiting_longest(&self, axis: Axis) -> (Instant, u8) {
        let cursor = self.schedule.cursor;
        (
            self.schedule.last_poll[axis],
            axis.get().wrapping_sub(cursor) % 16,
        )
    }

    /// The axis polled longest ago, if that is `limit` ago or more.
    fn idle_due(&self, pass: &Pass, limit: Duration) -> Option<Axis> {
        // One subtraction, not an addition per axis (twice a transaction, every axis).
        let since = Instant(pass.now.0.checked_sub(limit.0)?);
        let due = pass
            .polled
            .iter()
            .filter(|&a| self.schedule.last_poll[a] <= since && !self.awaited(a, pass.cycle));
        least(due, |a| self.waiting_longest(a))
    }

    /// Whether the axis' next status poll is the one at its estimated arrival: that is within
    /// two cycles of its last poll (the bound of an idle axis' status age), and a poll before
    /// it would only see it moving.
    fn awaited(&self, axis: Axis, cycle: Duration) -> bool {
        let approach = &self.schedule.approach[axis];
        let bound = self.schedule.last_poll[axis] + Duration(cycle.0.saturating_mul(2));
        approach.eta().is_some_and(|eta| eta <= bound)
    }

    /// A mover expected at its target since (for up to a `cycle`), the one with the oldest news:
    /// polled in its window longest ago, or whose window opened first if not polled in it (what
    /// shows a move complete soonest: by the last poll alone, a mover polled just after its
    /// estimate, still moving, waited behind every window opened since).
    fn arriving(&self, arriving: AxisSet) -> Option<Axis> {
        least(arriving.iter(), |a| {
            let eta = self.schedule.approach[a].eta().unwrap_or(Instant::ZERO);
            eta.max(self.schedule.last_poll[a])
        })
    }

    /// The probe (or rejoin try) of an offline axis whose time has come, earliest first.
    fn next_probe(&mut self, pass: &Pass) -> Option<Next> {
        let now = pass.now;
        loop {
            let due = self
                .config
                .axes
                .iter()
                .filter(|&a| self.axes[a].link == Link::Offline && !self.rejoining(a))
                .filter(|&a| self.schedule.probes[a].due <= now);
            let axis = least(due, |a| self.schedule.probes[a].due)?;
            // A rejoin try holds the bus up to 300 ms: only while nothing moves, by default.
            let quiet = self.config.rejoin_while_moving || pass.hot.is_empty();
            if quiet && self.start_rejoin(now, axis) {
                let max = self.config.probe_interval;
                self.schedule.probe_failed(now, axis, max);
                continue;
            }
            return Some((Request::new(axis, Command::Status), Origin::Probe, 0));
        }
    }

    /// The axis' position read (R4 PNOW), no longer due. Not inlined: two rules end in it.
    #[inline(never)]
    fn position_read(&mut self, axis: Axis) -> Next {
        self.schedule.position_due = self.schedule.position_due.without(axis);
        let read = Command::ReadMemory { address: PNOW };
        (Request::new(axis, read), Origin::Position, 0)
    }

    /// The position read to go next: urgent ones first (a mover's estimate: few per move, and
    /// they save many status polls; a position never read), which go beyond the per-cycle
    /// share, then the one read longest ago, within it; and whether it is urgent.
    fn oldest_position_due(&self, pass: &Pass) -> Option<(Axis, bool)> {
        // A mover's position is read as often as its part of the share of reads allows, once a
        // cycle at least (as a round robin of reads would).
        let share = divisor(u32::from(self.config.position_reads_per_cycle));
        let movers = pass.moving.len() as u64;
        let period = Duration(div(pass.cycle.0.saturating_mul(movers), share)).min(pass.cycle);
        // One whose arrival is estimated needs no reads for it: every two cycles, the bound of
        // an idle axis' status.
        let twice = Duration(pass.cycle.0.saturating_mul(2));
        let stale = pass.moving.iter().filter(|&a| {
            let approach = &self.schedule.approach[a];
            let period = if approach.timed() { twice } else { period };
            // (Not before its estimate's read, half an acceleration into its cruise.)
            !approach.needs_read()
                && self.axes[a]
                    .position_at
                    .is_none_or(|at| at + period <= pass.now)
        });
        // A stopped axis is read again until two reads agree (it may have stopped short, in
        // its position band), each read a gap after the last.
        let settling = self.config.axes.iter().filter(|&a| {
            self.schedule.approach[a].settling()
                && self.axes[a]
                    .position_at
                    .is_some_and(|at| at + SETTLE_GAP <= pass.now)
        });
        // A mover's estimate, half an acceleration into its cruise.
        let estimate = pass
            .hot
            .iter()
            .filter(|&a| self.schedule.approach[a].read_due(pass.now));
        let due = stale
            .chain(settling)
            .chain(estimate)
            .fold(self.schedule.position_due, AxisSet::with);
        // Urgent: a mover's estimate, and a position never read (every position register of
        // the axis waits for it).
        let urgent = |a: Axis| {
            let estimate = self.schedule.approach[a].needs_read() && pass.hot.contains(a);
            estimate || self.axes[a].position.is_none()
        };
        let online = due.iter().filter(|&a| self.axes[a].link == Link::Online);
        let axis = least(online, |a| {
            (!urgent(a), self.axes[a].position_at.map_or(0, |t| t.0))
        })?;
        Some((axis, urgent(axis)))
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Acceleration, Pulses, Velocity};

    const MS: u64 = 1_000;

    /// The axis moves 4000 pulses from 0 at 20 pulses/ms reached in 68.18 ms (`v` 7500 × 0.2
    /// rpm at 220 × 0.1 rpm/ms), its command answered at `since` ms and its position read 120
    /// ms later: its arrival is estimated about 251 ms after `since`.
    fn estimated(engine: &mut Engine, axis: Axis, since: u64) -> Instant {
        let (Some(velocity), Some(acceleration)) = (Velocity::new(7_500), Acceleration::new(220))
        else {
            panic!("the bench's motion");
        };
        let v = Command::SetVelocityAcceleration {
            velocity,
            acceleration,
        };
        let approach = engine.schedule.approach(axis);
        let at = Instant(since * MS);
        approach.command_accepted(at, &v, None, None);
        approach.command_accepted(
            at,
            &Command::MoveAbsolute(Pulses(4_000)),
            Some(Pulses(0)),
            None,
        );
        approach.position_read(
            at + Duration(120 * MS),
            Pulses(1_718),
            None,
            Duration(5 * MS),
        );
        approach.eta().unwrap_or(Instant(u64::MAX))
    }

    /// Of two movers in their arrival windows, the one whose window opened earlier and that was
    /// polled in it (too early: still moving) goes before one whose window opened since: it is
    /// nearer its band. (Taken by when each was last polled, the second went first, polled
    /// long before its window, and the first waited a transaction or two more: `rt-bench`'s
    /// point moves at RTIM 7, 3.6-3.8 T at p99.)
    #[test]
    fn an_arriving_mover_polled_in_its_window_goes_before_one_whose_window_just_opened() {
        let mut engine = Engine::new(super::super::Config::default());
        let (first, second) = (Axis::MIN, Axis::MAX);
        let first_eta = estimated(&mut engine, first, 0);
        let second_eta = estimated(&mut engine, second, 10);
        assert!(first_eta > Instant(240 * MS) && second_eta == first_eta + Duration(10 * MS));
        engine.schedule.last_poll[second] = Instant(100 * MS);
        engine.schedule.last_poll[first] = first_eta + Duration(2 * MS);
        let both = AxisSet::EMPTY.with(first).with(second);
        assert_eq!(engine.arriving(both), Some(first));
        // Polled again since the second's window opened: the second's turn.
        engine.schedule.last_poll[first] = second_eta + Duration(MS);
        assert_eq!(engine.arriving(both), Some(second));
    }
}
