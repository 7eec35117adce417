//! Jobs: what each job may send, the engine's events, the JobId bookkeeping and the attribution
//! of every frame sent to a job.

use protocol::engine::point_jobs as jobs;
use protocol::engine::{Event, Job, JobError, JobKind, JobOutput, SubmitError};
use protocol::memory::PNOW;
use protocol::{Axis, Command, Pulses, Request};

use crate::driver::Soak;

pub(crate) struct JobRec {
    pub(crate) axis: Axis,
    pub(crate) kind: JobKind,
    pub(crate) submitted: u64,
    pub(crate) done: Option<Result<JobOutput, JobError>>,
    /// Transmissions of this job's `m`, attributed to it as the axis' active job.
    pub(crate) m_sends: u32,
    /// Transmissions of this exact `m` request on the axis between submit and JobDone.
    m_literal: u32,
    /// For a stop: `d` transmissions on its axis while it was outstanding.
    pub(crate) d_sends: u32,
}

/// The requests a job's program may send.
pub(crate) fn job_requests(job: &Job) -> Vec<Request> {
    let a = job.axis;
    let one = |c: Command| vec![Request::new(a, c)];
    let steps = |s: &[jobs::Step]| s.iter().map(|s| s.request).collect::<Vec<_>>();
    // `v2`, then a move: a jog's and a direct move's two frames.
    let v2_then = |velocity, acceleration, command| {
        let v2 = Command::SetVelocityAcceleration {
            velocity,
            acceleration,
        };
        vec![Request::new(a, v2), Request::new(a, command)]
    };
    match job.kind {
        JobKind::Command(c) => one(c),
        JobKind::Servo(on) => one(Command::Servo(on)),
        JobKind::Home(d) => one(Command::Home(d)),
        JobKind::MoveToPoint(p, _) => one(Command::MoveToPoint(p)),
        JobKind::MoveAbsolute(x) => one(Command::MoveAbsolute(x)),
        JobKind::MoveRelative(d) => one(Command::MoveRelative(d)),
        JobKind::Jog {
            end,
            velocity,
            acceleration,
        } => v2_then(velocity, acceleration, Command::MoveAbsolute(end)),
        JobKind::DirectMove {
            target,
            relative,
            velocity,
            acceleration,
        } => v2_then(
            velocity,
            acceleration,
            if relative {
                Command::MoveRelative(target)
            } else {
                Command::MoveAbsolute(target)
            },
        ),
        JobKind::Stop => one(Command::CancelMotion),
        JobKind::AlarmReset => vec![
            Request::new(a, Command::Servo(false)),
            Request::new(a, Command::Reset(protocol::ResetKind::AlarmReset)),
        ],
        JobKind::SetMotion {
            velocity,
            acceleration,
        } => one(Command::SetVelocityAcceleration {
            velocity,
            acceleration,
        }),
        JobKind::WriteField {
            point,
            field,
            value,
        } => steps(&jobs::write_field(a, point, field, value)),
        JobKind::WritePoint {
            point,
            data,
            verify,
        } => {
            let mut r = steps(&jobs::write_point(a, point, &data));
            if verify {
                r.extend(steps(&jobs::read_point(a, point)));
            }
            r
        }
        JobKind::ReadPoint(p) => steps(&jobs::read_point(a, p)),
        JobKind::StorePoint { point, data } => {
            let mut r = steps(&jobs::read_point(a, point));
            r.extend(steps(&jobs::write_point(a, point, &data)));
            r
        }
        JobKind::AwaitInPosition => vec![],
        JobKind::StartBuffered(_) => one(Command::ExecuteBuffered),
    }
}

/// The distance of the `m` a job sends, if it sends one.
pub(crate) fn relative_distance(kind: &JobKind) -> Option<Pulses> {
    match *kind {
        JobKind::MoveRelative(d)
        | JobKind::DirectMove {
            target: d,
            relative: true,
            ..
        } => Some(d),
        _ => None,
    }
}

pub(crate) fn kind_name(kind: &JobKind) -> &'static str {
    match kind {
        JobKind::Command(_) => "Command",
        JobKind::Servo(_) => "Servo",
        JobKind::Home(_) => "Home",
        JobKind::MoveToPoint(..) => "MoveToPoint",
        JobKind::MoveAbsolute(_) => "MoveAbsolute",
        JobKind::MoveRelative(_) => "MoveRelative",
        JobKind::DirectMove { relative: true, .. } => "DirectMove (m)",
        JobKind::DirectMove { .. } => "DirectMove (a)",
        JobKind::Jog { .. } => "Jog",
        JobKind::Stop => "Stop",
        JobKind::AlarmReset => "AlarmReset",
        JobKind::SetMotion { .. } => "SetMotion",
        JobKind::WriteField { .. } => "WriteField",
        JobKind::WritePoint { .. } => "WritePoint",
        JobKind::ReadPoint(_) => "ReadPoint",
        JobKind::StorePoint { .. } => "StorePoint",
        JobKind::AwaitInPosition => "AwaitInPosition",
        JobKind::StartBuffered(_) => "StartBuffered",
    }
}

pub(crate) fn result_name(result: &Result<JobOutput, JobError>) -> String {
    match result {
        Ok(_) => "ok".into(),
        Err(JobError::Rejected(code)) => format!("Rejected({:02X})", code.0),
        Err(JobError::Alarm(code)) => format!("Alarm({:02X})", code.0),
        Err(e) => format!("{e:?}"),
    }
}

impl Soak {
    pub(crate) fn drain_events(&mut self) {
        while let Some(event) = self.h.engine.next_event() {
            match event {
                Event::JobDone { id, axis, result } => self.job_done(id.0, axis, result),
                Event::Offline(a) => {
                    self.tally.offline_events += 1;
                    let pending_end = self.cur.as_ref().is_some_and(|c| c.axis == a);
                    if pending_end {
                        // Ended by a corrupted answer inside `receive`: judged after `poll`.
                        self.offline_checks.push(a);
                    } else {
                        self.check_offline(a);
                    }
                }
                Event::Online(_) | Event::Status { .. } => {}
                Event::Established => self.violation("established", "no establishment".into()),
            }
        }
    }

    fn job_done(&mut self, id: u32, a: Axis, result: Result<JobOutput, JobError>) {
        let Some(job) = self.jobs.get_mut(id as usize) else {
            self.violation("JobDone for an unknown id", format!("{id}"));
            return;
        };
        if job.done.is_some() {
            self.violation("JobDone twice", format!("{id}"));
            return;
        }
        job.done = Some(result);
        let (kind, job_axis) = (job.kind, job.axis);
        let (m_sends, m_literal) = (job.m_sends, job.m_literal);
        if job_axis != a {
            self.violation("JobDone on the wrong axis", format!("{id}"));
        }
        let i = usize::from(a.get());
        if kind == JobKind::Stop {
            self.stops[i].retain(|&s| s != id);
        } else {
            match self.fifo[i].iter().position(|&j| j == id) {
                Some(0) => {
                    self.fifo[i].pop_front();
                }
                Some(p) => {
                    // Cancellation finishes the whole queue in order; anything else is out of
                    // order.
                    if result != Err(JobError::Cancelled) {
                        self.violation("job finished before an older one", format!("{id}"));
                    }
                    self.fifo[i].remove(p);
                }
                None => self.violation("JobDone for a job not outstanding", format!("{id}")),
            }
        }
        if result == Err(JobError::Cancelled) && kind != JobKind::Stop {
            self.cancelled[i].push_back(id);
            if self.cancelled[i].len() > 8 {
                self.cancelled[i].pop_front();
            }
        }
        if relative_distance(&kind).is_some() {
            // The `m` went out exactly once when the outcome says it was sent; at most once
            // otherwise (a cancelled or failed job may never have sent it; a DirectMove's
            // rejection may be its `v`'s).
            let direct = matches!(kind, JobKind::DirectMove { .. });
            let sent = match result {
                Ok(_)
                | Err(JobError::OutcomeUnknown | JobError::WaitTimeout | JobError::Alarm(_)) => {
                    true
                }
                Err(JobError::Rejected(_) | JobError::Unexpected) => !direct,
                Err(_) => false,
            };
            if m_literal != m_sends || m_sends > 1 || (sent && m_sends != 1) {
                self.violation(
                    "m sent other than once",
                    format!("job {id}: {m_sends} sends ({m_literal} of that request), {result:?}"),
                );
            }
        }
        // The PLC's bookkeeping.
        let plc = &mut self.plc[i];
        match (kind, &result) {
            (JobKind::Home(_), Ok(_)) => plc.homed = true,
            (JobKind::WritePoint { point, .. } | JobKind::WriteField { point, .. }, Ok(_)) => {
                plc.written |= 1 << point.get();
            }
            (JobKind::Servo(true), _) => plc.resetting = false,
            _ => {}
        }
        if matches!(result, Err(JobError::Cancelled)) && kind == JobKind::Servo(true) {
            plc.resetting = false;
        }
    }

    /// A job of `request`'s axis that a stop cancelled and that may send `request`.
    pub(crate) fn cancelled_owner(&self, request: &Request) -> Option<u32> {
        self.cancelled[usize::from(request.axis.get())]
            .iter()
            .rev()
            .copied()
            .find(|&id| {
                let job = &self.jobs[id as usize];
                job_requests(&Job {
                    axis: job.axis,
                    kind: job.kind,
                })
                .contains(request)
            })
    }

    /// Which job sent this frame; counts `m` transmissions. `owed`: the axis is owed a stop, so
    /// a `d` to it that no stop job sent stands in for another frame (`Engine::stop_owed`).
    pub(crate) fn attribute(&mut self, now: u64, request: Request, owed: bool) {
        let i = usize::from(request.axis.get());
        match request.command {
            Command::Status => return,
            Command::ReadMemory { address } if address == PNOW => return,
            Command::CancelMotion if !self.stops[i].is_empty() => {
                // To the newest stop of the axis (an older one may still wait for its answer).
                if let Some(&id) = self.stops[i].last() {
                    self.jobs[id as usize].d_sends += 1;
                }
                return;
            }
            Command::CancelMotion if owed => return,
            _ => {}
        }
        if let Command::MoveRelative(d) = request.command {
            for &id in &self.fifo[i] {
                let job = &mut self.jobs[id as usize];
                if relative_distance(&job.kind) == Some(d) && job.submitted <= now {
                    job.m_literal += 1;
                }
            }
        }
        let front = self.fifo[i].front().copied();
        let owner = front.filter(|&id| {
            let job = &self.jobs[id as usize];
            job_requests(&Job {
                axis: job.axis,
                kind: job.kind,
            })
            .contains(&request)
        });
        match owner {
            Some(id) => {
                if let Command::MoveRelative(_) = request.command {
                    let job = &mut self.jobs[id as usize];
                    job.m_sends += 1;
                    if job.m_sends > 1 {
                        self.violation("m resent", format!("job {id}: {request:?}"));
                    }
                }
            }
            None => {
                let active = front.map(|id| {
                    let j = &self.jobs[id as usize];
                    (id, j.kind)
                });
                let kind = match self.cancelled_owner(&request) {
                    Some(_) => "frame of a cancelled job resent after the stop",
                    None => "frame sent for no job",
                };
                self.violation(kind, format!("{request:?}; active job {active:?}"));
            }
        }
    }

    pub(crate) fn submit(&mut self, a: Axis, kind: JobKind) -> bool {
        match self.h.engine.submit(Job { axis: a, kind }) {
            Ok(id) => {
                let i = usize::from(a.get());
                if id.0 as usize != self.jobs.len() {
                    self.violation("job ids not consecutive", format!("{id:?}"));
                }
                self.jobs.push(JobRec {
                    axis: a,
                    kind,
                    submitted: self.now(),
                    done: None,
                    m_sends: 0,
                    m_literal: 0,
                    d_sends: 0,
                });
                if kind == JobKind::Stop {
                    self.stops[i].push(id.0);
                } else {
                    self.fifo[i].push_back(id.0);
                }
                // A stop finishes the axis' jobs at once.
                self.drain_events();
                true
            }
            Err(SubmitError::QueueFull) => {
                self.tally.queue_full += 1;
                false
            }
            Err(e) => {
                self.violation("submit refused", format!("{e:?}"));
                false
            }
        }
    }
}
