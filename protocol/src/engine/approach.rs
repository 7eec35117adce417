//! When a moving axis will arrive: the estimate that lets the schedule poll a mover's status
//! around the moment its move completes, and rarely before.
//!
//! A status poll is what shows a move complete (PEND/PFIN in the OUT byte, complete edition
//! §4-3-1), so the sooner one follows the completion, the sooner the PLC sees it. Polling every
//! mover all the time cannot do it with several movers (four movers polled in turn: each every
//! four transactions at best, and idle axes starved); polling a mover when it is about to arrive
//! can. The estimate comes from what the engine sees anyway: the target of the move command it
//! sent (`a` absolute, `m` relative, complete edition §4-4-8/§4-4-11), where the axis rested
//! at the command, and position reads (R4 PNOW) during the move, modelled as the controller
//! moves: an even acceleration from a standstill, a cruise, and a braking as long as the
//! acceleration (complete edition §7-2-1, MXAC 0):
//!
//! - **Accelerating** (a read's distance from the start over the square of its time does not
//!   fall, or the read before came in the first quarter of the time): twice the mean speed
//!   since the command is the speed it has. Provisional: it speeds up further, so the estimate
//!   errs early, and the next read is asked for.
//! - **Cruising**: the speed between the last two reads, extrapolated to the target, plus half
//!   the time the acceleration lost against that speed (`lost`): a constant-speed
//!   extrapolation alone is early by half the braking time (eight transactions early for
//!   `rt-bench`'s 40 mm moves), and the axis was polled as arriving all that while. The half
//!   left out keeps the estimate early by about a quarter of the braking time, which covers
//!   the position band (PFIN comes when the axis enters it, before the target, complete
//!   edition §4-3-1).
//! - **Braking** (less left than the acceleration covered): the estimate from the cruise
//!   stands; the speed between reads now overstates how long the rest takes.
//!
//! The reads an estimate needs are few (`ESTIMATE_READS` per move), so the schedule sends them
//! first and outside the per-cycle share of position reads, each when the mover's position is
//! due (right after the command, then a share period later). Before this model the second read,
//! still in the acceleration, set a speed far below the one the axis reached, and the estimate
//! was late by tens of milliseconds (`rt-bench`: movers seen complete up to 9 transactions
//! after they entered their band). A mover whose command was accepted counts as moving until
//! a status says otherwise (`unseen`): its last status, from before the command, says it
//! stands.
//!
//! A move ends in its position band, not at rest, so the estimate's last duty is the stop: the
//! stopped axis is read again until two reads agree ([`SETTLE_READS`]), so that the position the
//! PLC sees is where the axis came to rest.

use core::num::NonZeroU32;

use crate::div::div;
use crate::time::{Duration, Instant};
use crate::{Command, Pulses};

/// What the engine expects of one axis' move.
#[derive(Clone, Copy, Debug)]
pub(super) struct Approach {
    /// Where the move in progress goes, if a command the engine sent says so.
    target: Option<Pulses>,
    /// When its command was answered: position reads before it belong to an earlier move.
    since: Instant,
    /// Where it was then (the last position read), if it rested there: the first point of its
    /// speed.
    start: Option<Pulses>,
    /// When it is expected at its target, if `eta_known`.
    // Not an `Option<Instant>`: 8 bytes more per axis, in a node the F103 budget holds to the
    // byte.
    eta: Instant,
    eta_known: bool,
    /// Whether `eta` comes from two reads during the move (at its speed), not from its start.
    measured: bool,
    /// Position reads since the command: bounds the reads an estimate may ask for.
    reads: u8,
    /// A move command was accepted and no status seen since: the axis moves although its last
    /// status says it stands.
    unseen: bool,
    /// Position reads left to find where a stopped axis came to rest ([`SETTLE_READS`]).
    settle_reads: u8,
}

/// The position reads a move's estimate may ask for beyond the per-cycle share (one from its
/// start, one at its speed, one spare for a read that came before the axis started).
const ESTIMATE_READS: u8 = 3;

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
        measured: false,
        reads: 0,
        unseen: false,
        settle_reads: 0,
    };

    /// A move command was accepted at `now`, with the position last read (for a relative
    /// move) and, for a move to a point, the point's position if its job knows it. Other
    /// commands leave the estimate alone.
    pub(super) fn command_accepted(
        &mut self,
        now: Instant,
        command: &Command,
        at: Option<Pulses>,
        point_at: Option<Pulses>,
    ) {
        let target = match *command {
            Command::MoveAbsolute(to) => Some(to),
            Command::MoveRelative(by) => at.map(|from| Pulses(from.0.saturating_add(by.0))),
            // A point's position is not in the command: only if its job knows it.
            Command::MoveToPoint(_) => point_at,
            // A home's is not known: no estimate.
            Command::Home(_) => None,
            _ => return,
        };
        // Where the axis rests, if it does: a position read while the last move was still
        // ending (or settling in its band) is not where this one starts, and would make its
        // acceleration look longer than it was (`lost`), the estimate late (`scripts/bench.sh`,
        // scenario 6, moves given as soon as the last one is seen complete).
        let rested = self.target.is_none() && !self.unseen && self.settle_reads == 0;
        *self = Approach {
            target,
            since: now,
            start: at.filter(|_| rested),
            eta: Instant::ZERO,
            eta_known: false,
            measured: false,
            reads: 0,
            unseen: true,
            settle_reads: 0,
        };
    }

    /// A position read answered at `now` (`position`), after the one before (`previous`): the
    /// estimate of the phase the move is in (the module's doc).
    pub(super) fn position_read(
        &mut self,
        now: Instant,
        position: Pulses,
        previous: Option<(Pulses, Instant)>,
    ) {
        let Some(target) = self.target else {
            // Stopped (or a move without a target, where nothing settles): at rest once a read
            // agrees with the one before.
            if let Some(left) = self.settle_reads.checked_sub(1) {
                let agrees = previous.is_some_and(|(before, _)| before == position);
                self.settle_reads = if agrees { 0 } else { left };
            }
            return;
        };
        self.reads = self.reads.saturating_add(1);
        let previous = previous.filter(|&(_, at)| at >= self.since);
        let (t, before) = (
            self.elapsed(now),
            previous.map(|(p, at)| (p, self.elapsed(at))),
        );
        let (from, elapsed, lost, measured) = match (before, self.start) {
            // Cruising: at its speed between the two reads, plus half the time its
            // acceleration lost (its braking loses as much: see `lost`).
            (Some((before, early)), Some(start))
                if !accelerating(start, before, early, position, t) =>
            {
                let elapsed = t.saturating_sub(early);
                (
                    before,
                    elapsed,
                    lost(start, t, before, position, elapsed),
                    true,
                )
            }
            // Without the position at the command: at the speed between the reads.
            (Some((before, early)), None) => (before, t.saturating_sub(early), 0, true),
            // Still accelerating (or the first read of the move): twice the mean speed since
            // the command, the speed it has now if it accelerates evenly from a standstill.
            (_, Some(start)) => (start, t / 2, 0, false),
            (None, None) => return,
        };
        let left = time_left(position, target, from, elapsed);
        // Less left than its acceleration covered: it brakes, slower than between the reads.
        // The estimate from its cruise stands.
        if self.measured && left.is_some_and(|left| left < u64::from(lost)) {
            return;
        }
        self.eta = now + Duration(left.unwrap_or(0).saturating_add(u64::from(lost / 2)));
        self.eta_known = left.is_some();
        self.measured = measured && self.eta_known;
    }

    /// µs from the command to `at`, in 32 bits (71 minutes, saturating: no move's estimate
    /// needs more).
    // 32-bit products spare the F103 64-bit multiplications.
    fn elapsed(&self, at: Instant) -> u32 {
        u32::try_from(at.0.saturating_sub(self.since.0)).unwrap_or(u32::MAX)
    }

    /// Whether the axis' move has a target, so that position reads can estimate its arrival.
    pub(super) fn has_target(&self) -> bool {
        self.target.is_some()
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

    /// Whether a position read would give (or correct) the estimate: the move has a target, its
    /// speed is not measured yet, and it has not had its share of reads.
    pub(super) fn needs_read(&self) -> bool {
        self.target.is_some() && !self.measured && self.reads < ESTIMATE_READS
    }

    /// Whether the axis' arrival is estimated from its speed (its position need not be read as
    /// often any more).
    pub(super) fn estimated(&self) -> bool {
        self.measured
    }

    /// The axis is not moving any more (or never started): nothing to expect.
    pub(super) fn clear(&mut self) {
        *self = Approach::NONE;
    }

    /// The axis stopped: nothing to expect of its move, but its position is read until it
    /// rests ([`SETTLE_READS`]).
    pub(super) fn stopped(&mut self) {
        *self = Approach {
            settle_reads: SETTLE_READS,
            ..Approach::NONE
        };
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

/// The µs an axis at `position` takes to reach `target`, having come from `before` in
/// `elapsed_us` µs at the same speed; `None` if it does not move toward the target.
fn time_left(position: Pulses, target: Pulses, before: Pulses, elapsed_us: u32) -> Option<u64> {
    let remaining = target.0.abs_diff(position.0);
    if remaining == 0 {
        return Some(0);
    }
    let moved = NonZeroU32::new(position.0.abs_diff(before.0))?;
    if (position.0 > before.0) != (target.0 > position.0) {
        return None;
    }
    // 32 x 32 bits: no overflow, and no 64-bit division routine (crate::div).
    Some(div(u64::from(remaining) * u64::from(elapsed_us), moved))
}

/// Whether an axis that left `start` at the command still accelerated between a read `before`,
/// `early` µs after the command, and one at `position`, `late` µs after it: an even
/// acceleration from a standstill covers a distance in proportion to the square of its time,
/// so the distance over the square of the time stays the same while it accelerates and falls
/// once it cruises.
///
/// A read in the first quarter of the time tells nothing: the axis starts when its controller
/// takes the command, up to a transaction before the engine's `since` (its answer), so a read
/// 4 ms after the answer may find it 7 ms under way. Counted as accelerating, the safe side (the
/// speed from the start errs early).
fn accelerating(start: Pulses, before: Pulses, early: u32, position: Pulses, late: u32) -> bool {
    // In ms, up to 65 s: each product fits its type.
    let (early, late) = ((early >> 10).min(0xFFFF), (late >> 10).min(0xFFFF));
    early * 4 < late
        || u64::from(position.0.abs_diff(start.0)) * u64::from(early * early)
            >= u64::from(before.0.abs_diff(start.0)) * u64::from(late * late)
}

/// The time (µs) an axis that left `start` at the command, `elapsed` µs ago, lost to its
/// acceleration against its speed now (from `before` to `position` in `step_us` µs, its last
/// two reads): the time it has been under way less the time its distance takes at that speed.
/// It brakes as long as it accelerated (the deceleration follows the acceleration value unless
/// MXAC says otherwise, complete edition §7-2-1; with MXAC the acceleration is the harder, and
/// the estimate earlier), so a constant-speed extrapolation is early by half the braking time,
/// which is this.
fn lost(start: Pulses, elapsed: u32, before: Pulses, position: Pulses, step_us: u32) -> u32 {
    let Some(step) = NonZeroU32::new(position.0.abs_diff(before.0)) else {
        return 0;
    };
    let distance = u64::from(position.0.abs_diff(start.0));
    let at_speed = div(distance * u64::from(step_us), step);
    elapsed.saturating_sub(u32::try_from(at_speed).unwrap_or(u32::MAX))
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000;

    #[test]
    fn extrapolates_the_speed_between_two_reads_to_the_target() {
        let mut a = Approach::NONE;
        a.command_accepted(
            Instant(0),
            &Command::MoveAbsolute(Pulses(10_000)),
            None,
            None,
        );
        // 1000 pulses in 100 ms, 6000 to go: 600 ms.
        a.position_read(
            Instant(200 * MS),
            Pulses(4_000),
            Some((Pulses(3_000), Instant(100 * MS))),
        );
        assert_eq!(a.eta(), Some(Instant(800 * MS)));
        // Backwards, relative.
        a.command_accepted(
            Instant(0),
            &Command::MoveRelative(Pulses(-5_000)),
            Some(Pulses(10_000)),
            None,
        );
        a.position_read(
            Instant(50 * MS),
            Pulses(9_000),
            Some((Pulses(9_500), Instant(25 * MS))),
        );
        assert_eq!(a.eta(), Some(Instant(50 * MS + 200 * MS)));
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

    #[test]
    fn a_move_is_expected_early_but_near_its_end_after_its_acceleration() {
        // rt-bench's moves: 40 mm at 200 mm/s, 68 ms of acceleration (0.3 G); 268 ms in all.
        let (distance, speed, ramp) = (4_000.0, 20.0, 68.0);
        let end = distance / speed + ramp;
        let mut a = Approach::NONE;
        a.command_accepted(
            Instant(0),
            &Command::MoveAbsolute(Pulses(4_000)),
            Some(Pulses(0)),
            None,
        );
        let mut previous = None;
        let mut etas = [0.0; 5];
        for (i, t) in [4.0, 65.0, 135.0, 205.0, 250.0].into_iter().enumerate() {
            let now = Instant((t * 1_000.0) as u64);
            let at = Pulses(trapezoid(distance, speed, ramp, t));
            a.position_read(now, at, previous);
            previous = Some((at, now));
            etas[i] = a.eta().map_or(f64::NAN, |eta| eta.0 as f64 / 1_000.0);
        }
        // Never late (a late estimate leaves the axis unpolled past its end) once it has moved
        // more than a pulse or two (4 ms after the command: provisional, not `estimated`).
        for (i, eta) in etas.iter().enumerate().skip(1) {
            assert!(*eta <= end, "read {i}: {eta} ms, the move ends at {end} ms");
        }
        // Accelerating (65 ms): at the speed it has, within its braking time.
        assert!(etas[1] >= end - ramp, "{etas:?}");
        // Cruising: within a quarter of the ramp (half the braking time, which the position band
        // partly covers), not half the braking time early as a constant speed would be.
        for eta in &etas[2..] {
            assert!(*eta >= end - ramp / 4.0 - 1.0, "{etas:?}");
        }
        assert!(a.estimated());
    }

    #[test]
    fn no_estimate_without_a_target_a_sample_of_this_move_or_progress() {
        let mut a = Approach::NONE;
        a.command_accepted(
            Instant(0),
            &Command::MoveToPoint(crate::PositionNo::MIN),
            None,
            None,
        );
        a.position_read(Instant(20), Pulses(5), Some((Pulses(0), Instant(10))));
        assert_eq!(a.eta(), None, "a point's position is unknown here");
        // Known to its job (the gateway's cached row): estimated as an `a` is.
        a.command_accepted(
            Instant(0),
            &Command::MoveToPoint(crate::PositionNo::MIN),
            None,
            Some(Pulses(105)),
        );
        a.position_read(Instant(20), Pulses(5), Some((Pulses(0), Instant(10))));
        assert_eq!(
            a.eta(),
            Some(Instant(20 + 200)),
            "100 pulses left at 0.5 pulse/µs"
        );
        a.command_accepted(
            Instant(100),
            &Command::MoveAbsolute(Pulses(1_000)),
            None,
            None,
        );
        a.position_read(Instant(120), Pulses(5), Some((Pulses(0), Instant(90))));
        assert_eq!(a.eta(), None, "the earlier read is from before the move");
        a.position_read(Instant(140), Pulses(5), Some((Pulses(5), Instant(120))));
        assert_eq!(a.eta(), None, "standing still");
        a.position_read(Instant(160), Pulses(0), Some((Pulses(5), Instant(140))));
        assert_eq!(a.eta(), None, "moving away");
        a.position_read(Instant(180), Pulses(1_000), Some((Pulses(0), Instant(160))));
        assert_eq!(a.eta(), Some(Instant(180)), "there");
        a.clear();
        assert_eq!(a.eta(), None);
    }

    #[test]
    fn a_stopped_axis_settles_when_two_reads_agree_or_after_its_reads() {
        let read = |a: &mut Approach, position: i32, before: i32| {
            a.position_read(
                Instant(0),
                Pulses(position),
                Some((Pulses(before), Instant(0))),
            )
        };
        let mut a = Approach::NONE;
        assert!(!a.settling(), "not stopped");
        a.stopped();
        assert!(a.settling());
        read(&mut a, 4_994, 3_000);
        read(&mut a, 5_000, 4_994);
        assert!(a.settling(), "still moving in its band");
        read(&mut a, 5_000, 5_000);
        assert!(!a.settling(), "two reads agree");
        // A servo hunting a pulse either side: read no more than SETTLE_READS times.
        a.stopped();
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
        a.stopped();
        a.command_accepted(Instant(0), &Command::MoveAbsolute(Pulses(0)), None, None);
        assert!(!a.settling());
    }

    #[test]
    fn other_commands_keep_the_estimate_and_extremes_do_not_overflow() {
        let mut a = Approach::NONE;
        a.command_accepted(
            Instant(0),
            &Command::MoveAbsolute(Pulses(i32::MAX)),
            None,
            None,
        );
        a.position_read(
            Instant(u64::MAX / 2),
            Pulses(i32::MIN + 1),
            Some((Pulses(i32::MIN), Instant(0))),
        );
        assert_eq!(a.eta(), Some(Instant(u64::MAX)), "saturates");
        a.command_accepted(Instant(1), &Command::Status, None, None);
        assert_eq!(a.eta(), Some(Instant(u64::MAX)));
    }
}
