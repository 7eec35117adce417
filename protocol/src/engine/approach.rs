//! When a moving axis will arrive: the estimate that lets the schedule poll a mover's status
//! around the moment its move completes, and rarely before.
//!
//! A status poll is what shows a move complete (PEND/PFIN in the OUT byte, complete edition
//! §4-3-1), so the sooner one follows the completion, the sooner the PLC sees it. Polling every
//! mover all the time cannot do it with several movers (four movers polled in turn: each every
//! four transactions at best, and idle axes starved); polling a mover when it is about to arrive
//! can. The estimate comes from what the engine sees anyway, modelled as the controller moves:
//! an even acceleration from a standstill, a cruise, and a braking as long as the acceleration
//! (complete edition §7-2-1, MXAC 0):
//!
//! - the target of the move command it sent (`a` absolute, `m` relative, complete edition
//!   §4-4-8/§4-4-11; a point's position from the gateway's cached row);
//! - where the axis started: where it rested at the command, or the target of the move before
//!   if that one was seen complete and its axis not read at rest yet;
//! - how long it accelerates: `2 × velocity / acceleration` ms, from the last `v` (0.2 rpm and
//!   0.1 rpm/ms, §4-4-20, whatever the lead and the encoder) or the cached row's VCMD and ACMD
//!   (§7-2-2) of the point it moves to;
//! - one position read (R4 PNOW) half an acceleration time into the cruise (a read right at
//!   the end of the acceleration divides the distance by half an acceleration time, so that a
//!   start a few milliseconds late in the host's timing put the arrival 4 transactions late:
//!   `rt-bench`, point moves at RTIM 7; half an acceleration later the error is halved, and a
//!   read that lands in the braking is known by the end it gives, and gives none). With the
//!   acceleration time known, the distance covered gives the speed, and the speed the end: the
//!   whole distance at that speed plus one acceleration time ([`trapezoid_end`]). A read is
//!   timed by its answer, as the command is: each is a transaction after its controller took
//!   it, so the time between them is right (timing the command by its request made every
//!   estimate a transaction late).
//!
//! The estimate aims where a poll finds PFIN. PFIN comes when the braking enters the position
//! band, before the target (§4-3-1): `sqrt(2 × band / deceleration)` before the end
//! ([`band_edge`], a band of [`BAND`]). The end counts from the command's answer, which came
//! RTIM and a reply's wire time after the controller took the command and started; a poll sees
//! the status when its request reaches the controller, a request's wire time after it is sent.
//! Together that is one transaction (as measured on the bus), so the poll is sent a transaction
//! before the band's edge, and a quarter transaction later for the estimate's errors of a few
//! milliseconds (the host's timing): a poll too early costs a whole transaction, one too late
//! only the lateness. The aim before, a quarter of the acceleration time before the end, held
//! both by chance: it was 4 ms after the band in the virtual bench (a 34 ms acceleration) and a
//! transaction before it in `rt-bench`'s (68 ms), where a third of the moves at RTIM 7 were
//! polled twice (docs/performance.md, "A spare read, a rule tried, and where the aim lands").
//!
//! A move the gateway cannot model (a home, a point whose row it does not hold or whose
//! motion comes from the common parameters, a move before any `v`, one too short to reach its
//! speed) has no estimate, and the schedule polls its axis as often as the bus allows. (An
//! earlier model took the speed between reads without the acceleration time: a read in the
//! acceleration made it up to 7 transactions early or late, docs/performance.md.) A mover whose
//! command was accepted counts as moving until a status says otherwise (`unseen`): its last
//! status, from before the command, says it stands.
//!
//! A move ends in its position band, not at rest, so the estimate's last duty is the stop: the
//! stopped axis is read again until two reads agree ([`SETTLE_READS`]), or one finds it at the
//! move's target (a trapezoid ends at rest there), so that the position the PLC sees is where
//! the axis came to rest.

use core::num::NonZeroU32;

use crate::div::{div, divisor};
use crate::time::{Duration, Instant};
use crate::{Acceleration, Command, Pulses, Velocity};

use super::job::PointAim;

/// What the engine expects of one axis' move.
#[derive(Clone, Copy, Debug)]
pub(super) struct Approach {
    /// Where the move in progress goes, if a command the engine sent says so.
    target: Option<Pulses>,
    /// When its command was answered: position reads before it belong to an earlier move.
    since: Instant,
    /// Where the move started, if known (the module's doc). Once it stopped at its target,
    /// that target: a read there finds it at rest, and the next move starts there.
    start: Option<Pulses>,
    /// When it is expected at its target, if `eta_known`.
    // Not an `Option<Instant>`: 8 bytes more per axis, in a node the F103 budget holds to the
    // byte.
    eta: Instant,
    eta_known: bool,
    /// Position reads since the command: bounds the reads an estimate may ask for.
    reads: u8,
    /// A move command was accepted and no status seen since: the axis moves although its last
    /// status says it stands.
    unseen: bool,
    /// Position reads left to find where a stopped axis came to rest ([`SETTLE_READS`]).
    settle_reads: u8,
    /// How long the axis accelerates to its speed, µs (0: not known): what the velocity and
    /// acceleration of its execution area make of it ([`ramp_time`]), from the last `v` or
    /// the cached row of the point it moved to. Kept from move to move.
    ramp: u32,
}

/// The position reads a move's estimate may ask for beyond the per-cycle share: one, and one
/// spare for a read that came too early (the axis had not started yet).
const ESTIMATE_READS: u8 = 2;

/// The position reads that may follow a stop until two in a row agree, each at least
/// [`SETTLE_GAP`] after the one before. A controller reports positioning complete (PFIN) when the
/// axis enters its position band (complete edition §4-3-1, INP), while it still travels the
/// rest of the band: the read that ends a move can be up to a band short of where the axis
/// stops, and an idle axis' position is not read otherwise. Bounded, so that a servo hunting
/// a pulse either side costs nothing for long.
const SETTLE_READS: u8 = 8;

/// The least time between two reads of a settling axis, so that two reads agree only when the
/// axis has rested in between: the last half pulse of a deceleration takes 5 ms at ACMD 30
/// (0.04 pulse/ms², complete edition §7-2-2, §8-2), 27 ms at the lowest (ACMD 1).
pub(super) const SETTLE_GAP: Duration = Duration::from_millis(20);

impl Approach {
    pub(super) const NONE: Approach = Approach {
        target: None,
        since: Instant::ZERO,
        start: None,
        eta: Instant::ZERO,
        eta_known: false,
        reads: 0,
        unseen: false,
        settle_reads: 0,
        ramp: 0,
    };

    /// A command answered at `now` was accepted, with the position last read (for a relative
    /// move) and, for a move to a point, what its job knows of the point. A move starts an
    /// estimate; a `v` sets the acceleration time of the moves after it; other commands leave
    /// the estimate alone.
    // Not inlined into the reply handler: some 200 B of the F103's flash for the three.
    #[inline(never)]
    pub(super) fn command_accepted(
        &mut self,
        now: Instant,
        command: &Command,
        at: Option<Pulses>,
        point: Option<PointAim>,
    ) {
        let target = match *command {
            Command::MoveAbsolute(to) => Some(to),
            Command::MoveRelative(by) => at.map(|from| Pulses(from.0.saturating_add(by.0))),
            // A point's position is not in the command: only if its job knows it. Its row's
            // velocity and acceleration are now the execution area's (complete edition §7-3-2),
            // or the common defaults when its flags say so, which the gateway does not know.
            Command::MoveToPoint(_) => {
                self.ramp = point
                    .and_then(|p| p.motion)
                    .map_or(0, |(v, a)| ramp_time(v, a));
                point.map(|p| p.position)
            }
            // A home's is not known: no estimate.
            Command::Home(_) => None,
            Command::SetVelocityAcceleration {
                velocity,
                acceleration,
            } => {
                self.ramp = ramp_time(velocity, acceleration);
                return;
            }
            _ => return,
        };
        // Where the axis rests, if it does: a position read while the last move was still
        // ending is not where this one starts. Seen complete and not read at rest yet, it is in
        // the band of the target it went to, a band's width from where it rests: its start as
        // near as the gateway knows it (the PLC gives the next move as soon as it sees PEND,
        // before the read at rest: `rt-bench`).
        let rested = self.target.is_none() && !self.unseen && self.settle_reads == 0;
        let start = if rested {
            at
        } else {
            self.start.filter(|_| self.settling())
        };
        *self = Approach {
            target,
            since: now,
            start,
            eta: Instant::ZERO,
            eta_known: false,
            reads: 0,
            unseen: true,
            settle_reads: 0,
            ramp: self.ramp,
        };
    }

    /// A position read answered at `now` (`position`), after the one before (`previous`), on a
    /// bus whose transactions take `transaction`: the estimate, or a step of the settling after
    /// a stop.
    // Not inlined into the reply handler: some 200 B of the F103's flash for the three.
    #[inline(never)]
    pub(super) fn position_read(
        &mut self,
        now: Instant,
        position: Pulses,
        previous: Option<Pulses>,
        transaction: Duration,
    ) {
        let Some(target) = self.target else {
            // Stopped (or a move without a target, where nothing settles): at rest once a read
            // agrees with the one before, or finds it at its target (a trapezoid's speed is nil
            // there: one read less after most moves).
            if let Some(left) = self.settle_reads.checked_sub(1) {
                let agrees = previous == Some(position) || self.start == Some(position);
                self.settle_reads = if agrees { 0 } else { left };
            }
            return;
        };
        self.reads = self.reads.saturating_add(1);
        let Some(start) = self.start else {
            return;
        };
        // Once it may brake (a ramp before the end; the aim is before the end) a read would
        // give a speed too low: the estimate stands.
        if self.eta_known && now + Duration(u64::from(self.ramp)) > self.eta {
            return;
        }
        let t = u32::try_from(now.0.saturating_sub(self.since.0)).unwrap_or(u32::MAX);
        match trapezoid_end(start, position, target, self.ramp, t) {
            Some(end) => {
                let distance = target.0.abs_diff(start.0);
                let edge = band_edge(distance, self.ramp, end - u64::from(self.ramp));
                // A poll finds PFIN if its request reaches the controller after the band's
                // edge: sent a transaction (the command's answer's lag, `since` counts from it,
                // and the request's wire time) before the edge, and a quarter transaction
                // later, for the estimate's errors (a poll too early costs a transaction).
                let early = u64::from(edge) + transaction.0 - transaction.0 / 4;
                self.eta = self.since + Duration(end.saturating_sub(early));
                self.eta_known = true;
            }
            // Under way a ramp after its command and still no estimate: in its braking, or a
            // move too short to reach its speed. A later read is no better (deeper in the
            // braking), so the spare read is not asked for: it went before the idle axes due,
            // four movers' in a row (`rt-bench`, direct moves at RTIM 7).
            None if t >= self.ramp && position != start => self.reads = ESTIMATE_READS,
            None => {}
        }
    }

    /// A `t` started the move this axis had buffered, at `now`: it moves, although its last
    /// status (from before the `t`) says it stands, until a status says otherwise. Without
    /// this a buffered move that ended between two polls, or was stopped before one, was never
    /// seen to stop, and its position never read (found by the firmware soak).
    pub(super) fn started(&mut self, now: Instant) {
        self.since = now;
        self.unseen = true;
    }

    /// A command that can start a move went to the axis and its answer was lost: the axis may
    /// move, so it counts as moving until a status says otherwise, as after
    /// [`started`](Self::started), the estimate left alone.
    pub(super) fn may_have_started(&mut self) {
        self.unseen = true;
    }

    /// A status report came in: from now on it says whether the axis moves.
    pub(super) fn status_seen(&mut self) {
        self.unseen = false;
    }

    /// Whether a move was commanded since the last status report.
    pub(super) fn unseen(&self) -> bool {
        self.unseen
    }

    /// Whether its arrival can be estimated (the module's doc), and is not yet: a read
    /// would give it.
    pub(super) fn needs_read(&self) -> bool {
        self.timed() && !self.eta_known && self.reads < ESTIMATE_READS
    }

    /// Whether its position is to be read at `now` for the estimate: it needs one, and it is
    /// half an acceleration into its cruise (a read nearer the start tells the speed least
    /// well: the module's doc).
    pub(super) fn read_due(&self, now: Instant) -> bool {
        self.needs_read() && now >= self.since + Duration(u64::from(self.ramp / 2 * 3))
    }

    /// Whether its arrival can be estimated: its start, target and acceleration time are known.
    pub(super) fn timed(&self) -> bool {
        self.target.is_some() && self.start.is_some() && self.ramp > 0
    }

    /// The axis is not moving any more (or never started): nothing to expect.
    pub(super) fn clear(&mut self) {
        *self = Approach {
            ramp: self.ramp,
            ..Approach::NONE
        };
    }

    /// The axis stopped (`arrived`: positioning complete, in its target's band): nothing to
    /// expect of its move, but its position is read until it rests ([`SETTLE_READS`]).
    // Not inlined into the reply handler: some 200 B of the F103's flash for the three.
    #[inline(never)]
    pub(super) fn stopped(&mut self, arrived: bool) {
        *self = Approach {
            settle_reads: SETTLE_READS,
            start: self.target.filter(|_| arrived),
            ramp: self.ramp,
            ..Approach::NONE
        };
    }

    /// A stop (`d`) was accepted: the move ends short of its target, and is not expected there.
    pub(super) fn cancelled(&mut self) {
        self.target = None;
        self.eta_known = false;
    }

    /// Whether the axis stopped and its position has not been seen to rest yet.
    pub(super) fn settling(&self) -> bool {
        self.settle_reads > 0
    }

    /// When the axis is expected at its target, if that is known.
    pub(super) fn eta(&self) -> Option<Instant> {
        self.eta_known.then_some(self.eta)
    }
}

/// The position band the arrival is aimed at, in pulses: 0.1 mm at 100 pulses/mm, the band of
/// the brief edition's worked example ("Enter New Point in Point Table", 0.1 mm) and of the
/// controllers' factory parameters as the simulator has them. The gateway neither reads the
/// axis' INP (complete edition §7-2-1) nor takes a point row's band (§7-2-2). A band twice as
/// wide is entered `sqrt(2)` times as early, 3.4 ms sooner at 0.3 G: the poll at the aim sees
/// PFIN that much after it came. A narrower one is entered later, and a poll before it costs
/// one more.
const BAND: u64 = 10;

/// How long before the end of a move (µs) its braking enters the position band ([`BAND`]), PFIN
/// (§4-3-1): `sqrt(2 × band / deceleration)`, the deceleration `distance / at_speed / ramp`
/// (pulses/µs²; `at_speed`: the whole distance at its speed, µs).
fn band_edge(distance: u32, ramp: u32, at_speed: u64) -> u32 {
    let square = div(
        (2 * BAND * u64::from(ramp)).saturating_mul(at_speed),
        divisor(distance),
    );
    isqrt(u32::try_from(square).unwrap_or(u32::MAX))
}

/// The integer square root, digit by digit (core's `isqrt` brings a table the F103's flash has
/// no room for).
fn isqrt(n: u32) -> u32 {
    let (mut rest, mut root, mut bit) = (n, 0u32, 1u32 << 30);
    while bit > n {
        bit >>= 2;
    }
    while bit != 0 {
        if rest >= root + bit {
            rest -= root + bit;
            root = (root >> 1) + bit;
        } else {
            root >>= 1;
        }
        bit >>= 2;
    }
    root
}

/// The acceleration time (µs) of a move at `velocity` (0.2 rpm) reached at `acceleration`
/// (0.1 rpm/ms): 2 × velocity / acceleration ms, whatever the lead and the encoder (complete
/// edition §4-4-20, `v`; the same units as a point's VCMD and ACMD, §7-2-2).
fn ramp_time(velocity: Velocity, acceleration: Acceleration) -> u32 {
    2_000 * u32::from(velocity.get()) / u32::from(acceleration.get()).max(1)
}

/// When (µs after its start) a move from `start` to `target` ends, from a read at `position`
/// `t` µs after its start, if it accelerates evenly for `ramp` µs to its speed, cruises, and
/// brakes as long (MXAC 0, complete edition §7-2-1); `None` if the read tells nothing: before
/// half its acceleration (where the transaction's part of `t` weighs most), away from the
/// target, in the braking (by the end it would give), or a move too short to reach its speed.
fn trapezoid_end(
    start: Pulses,
    position: Pulses,
    target: Pulses,
    ramp: u32,
    t: u32,
) -> Option<u64> {
    let covered = NonZeroU32::new(position.0.abs_diff(start.0))?;
    if ramp == 0 || t < ramp / 2 || (position.0 > start.0) != (target.0 > start.0) {
        return None;
    }
    let distance = u64::from(target.0.abs_diff(start.0));
    // The time the whole distance takes at its speed (its cruise plus one ramp).
    let at_speed = if t >= ramp {
        // Cruising: covered = speed × (t − ramp / 2).
        div(distance * u64::from(t - ramp / 2), covered)
    } else {
        // Accelerating: covered = speed × t² / (2 ramp).
        let half = div(distance * u64::from(t / 2), covered);
        div(half.saturating_mul(u64::from(t)), divisor(ramp))
    };
    // Reaching its speed and braking from it take a ramp's distance. A read the estimate puts
    // after the braking's start (`at_speed` after the start) was in it: a speed too low.
    (at_speed >= u64::from(ramp) && u64::from(t) <= at_speed).then(|| at_speed + u64::from(ramp))
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000;

    /// A bus that takes no time: the arrival is aimed at the band's edge itself.
    const INSTANT: Duration = Duration(0);

    /// A transaction at RTIM 7 over a pseudo-terminal (`rt-bench`).
    const RTIM_7: Duration = Duration(8_400);

    /// How long before the end a trapezoid at `speed` (pulses/ms) reached in `ramp` ms enters
    /// a band of [`BAND`] pulses, ms: found by walking the braking, not by `band_edge`'s formula.
    fn band_entry(speed: f64, ramp: f64) -> f64 {
        let deceleration = speed / ramp;
        let mut before = 0.0;
        while deceleration * before * before / 2.0 <= BAND as f64 {
            before += 0.01;
        }
        before
    }

    /// Where a trapezoidal move from 0 to `distance` is at `t` ms: accelerating evenly for
    /// `ramp` ms to `speed` pulses/ms, cruising, braking as long as it accelerated.
    fn trapezoid(distance: f64, speed: f64, ramp: f64, t: f64) -> i32 {
        let end = distance / speed + ramp;
        let a = speed / ramp;
        let p = if t <= ramp {
            a * t * t / 2.0
        } else if t <= end - ramp {
            speed * (t - ramp / 2.0)
        } else if t < end {
            distance - a * (end - t) * (end - t) / 2.0
        } else {
            distance
        };
        p.round() as i32
    }

    /// rt-bench's `v`: 20 pulses/ms (7500 × 0.2 rpm at 800 pulses a turn) reached in 68.18 ms
    /// (ACMD 220: 2 × 7500 / 220 ms).
    fn bench_motion() -> Option<(Velocity, Acceleration)> {
        Some((Velocity::new(7_500)?, Acceleration::new(220)?))
    }

    /// The `v` of [`bench_motion`].
    fn bench_v() -> Command {
        bench_motion().map_or(Command::Status, |(velocity, acceleration)| {
            Command::SetVelocityAcceleration {
                velocity,
                acceleration,
            }
        })
    }

    /// An axis moving to `to` from `at` after [`bench_v`], both answered at 0.
    fn moving(to: i32, at: Option<i32>) -> Approach {
        let mut a = Approach::NONE;
        a.command_accepted(Instant(0), &bench_v(), None, None);
        a.command_accepted(
            Instant(0),
            &Command::MoveAbsolute(Pulses(to)),
            at.map(Pulses),
            None,
        );
        a
    }

    #[test]
    fn no_estimate_without_a_target_a_start_an_acceleration_time_or_progress() {
        let mut a = Approach::NONE;
        let point = Command::MoveToPoint(crate::PositionNo::MIN);
        a.command_accepted(Instant(0), &point, Some(Pulses(0)), None);
        a.position_read(Instant(80 * MS), Pulses(1_000), None, INSTANT);
        assert_eq!(a.eta(), None, "a point's position is unknown here");
        // Known to its job (the gateway's cached row), but its motion from the common
        // parameters: no acceleration time.
        let row = |motion| {
            Some(PointAim {
                position: Pulses(4_000),
                motion,
            })
        };
        a.command_accepted(Instant(0), &point, Some(Pulses(0)), row(None));
        a.position_read(Instant(80 * MS), Pulses(1_000), None, INSTANT);
        assert!(a.eta().is_none() && !a.timed());
        // With its own: estimated as an `a` after a `v` is.
        let motion = bench_motion();
        a.clear();
        a.command_accepted(Instant(0), &point, Some(Pulses(0)), row(motion));
        let at = |t| Pulses(trapezoid(4_000.0, 20.0, 68.18, t));
        a.position_read(Instant(80 * MS), at(80.0), None, INSTANT);
        assert!(a.eta().is_some());
        // The same `a` without a start (the axis was not seen at rest): none.
        a.command_accepted(
            Instant(0),
            &Command::MoveAbsolute(Pulses(4_000)),
            None,
            None,
        );
        a.position_read(Instant(80 * MS), at(80.0), None, INSTANT);
        assert_eq!(a.eta(), None, "no start");
        // From a known start: not while it stands, nor while it moves away.
        a.clear();
        a.command_accepted(
            Instant(0),
            &Command::MoveAbsolute(Pulses(4_000)),
            Some(Pulses(0)),
            None,
        );
        a.position_read(Instant(80 * MS), Pulses(0), None, INSTANT);
        assert_eq!(a.eta(), None, "standing still");
        a.position_read(Instant(90 * MS), Pulses(-5), None, INSTANT);
        assert_eq!(a.eta(), None, "moving away");
        assert!(!a.needs_read(), "two reads spent");
        a.clear();
        assert_eq!(a.eta(), None);
    }

    /// A position read of a stopped axis at `position`, `before` the read before.
    fn read(a: &mut Approach, position: i32, before: i32) {
        a.position_read(Instant(0), Pulses(position), Some(Pulses(before)), INSTANT)
    }

    #[test]
    fn a_stopped_axis_read_at_its_target_rests_there() {
        let mut a = Approach::NONE;
        a.command_accepted(
            Instant(0),
            &Command::MoveAbsolute(Pulses(5_000)),
            Some(Pulses(0)),
            None,
        );
        a.stopped(true);
        read(&mut a, 4_994, 3_000);
        assert!(a.settling(), "short of its target, in its band");
        read(&mut a, 5_000, 4_994);
        assert!(!a.settling(), "at its target: one read, not two that agree");
        // A stop without a target (a home's, a point's the job does not know) needs two.
        a.stopped(true);
        read(&mut a, 5_000, 4_994);
        assert!(a.settling());
    }

    #[test]
    fn a_stopped_axis_settles_when_two_reads_agree_or_after_its_reads() {
        let mut a = Approach::NONE;
        assert!(!a.settling(), "not stopped");
        a.stopped(true);
        assert!(a.settling());
        read(&mut a, 4_994, 3_000);
        read(&mut a, 5_000, 4_994);
        assert!(a.settling(), "still moving in its band");
        read(&mut a, 5_000, 5_000);
        assert!(!a.settling(), "two reads agree");
        // A servo hunting a pulse either side: read no more than SETTLE_READS times.
        a.stopped(true);
        for i in 0..SETTLE_READS {
            assert!(a.settling(), "read {i}");
            read(
                &mut a,
                5_000 + i32::from(i % 2),
                5_000 + i32::from((i + 1) % 2),
            );
        }
        assert!(!a.settling());
        // A new move ends it.
        a.stopped(true);
        a.command_accepted(Instant(0), &Command::MoveAbsolute(Pulses(0)), None, None);
        assert!(!a.settling());
    }

    #[test]
    fn one_read_and_the_acceleration_time_give_the_end_of_the_move() {
        // rt-bench's moves: 4000 pulses, 268.18 ms in all.
        let (distance, speed, ramp) = (4_000.0, 20.0, 68.18);
        let end = distance / speed + ramp;
        for t in [40.0, 70.0, 120.0, 180.0] {
            let mut a = moving(4_000, Some(0));
            // Half an acceleration into the cruise (102 ms), not at its start.
            assert!(!a.read_due(Instant(100 * MS)), "too near its acceleration");
            assert!(a.read_due(Instant(103 * MS)));
            let now = Instant((t * 1_000.0) as u64);
            a.position_read(
                now,
                Pulses(trapezoid(distance, speed, ramp, t)),
                None,
                INSTANT,
            );
            // Aimed where the braking enters the band, within a millisecond (a pulse read
            // early in the acceleration weighs most; a transaction takes 4 ms or more).
            let eta = a.eta().map(|eta| eta.0 as f64 / 1_000.0);
            let aim = end - band_entry(speed, ramp);
            assert!(
                eta.is_some_and(|eta| (eta - aim).abs() < 1.0),
                "read at {t} ms: {eta:?}, not {aim}"
            );
            assert!(!a.needs_read());
            // A read once it brakes (its speed lower) leaves the estimate as it is.
            let late = Instant(250 * MS);
            a.position_read(
                late,
                Pulses(trapezoid(distance, speed, ramp, 250.0)),
                None,
                INSTANT,
            );
            assert_eq!(a.eta().map(|eta| eta.0 as f64 / 1_000.0), eta);
        }
        // Backwards, from a relative move.
        let mut a = Approach::NONE;
        a.command_accepted(Instant(0), &bench_v(), None, None);
        a.command_accepted(
            Instant(0),
            &Command::MoveRelative(Pulses(-4_000)),
            Some(Pulses(4_000)),
            None,
        );
        a.position_read(
            Instant(100 * MS),
            Pulses(4_000 - trapezoid(distance, speed, ramp, 100.0)),
            None,
            INSTANT,
        );
        assert!(a
            .eta()
            .is_some_and(
                |eta| (eta.0 as f64 / 1_000.0 - (end - band_entry(speed, ramp))).abs() < 1.0
            ));
        // Before half its ramp a read tells too little: no estimate, and another read is due.
        let mut a = moving(4_000, Some(0));
        a.position_read(
            Instant(20 * MS),
            Pulses(trapezoid(distance, speed, ramp, 20.0)),
            None,
            INSTANT,
        );
        assert!(a.eta().is_none() && a.needs_read());
        // A move too short to reach its speed (a triangle: under 1364 pulses) is not a
        // trapezoid: no estimate.
        let mut a = moving(600, Some(0));
        a.position_read(
            Instant(60 * MS),
            Pulses(trapezoid(distance, speed, ramp, 60.0)),
            None,
            INSTANT,
        );
        assert!(a.eta().is_none());
    }

    /// A read in the braking tells nothing (taken as a cruise, it gives a speed too low and an
    /// arrival too late): a read that the estimate it would give puts after the braking's start
    /// is not one. A read late in the cruise still gives the end.
    #[test]
    fn a_read_in_the_braking_gives_no_estimate() {
        let (distance, speed, ramp) = (4_000.0, 20.0, 68.18);
        let read = |t: f64| {
            let mut a = moving(4_000, Some(0));
            let at = Pulses(trapezoid(distance, speed, ramp, t));
            a.position_read(Instant((t * 1_000.0) as u64), at, None, INSTANT);
            a.eta()
        };
        // The braking starts at 200 ms.
        assert!(read(195.0).is_some());
        for t in [205.0, 230.0, 260.0] {
            assert_eq!(read(t), None, "read at {t} ms");
        }
    }

    /// A read that found the axis not yet started leaves a spare read; one in the braking
    /// leaves none, since a later one would be deeper in it (the spare went before the idle
    /// axes, four movers' in a row).
    #[test]
    fn only_a_read_before_the_start_asks_for_a_spare() {
        let (distance, speed, ramp) = (4_000.0, 20.0, 68.18);
        let after = |t: f64, at: i32| {
            let mut a = moving(4_000, Some(0));
            a.position_read(Instant((t * 1_000.0) as u64), Pulses(at), None, INSTANT);
            a.needs_read()
        };
        assert!(after(102.0, 0), "not started: the spare read");
        let braking = trapezoid(distance, speed, ramp, 230.0);
        assert!(!after(230.0, braking), "in the braking: no spare");
    }

    #[test]
    fn isqrt_is_the_floor_of_the_square_root() {
        for n in (0..70_000u32).chain([u32::MAX, u32::MAX - 1, 1 << 30, (1 << 30) - 1]) {
            assert_eq!(isqrt(n), n.isqrt(), "{n}");
        }
    }

    /// The arrival is aimed so that a poll's request reaches the controller just after the
    /// braking enters the band: a transaction before the band's edge (the command's answer came
    /// that much after the move started, and the request takes its wire time), plus a quarter
    /// transaction. The old aim, a quarter of the acceleration before the end or three
    /// transactions if less, was 4 ms late in the virtual bench (a 34 ms acceleration) and a
    /// transaction early in rt-bench's (68 ms).
    #[test]
    fn the_arrival_is_aimed_a_transaction_before_the_band_and_a_quarter() {
        for (speed, ramp) in [(20.0_f64, 68.18_f64), (10.0, 34.09), (2.0, 68.18)] {
            let distance = 8_000.0;
            let end = distance / speed + ramp;
            // Mid-cruise: a pulse's rounding weighs least there.
            let read_at = end / 2.0;
            let mut a = Approach::NONE;
            let mut v = Command::Status;
            if let (Some(velocity), Some(acceleration)) = (
                Velocity::new((speed * 375.0) as u16),
                Acceleration::new((2.0 * speed * 375.0 / ramp).round() as u16),
            ) {
                v = Command::SetVelocityAcceleration {
                    velocity,
                    acceleration,
                };
            }
            a.command_accepted(Instant(0), &v, None, None);
            a.command_accepted(
                Instant(0),
                &Command::MoveAbsolute(Pulses(8_000)),
                Some(Pulses(0)),
                None,
            );
            let read = Pulses(trapezoid(distance, speed, ramp, read_at));
            a.position_read(Instant((read_at * 1_000.0) as u64), read, None, RTIM_7);
            let aim = end - band_entry(speed, ramp) - 8.4 + 8.4 / 4.0;
            let eta = a.eta().map_or(f64::NAN, |eta| eta.0 as f64 / 1_000.0);
            assert!(
                (eta - aim).abs() < 1.0,
                "{speed} pulses/ms: {eta} ms, not {aim}"
            );
        }
    }

    #[test]
    fn the_next_move_starts_where_the_last_arrived_unless_a_stop_ended_it() {
        let mut a = Approach::NONE;
        let v = Command::SetVelocityAcceleration {
            velocity: Velocity::MAX,
            acceleration: Acceleration::MIN,
        };
        a.command_accepted(Instant(0), &v, None, None);
        a.command_accepted(
            Instant(0),
            &Command::MoveAbsolute(Pulses(4_000)),
            Some(Pulses(0)),
            None,
        );
        assert!(a.timed());
        // Seen complete, not read at rest yet (in its band): it starts at the last target.
        a.stopped(true);
        a.command_accepted(
            Instant(1),
            &Command::MoveAbsolute(Pulses(0)),
            Some(Pulses(3_990)),
            None,
        );
        assert!(a.timed(), "the arrived target is the start");
        // Stopped short (a `d`, an alarm): where it is is not known until it rests.
        a.cancelled();
        a.stopped(true);
        a.command_accepted(
            Instant(2),
            &Command::MoveAbsolute(Pulses(4_000)),
            Some(Pulses(2_000)),
            None,
        );
        assert!(!a.timed());
        a.stopped(false);
        a.command_accepted(
            Instant(3),
            &Command::MoveAbsolute(Pulses(0)),
            Some(Pulses(2_000)),
            None,
        );
        assert!(!a.timed());
    }

    #[test]
    fn other_commands_keep_the_estimate_and_extremes_do_not_overflow() {
        let mut a = Approach::NONE;
        let slowest = Command::SetVelocityAcceleration {
            velocity: Velocity::MAX,
            acceleration: Acceleration::MIN,
        };
        a.command_accepted(Instant(u64::MAX - 1), &slowest, None, None);
        let far = Command::MoveAbsolute(Pulses(i32::MAX));
        a.command_accepted(Instant(u64::MAX - 1), &far, Some(Pulses(i32::MIN)), None);
        a.position_read(Instant(u64::MAX), Pulses(i32::MIN + 1), None, INSTANT);
        assert_eq!(a.eta(), None, "a microsecond in: not half its ramp");
        // (At rest again: the start is where it was read.)
        a.clear();
        a.command_accepted(Instant(0), &far, Some(Pulses(i32::MIN)), None);
        a.position_read(Instant(u64::MAX), Pulses(i32::MIN + 1), None, INSTANT);
        // 2^32 pulses at one every 71 minutes: far ahead, and no overflow on the way.
        let eta = a.eta();
        assert!(eta.is_some_and(|eta| eta.0 > u64::MAX / 2), "{eta:?}");
        a.command_accepted(Instant(1), &Command::Status, None, None);
        assert_eq!(a.eta(), eta);
    }
}
