//! Running the jobs: one per axis at a time, the others wait in the queue. A job is its
//! description and a cursor into its program ([`program`]); responses move the cursor, waits
//! are judged on status responses, and the end of the program (or a failure) reports once.

use super::job::{self, program, readback_slot, reads_position, written, Op, STORE_COMPARED};
use super::{Engine, Event, Job, JobError, JobId, JobKind, JobOutput, Next, Origin, WaitingStop};
use crate::axes::AxisSet;
use crate::engine::point_jobs::{PointReadback, StepError};
use crate::time::Instant;
use crate::{Axis, Command, Reply, Request, StatusReport};

/// What the last response of a running job carried, for its result.
#[derive(Clone, Copy, Debug)]
enum Last {
    Done,
    Status(StatusReport),
    Value(u32),
}

/// A running job.
#[derive(Clone, Copy, Debug)]
pub(super) struct Active {
    pub(super) id: JobId,
    pub(super) job: Job,
    pub(super) cursor: u8,
    /// The furthest op reached; retries reset only past it (so a W4 rewound to its T4 keeps
    /// counting).
    high_water: u8,
    pub(super) attempt: u8,
    /// Status responses received after this instant count for an `Await`.
    since: Instant,
    pub(super) wait_deadline: Option<Instant>,
    readback: PointReadback,
    last: Last,
    /// The job has failed with the position unknown and reads it before reporting this.
    failing: Option<JobError>,
}

impl Engine {
    /// Cancel the running and waiting jobs of `axis` (a stop is coming).
    pub(super) fn cancel_jobs(&mut self, axis: Axis, error: JobError) {
        self.fail_job(axis, error);
        self.cancel_waiting(axis, error);
        if matches!(self.in_flight, Some(f) if f.origin == Origin::Job && f.request.axis == axis) {
            // The answer still completes the transaction; nothing routes it to a job.
            if let Some(f) = self.in_flight.as_mut() {
                f.origin = Origin::Cancelled;
            }
        }
        if matches!(self.retry, Some((r, Origin::Job, _)) if r.axis == axis) {
            self.retry = None;
        }
        if matches!(self.pending, Some((r, Origin::Job, _)) if r.axis == axis) {
            // A job frame parked for a baud change: its job is gone.
            self.pending = None;
        }
    }

    /// Fail the jobs waiting for `axis` (not the running one).
    pub(super) fn cancel_waiting(&mut self, axis: Axis, error: JobError) {
        for _ in 0..self.queue.len() {
            if let Some((id, job)) = self.queue.pop_front() {
                if job.axis == axis {
                    self.job_failed(id, axis, error);
                } else {
                    let _ = self.queue.push_back((id, job));
                }
            }
        }
    }

    pub(super) fn expire_waits(&mut self, now: Instant) {
        for axis in Axis::all() {
            // By reference: a job's state is large, and this runs on every poll.
            let expired = self.active[axis]
                .as_ref()
                .and_then(|a| a.wait_deadline)
                .is_some_and(|deadline| now >= deadline);
            if expired {
                self.fail_job(axis, JobError::WaitTimeout);
            }
        }
    }

    /// Put a stop back in its slot, unless a newer stop for the axis supersedes it: the newer
    /// one then takes over the tries this one used (see [`Engine::submit`]).
    pub(super) fn requeue_stop(&mut self, axis: Axis, id: JobId, attempt: u8) {
        match &mut self.stops[axis] {
            slot @ None => {
                *slot = Some(WaitingStop {
                    id,
                    tries: attempt,
                    asked: id.0,
                    // (Never sent: parked for a baud change.)
                    first: attempt == 0,
                })
            }
            Some(newer) => {
                newer.tries = newer.tries.max(attempt);
                self.job_failed(id, axis, JobError::Cancelled);
            }
        }
    }

    /// The next stop (`d`) waiting to go, if any: every axis' first before any resend, and of
    /// the first ones those of the axes that answer before the others (a dead axis' costs a
    /// time-out), each group in the order the stops were asked for.
    pub(super) fn next_stop(&mut self) -> Option<Next> {
        // Nearly always none: a plain scan first (it runs before every transaction; the
        // ranking below cost some 250 instructions each, `scripts/cpu-profile.sh`).
        if self.stops.values().all(Option::is_none) {
            return None;
        }
        let next_id = self.next_id;
        let axis = Axis::all()
            .filter_map(|axis| {
                let stop = self.stops[axis]?;
                let rank = match stop.first {
                    true if self.online(axis) => 0,
                    true => 1,
                    false => 2,
                };
                // Older first: job numbers wrap, so counted back from the next one.
                Some(((rank, stop.asked.wrapping_sub(next_id)), axis))
            })
            .min_by_key(|&(key, _)| key)
            .map(|(_, axis)| axis)?;
        let stop = self.stops[axis].take()?;
        Some((
            Request::new(axis, Command::CancelMotion),
            Origin::Stop(stop.id),
            stop.tries,
        ))
    }

    /// Start the waiting jobs whose axis is free; a job for an axis that does not answer fails
    /// at once ([`JobError::Offline`]): it must not run when the axis comes back.
    pub(super) fn activate_jobs(&mut self, now: Instant) {
        for _ in 0..self.queue.len() {
            let Some((id, job)) = self.queue.pop_front() else {
                break;
            };
            if self.active[job.axis].is_some() {
                let _ = self.queue.push_back((id, job));
                continue;
            }
            if self.axes[job.axis].link == super::Link::Offline {
                self.job_failed(id, job.axis, JobError::Offline);
                continue;
            }
            let wait_deadline = match program(&job, 0) {
                Some(Op::Await(_)) => Some(now + self.config.motion_timeout),
                _ => None,
            };
            self.active[job.axis] = Some(Active {
                id,
                job,
                cursor: 0,
                high_water: 0,
                attempt: 0,
                since: now,
                wait_deadline,
                readback: PointReadback::default(),
                last: Last::Done,
                failing: None,
            });
        }
    }

    /// The next frame of a running job, taking the axes in turn.
    pub(super) fn next_job_frame(&mut self) -> Option<Next> {
        for offset in 0..16u8 {
            let axis = Axis::new((self.job_cursor + offset) % 16)?;
            let Some(active) = self.active[axis] else {
                continue;
            };
            if let Some(Op::Send(step)) = program(&active.job, usize::from(active.cursor)) {
                self.job_cursor = (axis.get() + 1) % 16;
                return Some((step.request, Origin::Job, active.attempt));
            }
        }
        None
    }

    /// Whether the axis' job frame is to be sent again (its last attempt went unanswered): its
    /// attempts go in a row, nothing else to that axis between them (§5: the axis is offline
    /// after 1 + Nrt of them).
    pub(super) fn job_resending(&self, axis: Axis) -> bool {
        self.active[axis]
            .as_ref()
            .is_some_and(|active| active.attempt > 0)
    }

    /// Whether the axis' job reads its position (R4 PNOW) now or as its next op (after the wait
    /// that ends a move or homing): the schedule need not read it as well.
    pub(super) fn job_reads_position(&self, axis: Axis) -> bool {
        self.active[axis].as_ref().is_some_and(|active| {
            let at = usize::from(active.cursor);
            reads_position(&active.job, at) || reads_position(&active.job, at + 1)
        })
    }

    pub(super) fn check_await(&mut self, now: Instant, axis: Axis, report: &StatusReport) {
        let Some(active) = self.active[axis] else {
            return;
        };
        let Some(Op::Await(condition)) = program(&active.job, usize::from(active.cursor)) else {
            return;
        };
        if now <= active.since {
            return;
        }
        if report.outputs.alarm_active() && report.alarm.level() == crate::alarm::Level::Error {
            self.fail_job(axis, JobError::Alarm(report.alarm));
        } else if let job::Condition::Unbuffered(axes) = condition {
            if self.all_unbuffered(axes, active.since) {
                self.advance(now, axis);
            }
        } else if condition.met(report) {
            self.advance(now, axis);
        }
    }

    /// Whether every axis of `axes` reported, after `since`, that it has no buffered command.
    fn all_unbuffered(&self, axes: AxisSet, since: Instant) -> bool {
        axes.iter().all(|a| {
            let state = self.axis(a);
            state.report_at.is_some_and(|t| t > since)
                && state.report.is_some_and(|r| !r.status.buffered())
        })
    }

    /// Jobs on other axes that wait for this axis too (a synchronized start).
    pub(super) fn check_cross_axis_waits(&mut self, now: Instant, axis: Axis) {
        for lead in Axis::all().filter(|&a| a != axis) {
            let Some(active) = self.active[lead] else {
                continue;
            };
            if let Some(Op::Await(job::Condition::Unbuffered(axes))) =
                program(&active.job, usize::from(active.cursor))
            {
                if axes.contains(axis) && self.all_unbuffered(axes, active.since) {
                    self.advance(now, lead);
                }
            }
        }
    }

    pub(super) fn job_reply(&mut self, now: Instant, axis: Axis, reply: &Reply) {
        let Some(active) = self.active[axis].as_mut() else {
            return;
        };
        let cursor = usize::from(active.cursor);
        let Some(Op::Send(step)) = program(&active.job, cursor) else {
            return;
        };
        match step.expect.check(reply) {
            Err(StepError::Rejected(code)) => self.fail_job(axis, JobError::Rejected(code)),
            Err(StepError::Unexpected) => self.fail_job(axis, JobError::Unexpected),
            Ok(value) => {
                if let (Some(slot), Some(value)) = (readback_slot(&active.job, cursor), value) {
                    if let Some(v) = active.readback.0.get_mut(slot) {
                        *v = value;
                    }
                }
                active.last = match (value, reply.report()) {
                    (Some(value), _) => Last::Value(value),
                    (None, Some(report)) => Last::Status(*report),
                    (None, None) => Last::Done,
                };
                self.advance(now, axis);
            }
        }
    }

    /// Move the job of `axis` past its current op, and finish it at the end of its program.
    pub(super) fn advance(&mut self, now: Instant, axis: Axis) {
        let motion_timeout = self.config.motion_timeout;
        let Some(active) = self.active[axis].as_mut() else {
            return;
        };
        active.cursor = active.cursor.saturating_add(1);
        if active.cursor > active.high_water {
            active.high_water = active.cursor;
            active.attempt = 0;
        }
        active.since = now;
        active.wait_deadline = None;
        let cursor = usize::from(active.cursor);
        if let (JobKind::StorePoint { data, .. }, STORE_COMPARED) = (active.job.kind, cursor) {
            if active.readback.matches(&data) {
                // Already stored: no V5.
                let readback = active.readback;
                self.finish(axis, Ok(JobOutput::Unchanged(readback)));
                return;
            }
        }
        match program(&active.job, cursor) {
            Some(Op::Await(_)) => active.wait_deadline = Some(now + motion_timeout),
            Some(Op::Send(_)) => {}
            None => {
                let result = match (active.failing, written(&active.job), active.job.kind) {
                    // The position is read: now the failure.
                    (Some(error), _, _) => Err(error),
                    (None, Some(data), _) if !active.readback.matches(data) => {
                        Err(JobError::VerifyFailed)
                    }
                    (None, Some(_), _) | (None, None, JobKind::ReadPoint(_)) => {
                        Ok(JobOutput::Point(active.readback))
                    }
                    _ => Ok(match active.last {
                        Last::Done => JobOutput::Done,
                        Last::Status(report) => JobOutput::Status(report),
                        Last::Value(value) => JobOutput::Value(value),
                    }),
                };
                self.finish(axis, result);
            }
        }
    }

    fn finish(&mut self, axis: Axis, result: Result<JobOutput, JobError>) {
        if let Some(active) = self.active[axis].take() {
            self.emit(Event::JobDone {
                id: active.id,
                axis,
                result,
            });
        }
    }

    /// Report that job `id` of `axis` failed. Not inlined: several places report a failure,
    /// and each would build the whole event.
    #[inline(never)]
    pub(super) fn job_failed(&mut self, id: JobId, axis: Axis, error: JobError) {
        self.emit(Event::JobDone {
            id,
            axis,
            result: Err(error),
        });
    }

    /// Fail the running job of `axis`. A move or a home that fails with the position unknown
    /// ([`JobError::position_unknown`]) on an axis that still answers goes on to its read of the
    /// position first, so that PNOW is fresh when CMST shows the failure, as it is when it shows
    /// a move done; whatever ends that read (its answer, a time-out, a stop) reports the first
    /// failure.
    pub(super) fn fail_job(&mut self, axis: Axis, error: JobError) {
        let online = self.axes[axis].link == super::Link::Online;
        if let Some(active) = self.active[axis].as_mut() {
            if let Some(first) = active.failing {
                self.finish(axis, Err(first));
                return;
            }
            if online && error.position_unknown() {
                // Its read of the position, further on in its program (a move's or homing's
                // last op).
                let read = (usize::from(active.cursor) + 1..)
                    .take_while(|&i| program(&active.job, i).is_some())
                    .find(|&i| reads_position(&active.job, i))
                    .and_then(|i| u8::try_from(i).ok());
                if let Some(read) = read {
                    active.failing = Some(error);
                    active.cursor = read;
                    active.high_water = read;
                    active.attempt = 0;
                    active.wait_deadline = None;
                    return;
                }
            }
        }
        self.finish(axis, Err(error));
    }
}
