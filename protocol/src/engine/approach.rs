//! When a moving axis will arrive: the estimate that lets the schedule poll a mover's status
//! around the moment its move completes, and rarely before.
//!
//! A status poll is what shows a move complete (PEND/PFIN in the OUT byte, complete edition
//! §4-3-1), so the sooner one follows the completion, the sooner the PLC sees it. Polling every
//! mover all the time cannot do it with several movers (four movers polled in turn: each every
//! four transactions at best, and idle axes starved); polling a mover when it is about to arrive
//! can. The estimate comes from what the engine sees anyway: the target of the move command it
//! sent (`a` absolute, `m` relative, complete edition §4-4-8/§4-4-11) and two successive
//! position reads (R4 PNOW) during the move, their speed extrapolated to the target. Constant
//! speed ignores the deceleration, so the estimate is early by about half the braking time:
//! the safe side, since an axis due is polled until it is seen in position.
//!
//! Until a second read, the first one and the position at the command give a provisional
//! estimate, at twice their mean speed (an even acceleration from a standstill): also early.
//! The reads an estimate needs are few (`ESTIMATE_READS` per move), so the schedule sends them
//! first and outside the per-cycle share of position reads, each when the mover's position is
//! due (right after the command, then a share period later): not one right after the other,
//! since two reads in the first milliseconds of the acceleration measure a speed far below the
//! one the axis reaches, and the estimate from them was late by tens of milliseconds
//! (`rt-bench`, 40 mm moves over a pseudo-terminal). A mover whose command was accepted
//! counts as moving until a status says otherwise (`unseen`): its last status, from before the
//! command, says it stands.
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
    /// Where it was then (the last position read), the first point of its speed.
    start: Option<Pulses>,
    /// When it is expected at its target, if `eta_known` (an `Option<Instant>` would take 8
    /// bytes more per axis, in a node the F103 budget holds to the byte).
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
        *self = Approach {
            target,
            since: now,
            start: at,
            eta: Instant::ZERO,
            eta_known: false,
            measured: false,
            reads: 0,
            unseen: true,
            settle_reads: 0,
        };
    }

    /// A position read answered at `now` (`position`), after the one before (`previous`): the
    /// speed between them (or since the move started, from where it started: slower than the
    /// speed it reaches, so the first estimate is late, and the next read corrects it),
    /// extrapolated to the target.
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
        let (from, measured) = match previous {
            Some((before, at)) if at >= self.since => (Some((before, at)), true),
            _ => (self.start.map(|start| (start, self.since)), false),
        };
        if let Some((before, at)) = from {
            let elapsed = now.0.saturating_sub(at.0);
            // From a standstill at the command, accelerating evenly: twice the mean speed. Never
            // more than the speed it has, so this estimate errs early, like the measured one.
            let elapsed = if measured { elapsed } else { elapsed / 2 };
            let eta = arrival(now, position, target, before, elapsed);
            self.eta = eta.unwrap_or(Instant::ZERO);
            self.eta_known = eta.is_some();
            self.measured = measured && self.eta_known;
        }
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

/// When an axis at `position` (now) reaches `target`, having come from `before` in `elapsed_us`
/// µs at the same speed; `None` if it does not move toward the target.
fn arrival(
    now: Instant,
    position: Pulses,
    target: Pulses,
    before: Pulses,
    elapsed_us: u64,
) -> Option<Instant> {
    let moved = i64::from(position.0) - i64::from(before.0);
    let remaining = i64::from(target.0) - i64::from(position.0);
    if remaining == 0 {
        return Some(now);
    }
    if moved == 0 || (moved > 0) != (remaining > 0) {
        return None;
    }
    // remaining / moved > 0; the product stays far from overflow (|remaining| < 2^33,
    // elapsed < 2^31 µs in practice; saturating for the rest). `moved` is the difference of
    // two i32, so its magnitude fits in 32 bits (crate::div: no 64-bit division routine).
    let moved = NonZeroU32::new(u32::try_from(moved.unsigned_abs()).ok()?)?;
    let us = div(remaining.unsigned_abs().saturating_mul(elapsed_us), moved);
    Some(now + Duration(us))
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
