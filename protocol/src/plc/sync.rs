//! The synchronized start (complete edition §6-4): every axis of SYNCMASK moves to its POSR at
//! the same instant.
//!
//! 1. `h` (buffer) a Q3 on each axis of the mask, one job per axis;
//! 2. when all are buffered, one `t` to the first axis, which every axis receives; the job is
//!    confirmed per axis by the buffered bit going off in its status (`t` is never resent);
//! 3. SYNCSTAT 2 (done) once every axis has started; each axis' own CMST then follows its move
//!    to the end (the gateway waits for PFIN on each).
//!
//! Giving up (a `h` refused, a stop or the fail-safe, STP/EMG or the stop input coming on while
//! the commands are buffered) cancels what was buffered by buffering an `n` (§4-4-10), so that
//! a later `t` for other axes cannot start a stale move.

use super::command::Reason;
use super::refused::Refused;
use crate::axes::{AxisMap, AxisSet};
use crate::engine::{Engine, Job, JobError, JobId, JobKind, JobOutput, QUEUE_LEN};
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
    /// The axes holding a buffered command.
    buffered: AxisSet,
    jobs: AxisMap<Option<JobId>>,
    start: Option<JobId>,
    /// The mask of the start in progress (SYNCMASK may be rewritten meanwhile).
    running: AxisSet,
}

impl SyncStart {
    pub(super) const fn new() -> SyncStart {
        SyncStart {
            mask: AxisSet::EMPTY,
            status: SyncStatus::Idle,
            pending: AxisSet::EMPTY,
            buffered: AxisSet::EMPTY,
            jobs: AxisMap::new(None),
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
    /// EMG, stop input), 04 while busy (a start running, an `h` of an earlier attempt still
    /// out, or no room for one `h` per axis).
    pub(super) fn check(
        &self,
        mask: AxisSet,
        blocked: AxisSet,
        engine: &Engine,
    ) -> Result<(), Refused> {
        if mask.is_empty() || mask.0 & blocked.0 != 0 {
            return Err(Refused::OutOfRange);
        }
        let leftover = self.jobs.values().any(Option::is_some) || self.start.is_some();
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
        self.buffered = AxisSet::EMPTY;
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
        // Why the start is given up, if it is: given up in one place.
        let reason = 'fail: {
            if self.start == Some(id) {
                self.start = None;
                match result {
                    Ok(_) => {
                        self.status = SyncStatus::Done;
                        self.buffered = AxisSet::EMPTY;
                        return Some(SyncEnd::Started(self.running));
                    }
                    // The `t` may not have reached every axis: cancel what may still be
                    // buffered.
                    Err(error) => break 'fail Reason::of(*error),
                }
            }
            if self.jobs[axis] != Some(id) {
                return None;
            }
            self.jobs[axis] = None;
            self.pending = self.pending.without(axis);
            if let Err(error) = result {
                break 'fail Reason::of(*error);
            }
            self.buffered = self.buffered.with(axis);
            if self.status != SyncStatus::Running {
                // The start was given up while this `h` ran: cancel it at once.
                self.cancel_buffered(engine);
                return None;
            }
            if !self.pending.is_empty() {
                return None;
            }
            if self.running.0 & blocked.0 != 0 {
                // STP, EMG or the stop input came on while the commands were buffered.
                break 'fail Reason::Paused.code(0);
            }
            let lead = self.running.iter().next()?;
            match engine.submit(Job {
                axis: lead,
                kind: JobKind::StartBuffered(self.running),
            }) {
                Ok(id) => {
                    self.start = Some(id);
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
        self.cancel_buffered(engine);
        SyncEnd::Failed(self.running, reason)
    }

    /// Cancel what was buffered by buffering `n` (complete edition §4-4-10).
    fn cancel_buffered(&mut self, engine: &mut Engine) {
        for axis in self.buffered.iter() {
            if let Some(cancel) = Buffered::new(&Command::Status) {
                let _ = engine.submit(Job {
                    axis,
                    kind: JobKind::Command(Command::Buffer(cancel)),
                });
            }
        }
        self.buffered = AxisSet::EMPTY;
    }
}
