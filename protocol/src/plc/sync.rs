//! The synchronized start (complete edition §6-4): every axis of SYNCMASK moves to its POSR at
//! the same instant.
//!
//! 1. `h` (buffer) a Q3 on each axis of the mask, one job per axis;
//! 2. when all are buffered, one `t` to an axis of the mask with nothing else queued (it waits
//!    for one), which every axis receives; the job is confirmed per axis by the buffered bit
//!    going off in its status (`t` is never resent);
//! 3. SYNCSTAT 2 (done) once every axis has started; each axis' own CMST then follows its move
//!    to the end (the gateway waits for PFIN on each).
//!
//! Giving up (a `h` refused, a stop or the fail-safe, STP/EMG or the stop input coming on while
//! the commands are buffered) cancels what was buffered by buffering an `n` (§4-4-10), so that
//! a later `t` for other axes cannot start a stale move. A stop does not do it: `d` cancels the
//! remaining motion (§4-4-9, which says nothing of the buffer), and §4-4-10 names `h n` as the
//! way to cancel a buffered command before the `t`.
//!
//! Nothing else sends `h`, so this is where the gateway knows which axes may hold a buffered
//! move (issue 33 item 8, found by the firmware soak): an axis is *held* from the moment its `h`
//! is asked for (its job may fail, or a stop may cancel it, after the frame went out) until a
//! `t` is confirmed to have run it or an `h n` of it is answered. Hence:
//! - a stop cancels the axis' queued jobs, an `h n` among them: one cancelled so is asked for
//!   again, and goes after the stop's `d` (a stop is always sent first: the clearing never
//!   delays it); a held axis with no `h n` under way gets one when any other job of it succeeds
//!   (the stop's `d`, typically);
//! - a start is refused (04) while any axis may hold a move or an `h n` is under way, and asking
//!   for one asks again for the `h n` of a held axis whose last one failed (the axis did not
//!   answer): no `t` goes out while an axis outside its start may hold a move;
//! - the `t` goes to an axis with nothing else queued, so that the next frame to that axis is
//!   the `t`: giving up before any frame went to it, a stop of that axis (at rest, waiting for
//!   the `t`) takes the `t` off the queue, the only way the engine has. A `t` asked for before a
//!   stop must not go out after it and start what the stop left buffered.

use super::command::Reason;
use super::refused::Refused;
use crate::axes::{AxisMap, AxisSet};
use crate::engine::{Engine, Job, JobError, JobId, JobKind, JobOutput, SubmitError, QUEUE_LEN};
use crate::{Axis, Buffered, Command, PositionNo};

/// SYNCSTAT.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(u16)]
pub(super) enum SyncStatus {
    /// Never started.
    #[default]
    Idle = 0,
    /// Buffering, or waiting for the axes to start.
    Running = 1,
    /// Every axis started.
    Done = 2,
    /// Given up.
    Failed = 3,
}

/// What the gateway shows on the axes of the mask when the start ends.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum SyncEnd {
    /// Every axis of the set started its move.
    Started(AxisSet),
    /// The start was given up, for this CMER code, on every axis of the set.
    Failed(AxisSet, u16),
}

/// The synchronized start's state.
#[derive(Clone, Copy, Debug)]
pub(super) struct SyncStart {
    mask: AxisSet,
    status: SyncStatus,
    /// The axes whose `h` is out.
    pending: AxisSet,
    /// The axes that may hold a buffered move (see the module documentation).
    held: AxisSet,
    /// The start's job under way on each axis: its `h`, or its `h n` if in `cancelling`.
    jobs: AxisMap<Option<JobId>>,
    /// The axes whose job in `jobs` is an `h n`.
    cancelling: AxisSet,
    /// The `t`'s job, its axis, and the frames sent to that axis when it was asked for: while
    /// no more has gone, the `t` has not gone out.
    start: Option<(JobId, Axis, u32)>,
    /// The mask of the start in progress (SYNCMASK may be rewritten meanwhile).
    running: AxisSet,
}

impl SyncStart {
    pub(super) const fn new() -> SyncStart {
        SyncStart {
            mask: AxisSet::EMPTY,
            status: SyncStatus::Idle,
            pending: AxisSet::EMPTY,
            held: AxisSet::EMPTY,
            jobs: AxisMap::new(None),
            cancelling: AxisSet::EMPTY,
            start: None,
            running: AxisSet::EMPTY,
        }
    }

    /// SYNCMASK.
    pub(super) fn mask(&self) -> AxisSet {
        self.mask
    }

    pub(super) fn set_mask(&mut self, mask: AxisSet) {
        self.mask = mask;
    }

    /// SYNCSTAT.
    pub(super) fn status(&self) -> SyncStatus {
        self.status
    }

    /// Whether a start is in progress and involves `axis`.
    pub(super) fn involves(&self, axis: Axis) -> bool {
        self.status == SyncStatus::Running && self.running.contains(axis)
    }

    /// Whether a start of `mask` may begin now: 03 for an empty mask or a blocked axis (STP,
    /// EMG, stop input), 04 while busy (a start running, an `h` or `h n` of an earlier attempt
    /// still out, an axis that may hold a buffered move, or no room for one `h` per axis).
    /// Asking is what retries the `h n` of a held axis whose last one failed (the axis did not
    /// answer, or it found no room): the start waits for its answer.
    pub(super) fn check(
        &mut self,
        mask: AxisSet,
        blocked: AxisSet,
        engine: &mut Engine,
    ) -> Result<(), Refused> {
        if mask.is_empty() || mask.0 & blocked.0 != 0 {
            return Err(Refused::OutOfRange);
        }
        if self.status != SyncStatus::Running {
            self.cancel(self.held, engine);
        }
        let leftover = self.jobs.values().any(Option::is_some)
            || self.start.is_some()
            || !self.held.is_empty();
        let room = QUEUE_LEN.saturating_sub(engine.queued());
        let offline = mask.iter().any(|a| !engine.online(a));
        if self.status == SyncStatus::Running || leftover || mask.len() > room || offline {
            return Err(Refused::Busy);
        }
        Ok(())
    }

    /// Buffer the moves: `posr(axis)` is each axis' point.
    pub(super) fn start(
        &mut self,
        blocked: AxisSet,
        posr: impl Fn(Axis) -> PositionNo,
        engine: &mut Engine,
    ) -> Result<(), Refused> {
        let mask = self.mask;
        self.check(mask, blocked, engine)?;
        self.status = SyncStatus::Running;
        self.running = mask;
        self.pending = AxisSet::EMPTY;
        self.start = None;
        for axis in mask.iter() {
            let Some(buffered) = Buffered::new(&Command::MoveToPoint(posr(axis))) else {
                continue;
            };
            let job = Job {
                axis,
                kind: JobKind::Command(Command::Buffer(buffered)),
            };
            match engine.submit(job) {
                Ok(id) => {
                    self.pending = self.pending.with(axis);
                    self.held = self.held.with(axis);
                    self.jobs[axis] = Some(id);
                }
                Err(_) => {
                    self.fail(engine);
                    return Err(Refused::QueueFull);
                }
            }
        }
        Ok(())
    }

    /// A job finished: if it is one of the start's, the next step, and how the start ended if
    /// it did.
    pub(super) fn job_done(
        &mut self,
        id: JobId,
        axis: Axis,
        result: &Result<JobOutput, JobError>,
        blocked: AxisSet,
        engine: &mut Engine,
    ) -> Option<SyncEnd> {
        let given_up = self.status != SyncStatus::Running;
        // Why the start is given up, if it is: given up in one place.
        let reason = 'fail: {
            if self.start.is_some_and(|(t, ..)| t == id) {
                self.start = None;
                match result {
                    Ok(_) => {
                        // Every axis of the start reported its buffer empty (the job's wait).
                        self.held = AxisSet(self.held.0 & !self.running.0);
                        self.status = SyncStatus::Done;
                        return Some(SyncEnd::Started(self.running));
                    }
                    // Given up already (a stop took the `t` off the queue): the `h n`s.
                    Err(_) if given_up => {
                        self.cancel(self.held, engine);
                        return None;
                    }
                    // The `t` may not have reached every axis: cancel what may still be
                    // buffered.
                    Err(error) => break 'fail Reason::of(*error),
                }
            }
            if self.jobs[axis] != Some(id) {
                if !(self.involves(axis) && self.pending.is_empty() && self.start.is_none()) {
                    // Another job of the axis succeeded: it answers. Cancel what it may still
                    // hold (after a stop, this is the stop's `d`).
                    if result.is_ok() && self.held.contains(axis) && !self.involves(axis) {
                        self.cancel(AxisSet::EMPTY.with(axis), engine);
                    }
                    return None;
                }
                // The `t` waits for an axis of the start to be free (below): look again.
            } else {
                self.jobs[axis] = None;
                if self.cancelling.contains(axis) {
                    self.cancelling = self.cancelling.without(axis);
                    match result {
                        Ok(_) => self.held = self.held.without(axis),
                        // A stop took the `h n` off the queue (or the wire): again, after its
                        // `d`.
                        Err(JobError::Cancelled) if self.held.contains(axis) => {
                            self.cancel(AxisSet::EMPTY.with(axis), engine)
                        }
                        // The axis did not answer: again when it does (or at the next start).
                        Err(_) => {}
                    }
                    return None;
                }
                self.pending = self.pending.without(axis);
                if given_up {
                    // Given up while this `h` ran (it may have been taken even if its job
                    // failed): cancel it.
                    self.cancel(AxisSet::EMPTY.with(axis), engine);
                    return None;
                }
                if let Err(error) = result {
                    break 'fail Reason::of(*error);
                }
                if !self.pending.is_empty() {
                    return None;
                }
            }
            if self.running.0 & blocked.0 != 0 {
                // STP, EMG or the stop input came on while the commands were buffered.
                break 'fail Reason::Paused.code(0);
            }
            if self.held.0 & !self.running.0 != 0 {
                // Never (`check`): the `t` would start another axis' move.
                break 'fail Reason::Cancelled.code(0);
            }
            // The `t` goes to an axis of the start with nothing else to do: the next frame to it
            // is then the `t`, so that `start` tells whether it has gone out. While each has a
            // job (one the PLC gave it after its `h`), the `t` waits: each of their jobs that
            // ends looks again.
            let lead = self.running.iter().find(|&a| !engine.busy(a))?;
            match engine.submit(Job {
                axis: lead,
                kind: JobKind::StartBuffered(self.running),
            }) {
                Ok(id) => {
                    self.start = Some((id, lead, engine.axis(lead).counters.frames_sent));
                    return None;
                }
                Err(_) => Reason::QueueFull.code(0),
            }
        };
        Some(self.fail_with(reason, engine))
    }

    /// Give up the start in progress (a stop, the fail-safe): the axes of its mask, if one was
    /// running.
    pub(super) fn fail(&mut self, engine: &mut Engine) -> Option<SyncEnd> {
        (self.status == SyncStatus::Running)
            .then(|| self.fail_with(Reason::Cancelled.code(0), engine))
    }

    fn fail_with(&mut self, reason: u16, engine: &mut Engine) -> SyncEnd {
        self.status = SyncStatus::Failed;
        if let Some((_, axis, sent)) = self.start {
            if engine.axis(axis).counters.frames_sent == sent {
                // The `t` has not gone out (no frame to its axis since): a stop of its axis
                // takes it off the queue (it fails, cancelled). Once out, the moves started.
                let _ = engine.submit(Job {
                    axis,
                    kind: JobKind::Stop,
                });
            }
        }
        self.cancel(self.held, engine);
        SyncEnd::Failed(self.running, reason)
    }

    /// Cancel what `axes` may hold by buffering `n` (complete edition §4-4-10), on each that has
    /// no job of the start's under way (one whose `h` is still out: when it ends). No room: again
    /// at the next chance. An axis taken off the bus is no longer the gateway's to clear.
    // A set, not one axis in a loop: the callers' stack is a frame shallower.
    fn cancel(&mut self, axes: AxisSet, engine: &mut Engine) {
        for axis in axes.iter() {
            if self.jobs[axis].is_some() {
                continue;
            }
            let Some(cancel) = Buffered::new(&Command::Status) else {
                continue;
            };
            match engine.submit(Job {
                axis,
                kind: JobKind::Command(Command::Buffer(cancel)),
            }) {
                Ok(id) => {
                    self.jobs[axis] = Some(id);
                    self.cancelling = self.cancelling.with(axis);
                }
                Err(SubmitError::AxisDisabled) => self.held = self.held.without(axis),
                Err(SubmitError::QueueFull) => {}
            }
        }
    }
}
