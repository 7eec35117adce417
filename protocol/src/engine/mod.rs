//! The bus master: which frame goes next, how long to wait for its answer, what to do when the
//! answer is late, corrupted or missing, and what the axes are doing.
//!
//! Sans-IO (smoltcp's `poll(timestamp)` model): the caller passes the time and the received
//! bytes in, and gets frames to send, line actions and deadlines out.
//!
//! ```text
//! loop {
//!     match engine.poll(now) {
//!         Output::Transmit(frame) => uart.write(&frame.to_bytes()),
//!         Output::Line(action)    => do it (break, baud change, COMM_CHANGE bytes),
//!         Output::Idle(until)     => wait for received bytes or `until`,
//!     }
//!     engine.receive(now, &received_bytes);
//!     while let Some(event) = engine.next_event() { ... }
//! }
//! ```
//!
//! Rules, from the complete edition §2, §5 and §6:
//! - one transaction at a time (half duplex); at least 1 ms after each response before the next
//!   command; a response counts only if it parses, has a good BCC, comes from the addressed axis
//!   and echoes the command character ([`Reply::answers`](crate::Reply::answers));
//! - time-out Trt = 20 + RTIM + 160/Kbr ms (200 + ... for V5) from the end of the command;
//!   a corrupted response ends the attempt at once (the line is free), without waiting for Trt;
//!   up to [`Config::retries`] resends; `m` is never resent (its outcome is reported unknown and
//!   the position re-read), `t` is not resent, and a W4 is resent only after its T4;
//! - order: a stop (`d`) before everything (never behind another axis' retry), then a pending
//!   retry, then job frames, then polling: status (`n`) round-robin over the configured axes,
//!   a bounded number of position reads (R4 PNOW) per cycle for moving axes, and offline axes
//!   probed with a doubling back-off up to [`Config::probe_interval`] so that they cannot
//!   starve live ones;
//! - at start, the communication establishment procedure (§6-1) if configured.

mod axis;
mod establish;
mod job;
mod time;
pub mod timing;

pub use axis::{AxisState, Counters, Link, LinkError, REJECTION_CODES};
pub use job::{Job, JobError, JobId, JobKind, JobOutput};
pub use time::{Duration, Instant};

use establish::{Next, Phase};
use heapless::Deque;
use job::{program, readback_slot, written, Op};

use crate::jobs::{PointReadback, StepError};
use crate::line::{Baud, LineAction, BREAK_MS, COMM_CHANGE_REPEATS, COMM_CHANGE_SETTLE_MS};
use crate::memory::PNOW;
use crate::{
    Axis, Command, Deframer, Error, Frame, Packet, Reply, Request, Rtim, StatusReport,
    RTIM_AFTER_BREAK,
};

/// Axes on one bus.
pub const AXES: usize = 16;
/// Jobs waiting for their axis; more are refused with [`SubmitError::QueueFull`].
pub const QUEUE_LEN: usize = 32;
/// Events kept until read; older ones are dropped and counted when it overflows.
pub const EVENT_LEN: usize = 64;

/// The first probe of an axis that just went offline follows this soon.
pub const FIRST_PROBE: Duration = Duration::from_millis(20);

/// A set of axes, bit n = axis n.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisSet(pub u16);

impl AxisSet {
    /// Every axis.
    pub const ALL: AxisSet = AxisSet(u16::MAX);

    /// Whether `axis` is in the set.
    pub const fn contains(self, axis: Axis) -> bool {
        self.0 & (1 << axis.get()) != 0
    }

    /// The set with `axis` added.
    #[must_use]
    pub const fn with(self, axis: Axis) -> AxisSet {
        AxisSet(self.0 | 1 << axis.get())
    }

    /// The first `n` axes (0..n).
    pub const fn first(n: u8) -> AxisSet {
        if n >= 16 {
            AxisSet::ALL
        } else {
            AxisSet((1u16 << n) - 1)
        }
    }

    /// The axes, ascending.
    pub fn iter(self) -> impl Iterator<Item = Axis> {
        Axis::all().filter(move |&a| self.contains(a))
    }
}

/// How the engine runs the bus.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// The axes on the bus.
    pub axes: AxisSet,
    /// The line rate to establish and use.
    pub baud: Baud,
    /// The RTIM to establish (the controllers' minimum response delay).
    pub rtim: Rtim,
    /// Resends after a time-out, Nrt (complete edition §5 (2): 0-3; larger values count as 3).
    pub retries: u8,
    /// Run the communication establishment procedure (§6-1) first. Without it, the engine
    /// assumes every axis already runs at `baud` with `rtim`.
    pub establish: bool,
    /// The transceiver's receiver is always on: swallow the gateway's own transmissions.
    pub echo: bool,
    /// Position reads (R4 PNOW) per polling cycle for moving axes.
    pub position_reads_per_cycle: u8,
    /// How often an offline axis is probed, at most: the first probe follows after
    /// [`FIRST_PROBE`] and the interval doubles with each unanswered probe up to this, so that
    /// an axis lost to a burst of noise is back quickly and a dead one costs little.
    pub probe_interval: Duration,
    /// How long a job waits for a state (in position, homed) before it fails.
    pub motion_timeout: Duration,
    /// How often an offline axis is also tried at the power-up line settings (9.6 kbit/s,
    /// RTIM 255 ms) and, if it answers there, reconfigured like §6-1 for that axis alone
    /// (only with [`Config::establish`]: a controller that was power-cycled or replaced comes
    /// back at its stored settings).
    pub rejoin_interval: Duration,
}

impl Default for Config {
    fn default() -> Config {
        Config {
            axes: AxisSet::default(),
            baud: Baud::B115200,
            rtim: Rtim::MIN,
            retries: 2,
            establish: true,
            echo: false,
            position_reads_per_cycle: 4,
            probe_interval: Duration::from_millis(500),
            motion_timeout: Duration::from_millis(60_000),
            rejoin_interval: Duration::from_millis(5_000),
        }
    }
}

/// What the caller does next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Output {
    /// Send this frame now.
    Transmit(Frame),
    /// Do this to the line now.
    Line(LineAction),
    /// Nothing to send until this time (or until bytes arrive); `None`: until something changes.
    Idle(Option<Instant>),
}

/// Something that happened, for the PLC side and for logs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// The axis answered after being unknown or offline.
    Online(Axis),
    /// The axis stopped answering.
    Offline(Axis),
    /// The axis' status changed.
    Status {
        /// The axis.
        axis: Axis,
        /// Its new status.
        report: StatusReport,
    },
    /// A job finished.
    JobDone {
        /// The job.
        id: JobId,
        /// Its axis.
        axis: Axis,
        /// How it ended.
        result: Result<JobOutput, JobError>,
    },
    /// The communication establishment procedure finished.
    Established,
}

/// Why a job was not accepted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SubmitError {
    /// [`QUEUE_LEN`] jobs are waiting already.
    QueueFull,
    /// The axis is not in [`Config::axes`].
    AxisDisabled,
}

/// Counters that belong to the bus rather than to one axis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BusCounters {
    /// Valid frames or bad candidates that arrived while no command was waiting for an answer.
    pub unsolicited: u32,
    /// Events dropped because nobody read them.
    pub events_lost: u32,
    /// Jobs refused because the queue was full.
    pub queue_full: u32,
    /// Times the establishment procedure ran.
    pub establishments: u32,
}

/// Who started a transaction, to route its answer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Origin {
    Poll,
    /// A job frame whose job a stop cancelled while it was on the wire: its answer only
    /// updates the status; it is never resent and its loss says nothing about the axis.
    Cancelled,
    Position,
    Probe,
    Job,
    Stop(JobId),
    Establish,
    Rejoin,
}

#[derive(Clone, Copy, Debug)]
struct InFlight {
    request: Request,
    origin: Origin,
    /// No valid response by then: a time-out.
    deadline: Instant,
    /// The answer cannot be complete before this (command, RTIM, response on the wire); a bad
    /// frame that ends earlier is someone else's.
    earliest_reply: Instant,
    attempt: u8,
}

/// Why an attempt failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Failure {
    /// Nothing valid within Trt.
    Timeout,
    /// The answer arrived corrupted (bad BCC): the line is free now, no need to wait for Trt.
    Corrupted,
}

#[derive(Clone, Copy, Debug)]
struct Active {
    id: JobId,
    job: Job,
    cursor: u8,
    /// The furthest op reached; retries reset only past it (so a W4 rewound to its T4 keeps
    /// counting).
    high_water: u8,
    attempt: u8,
    /// Status responses received after this instant count for an `Await`.
    since: Instant,
    wait_deadline: Option<Instant>,
    readback: PointReadback,
    last: JobOutput,
}

/// The bus master; see the [module documentation](self).
#[derive(Debug)]
pub struct Engine {
    config: Config,
    axes: [AxisState; AXES],
    active: [Option<Active>; AXES],
    stops: [Option<(JobId, u8)>; AXES],
    queue: Deque<(JobId, Job), QUEUE_LEN>,
    events: Deque<Event, EVENT_LEN>,
    in_flight: Option<InFlight>,
    retry: Option<InFlight>,
    deframer: Deframer,
    line_baud: Baud,
    free_at: Instant,
    phase: Option<Phase>,
    settle_until: Instant,
    poll_cursor: u8,
    job_cursor: u8,
    position_credit: u8,
    position_due: AxisSet,
    probe_due: [Instant; AXES],
    probe_backoff: [Duration; AXES],
    rejoin: Option<(Axis, u8)>,
    rejoin_due: [Instant; AXES],
    rejoin_turn: bool,
    pending: Option<(Request, Origin, u8)>,
    next_id: u32,
    bus: BusCounters,
}

fn index(axis: Axis) -> usize {
    usize::from(axis.get())
}

impl Engine {
    /// An engine for `config`. With [`Config::establish`], the first outputs run §6-1.
    pub fn new(config: Config) -> Engine {
        let mut axes = [AxisState::new(); AXES];
        for axis in config.axes.iter() {
            if let Some(state) = axes.get_mut(index(axis)) {
                state.enabled = true;
                state.rtim = if config.establish {
                    RTIM_AFTER_BREAK
                } else {
                    config.rtim
                };
            }
        }
        let config = Config {
            retries: config.retries.min(3),
            ..config
        };
        Engine {
            config,
            axes,
            active: [None; AXES],
            stops: [None; AXES],
            queue: Deque::new(),
            events: Deque::new(),
            in_flight: None,
            retry: None,
            deframer: Deframer::new(),
            line_baud: config.baud,
            free_at: Instant(0),
            phase: config.establish.then_some(Phase::SlowBaud),
            settle_until: Instant(0),
            poll_cursor: 0,
            job_cursor: 0,
            position_credit: config.position_reads_per_cycle,
            position_due: AxisSet::default(),
            probe_due: [Instant(0); AXES],
            probe_backoff: [FIRST_PROBE; AXES],
            rejoin: None,
            rejoin_due: [Instant(0); AXES],
            rejoin_turn: false,
            pending: None,
            next_id: 0,
            bus: BusCounters::default(),
        }
    }

    /// The configuration in force.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// What the engine knows about `axis`.
    pub fn axis(&self, axis: Axis) -> &AxisState {
        // `index` is 0..=15 and `axes` has 16 entries.
        self.axes.get(index(axis)).unwrap_or(&self.axes[0])
    }

    /// Bus-level counters.
    pub fn bus_counters(&self) -> BusCounters {
        self.bus
    }

    /// Counters of the receive path (noise, echoes, rejected candidates).
    pub fn deframer(&self) -> &Deframer {
        &self.deframer
    }

    /// The line rate the engine has the UART at.
    pub fn line_baud(&self) -> Baud {
        self.line_baud
    }

    /// Jobs waiting for their axis.
    pub fn queued(&self) -> usize {
        self.queue.len()
    }

    /// Whether the establishment procedure is running.
    pub fn establishing(&self) -> bool {
        self.phase.is_some()
    }

    /// Run the communication establishment procedure (again). A resend left over from a
    /// procedure in progress is dropped: it belongs to the old one.
    pub fn establish(&mut self) {
        if matches!(self.retry, Some(f) if f.origin == Origin::Establish) {
            self.retry = None;
        }
        self.phase = Some(Phase::SlowBaud);
    }

    /// Whether `axis` has a job running or waiting, or a stop waiting.
    pub fn busy(&self, axis: Axis) -> bool {
        let i = index(axis);
        self.active.get(i).is_some_and(Option::is_some)
            || self.stops.get(i).is_some_and(Option::is_some)
            || self.queue.iter().any(|(_, job)| job.axis == axis)
    }

    /// Move the bus to another rate and RTIM: the establishment procedure runs with them
    /// (a break first, so every axis takes them).
    pub fn reconfigure(&mut self, baud: Baud, rtim: Rtim) {
        self.config.baud = baud;
        self.config.rtim = rtim;
        self.config.establish = true;
        self.establish();
    }

    /// Resends after a time-out, from now on (0-3).
    pub fn set_retries(&mut self, retries: u8) {
        self.config.retries = retries.min(3);
    }

    /// The oldest unread event.
    pub fn next_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    fn emit(&mut self, event: Event) {
        if self.events.is_full() {
            self.events.pop_front();
            self.bus.events_lost = self.bus.events_lost.wrapping_add(1);
        }
        // Cannot fail: there is room now.
        let _ = self.events.push_back(event);
    }

    fn state(&mut self, axis: Axis) -> Option<&mut AxisState> {
        self.axes.get_mut(index(axis))
    }

    /// Ask for a job. A [`JobKind::Stop`] jumps every queue and cancels the axis' other jobs.
    pub fn submit(&mut self, job: Job) -> Result<JobId, SubmitError> {
        if !self.config.axes.contains(job.axis) {
            return Err(SubmitError::AxisDisabled);
        }
        let id = JobId(self.next_id);
        if job.kind == JobKind::Stop {
            self.next_id = self.next_id.wrapping_add(1);
            self.cancel_jobs(job.axis);
            if let Some((old, _)) = self
                .stops
                .get_mut(index(job.axis))
                .and_then(|s| s.replace((id, 0)))
            {
                // Two stops in a row: the first is superseded by the second.
                self.emit(Event::JobDone {
                    id: old,
                    axis: job.axis,
                    result: Err(JobError::Cancelled),
                });
            }
            return Ok(id);
        }
        if self.queue.push_back((id, job)).is_err() {
            self.bus.queue_full = self.bus.queue_full.wrapping_add(1);
            return Err(SubmitError::QueueFull);
        }
        self.next_id = self.next_id.wrapping_add(1);
        Ok(id)
    }

    fn cancel_jobs(&mut self, axis: Axis) {
        if let Some(active) = self.active.get_mut(index(axis)).and_then(Option::take) {
            self.emit(Event::JobDone {
                id: active.id,
                axis,
                result: Err(JobError::Cancelled),
            });
        }
        for _ in 0..self.queue.len() {
            if let Some((id, job)) = self.queue.pop_front() {
                if job.axis == axis {
                    self.emit(Event::JobDone {
                        id,
                        axis,
                        result: Err(JobError::Cancelled),
                    });
                } else {
                    let _ = self.queue.push_back((id, job));
                }
            }
        }
        if matches!(self.in_flight, Some(f) if f.origin == Origin::Job && f.request.axis == axis) {
            // The answer still completes the transaction; nothing routes it to a job.
            if let Some(f) = self.in_flight.as_mut() {
                f.origin = Origin::Cancelled;
            }
        }
        if matches!(self.retry, Some(f) if f.origin == Origin::Job && f.request.axis == axis) {
            self.retry = None;
        }
        if matches!(self.pending, Some((r, Origin::Job, _)) if r.axis == axis) {
            // A job frame parked for a baud change: its job is gone.
            self.pending = None;
        }
    }

    /// Bytes received from the line at `now`.
    pub fn receive(&mut self, now: Instant, bytes: &[u8]) {
        for &byte in bytes {
            match self.deframer.push(byte) {
                Ok(Packet::Frame(frame)) => self.on_frame(now, &frame),
                Ok(Packet::CommChange) | Err(nb::Error::WouldBlock) => {}
                Err(nb::Error::Other(error)) => self.on_bad_candidate(now, error),
            }
        }
    }

    fn on_bad_candidate(&mut self, now: Instant, error: Error) {
        let Some(flight) = self.in_flight else {
            self.bus.unsolicited = self.bus.unsolicited.wrapping_add(1);
            return;
        };
        let bad_bcc = matches!(error, Error::BadBcc { .. });
        if let Some(state) = self.state(flight.request.axis) {
            let c = &mut state.counters;
            if bad_bcc {
                c.bcc_errors = c.bcc_errors.wrapping_add(1);
            } else {
                c.bad_replies = c.bad_replies.wrapping_add(1);
            }
        }
        let ours = self.deframer.rejected().get(2) == Some(&flight.request.axis.to_char());
        if bad_bcc && ours && now >= flight.earliest_reply {
            // A whole frame ended: whoever sent it is done and the line is free.
            self.attempt_failed(now, flight, Failure::Corrupted);
        }
    }

    fn on_frame(&mut self, now: Instant, frame: &Frame) {
        let Some(flight) = self.in_flight else {
            self.bus.unsolicited = self.bus.unsolicited.wrapping_add(1);
            return;
        };
        let axis = flight.request.axis;
        let reply = match Reply::parse(frame) {
            Ok(reply) if reply.answers(&flight.request).is_ok() && now >= flight.earliest_reply => {
                reply
            }
            _ => {
                // Malformed, another axis, or another command: never accepted.
                if let Some(state) = self.state(axis) {
                    state.counters.bad_replies = state.counters.bad_replies.wrapping_add(1);
                }
                return;
            }
        };
        self.in_flight = None;
        self.free_at = now + timing::HOST_GAP;
        self.complete(now, flight, reply);
    }

    fn complete(&mut self, now: Instant, flight: InFlight, reply: Reply) {
        let axis = flight.request.axis;
        let Some(state) = self.state(axis) else {
            return;
        };
        state.counters.replies = state.counters.replies.wrapping_add(1);
        if let Some(code) = reply.rejection() {
            state.counters.count_rejection(code);
            state.last_error = Some(LinkError::Rejected(code));
        }
        if flight.origin != Origin::Rejoin {
            // Online means answering at the bus rate; a rejoin talks at the power-up rate.
            self.set_link(now, axis, Link::Online);
        }
        if let Some(report) = reply.report() {
            self.update_report(now, axis, *report);
        }
        let reads_pnow =
            matches!(flight.request.command, Command::ReadMemory { address } if address == PNOW);
        if let (true, Some(position), Some(state)) =
            (reads_pnow, reply.position(), self.state(axis))
        {
            // Whoever asked (polling, a job), PNOW is PNOW.
            state.position = Some(position);
            state.position_at = Some(now);
        }
        match flight.origin {
            Origin::Poll | Origin::Probe | Origin::Position | Origin::Cancelled => {}
            Origin::Stop(id) => {
                let result = match (reply.rejection(), reply.report()) {
                    (Some(code), _) => Err(JobError::Rejected(code)),
                    (None, Some(report)) => Ok(JobOutput::Status(*report)),
                    (None, None) => Ok(JobOutput::Done),
                };
                self.emit(Event::JobDone { id, axis, result });
            }
            Origin::Job => self.job_reply(now, axis, &reply),
            Origin::Establish => self.establish_reply(axis, &flight.request, &reply),
            Origin::Rejoin => self.rejoin_reply(axis, &flight.request, &reply),
        }
    }

    fn set_link(&mut self, now: Instant, axis: Axis, link: Link) {
        let Some(state) = self.state(axis) else {
            return;
        };
        if state.link == link {
            return;
        }
        state.link = link;
        match link {
            Link::Online => {
                // Read its position once, so that it is known before the first move.
                self.position_due = self.position_due.with(axis);
                self.emit(Event::Online(axis));
            }
            Link::Offline => {
                if let Some(backoff) = self.probe_backoff.get_mut(index(axis)) {
                    *backoff = FIRST_PROBE;
                }
                if let Some(due) = self.probe_due.get_mut(index(axis)) {
                    *due = now + FIRST_PROBE;
                }
                self.emit(Event::Offline(axis));
                // A job that waits on an axis that no longer answers cannot finish.
                self.fail_job(axis, JobError::Timeout);
            }
            Link::Unknown => {}
        }
    }

    fn update_report(&mut self, now: Instant, axis: Axis, report: StatusReport) {
        let Some(state) = self.state(axis) else {
            return;
        };
        let changed = state.report != Some(report);
        let was_moving = state.moving();
        state.report = Some(report);
        state.report_at = Some(now);
        let moving = state.moving();
        if moving || was_moving {
            // Moving, or just stopped: its position is worth reading.
            self.position_due = self.position_due.with(axis);
        }
        if changed {
            self.emit(Event::Status { axis, report });
        }
        self.check_await(now, axis, &report);
        self.check_cross_axis_waits(now, axis);
    }

    fn check_await(&mut self, now: Instant, axis: Axis, report: &StatusReport) {
        let Some(active) = self.active.get(index(axis)).copied().flatten() else {
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
    fn check_cross_axis_waits(&mut self, now: Instant, axis: Axis) {
        for lead in Axis::all().filter(|&a| a != axis) {
            let Some(active) = self.active.get(index(lead)).copied().flatten() else {
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

    fn job_reply(&mut self, now: Instant, axis: Axis, reply: &Reply) {
        let Some(active) = self.active.get(index(axis)).copied().flatten() else {
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
                if let Some(active) = self.active.get_mut(index(axis)).and_then(Option::as_mut) {
                    if let (Some(slot), Some(value)) = (readback_slot(&active.job, cursor), value) {
                        if let Some(v) = active.readback.0.get_mut(slot) {
                            *v = value;
                        }
                    }
                    active.last = match (value, reply.report()) {
                        (Some(value), _) => JobOutput::Value(value),
                        (None, Some(report)) => JobOutput::Status(*report),
                        (None, None) => JobOutput::Done,
                    };
                }
                self.advance(now, axis);
            }
        }
    }

    /// Move the job of `axis` past its current op, and finish it at the end of its program.
    fn advance(&mut self, now: Instant, axis: Axis) {
        let motion_timeout = self.config.motion_timeout;
        let Some(active) = self.active.get_mut(index(axis)).and_then(Option::as_mut) else {
            return;
        };
        active.cursor = active.cursor.saturating_add(1);
        if active.cursor > active.high_water {
            active.high_water = active.cursor;
            active.attempt = 0;
        }
        active.since = now;
        active.wait_deadline = None;
        match program(&active.job, usize::from(active.cursor)) {
            Some(Op::Await(_)) => active.wait_deadline = Some(now + motion_timeout),
            Some(Op::Send(_)) => {}
            None => {
                let active = *active;
                let result = match (written(&active.job), active.job.kind) {
                    (Some(data), _) if !active.readback.matches(&data) => {
                        Err(JobError::VerifyFailed)
                    }
                    (Some(_), _) | (None, JobKind::ReadPoint(_)) => {
                        Ok(JobOutput::Point(active.readback))
                    }
                    _ => Ok(active.last),
                };
                self.finish(axis, result);
            }
        }
    }

    fn finish(&mut self, axis: Axis, result: Result<JobOutput, JobError>) {
        if let Some(active) = self.active.get_mut(index(axis)).and_then(Option::take) {
            self.emit(Event::JobDone {
                id: active.id,
                axis,
                result,
            });
        }
    }

    fn fail_job(&mut self, axis: Axis, error: JobError) {
        self.finish(axis, Err(error));
    }

    /// What to do at `now`.
    pub fn poll(&mut self, now: Instant) -> Output {
        if let Some(flight) = self.in_flight {
            if now < flight.deadline {
                return Output::Idle(Some(flight.deadline));
            }
            self.attempt_failed(now, flight, Failure::Timeout);
        }
        self.expire_waits(now);
        if now < self.free_at {
            return Output::Idle(Some(self.free_at));
        }
        if self.phase.is_some() {
            if let Some(output) = self.establish_step(now) {
                return output;
            }
        }
        // A stop goes before everything: before a frame parked for a baud change and before the
        // broadcasts of a rejoin.
        let next = match self.next_stop() {
            Some(stop) => {
                if let Some((request, origin, attempt)) = self.pending.take() {
                    // Job frames are rebuilt from their job's cursor, polls come round again.
                    match origin {
                        Origin::Rejoin => self.abort_rejoin(),
                        Origin::Stop(id) => self.requeue_stop(request.axis, id, attempt),
                        _ => {}
                    }
                }
                stop
            }
            None => {
                if let Some(output) = self.rejoin_line_action(now) {
                    return output;
                }
                match self.pending.take() {
                    Some(next) => next,
                    None => match self.next_transaction(now) {
                        Some(next) => next,
                        None => return Output::Idle(self.next_deadline()),
                    },
                }
            }
        };
        // Each transaction at its rate: a rejoining axis at the power-up rate, the rest at ours.
        let baud = if next.1 == Origin::Rejoin {
            crate::line::BAUD_AFTER_BREAK
        } else {
            self.config.baud
        };
        if self.line_baud != baud {
            self.line_baud = baud;
            self.deframer.reset();
            self.pending = Some(next);
            return Output::Line(LineAction::SetBaud(baud));
        }
        let (request, origin, attempt) = next;
        self.start(now, request, origin, attempt)
    }

    fn start(&mut self, now: Instant, request: Request, origin: Origin, attempt: u8) -> Output {
        let baud = self.line_baud;
        let Some(state) = self.state(request.axis) else {
            return Output::Idle(None);
        };
        state.counters.frames_sent = state.counters.frames_sent.wrapping_add(1);
        if attempt > 0 {
            state.counters.retries = state.counters.retries.wrapping_add(1);
        }
        let is_v5 = matches!(request.command, Command::StoreFromEdit(_));
        let deadline =
            now + timing::frame_time(baud).plus(timing::response_timeout(baud, state.rtim, is_v5));
        // §6-1 step 2: `p`'s own answer may already come after the new delay.
        let fastest = match request.command {
            Command::SetResponseDelay(new) => new.min(state.rtim),
            _ => state.rtim,
        };
        let rtim = Duration::from_millis(u64::from(fastest.get()));
        let earliest_reply = now
            + timing::frame_time(baud)
                .plus(rtim)
                .plus(timing::frame_time(baud));
        let frame = request.emit();
        if self.config.echo {
            self.deframer.expect_echo(&frame.to_bytes());
        }
        self.in_flight = Some(InFlight {
            request,
            origin,
            deadline,
            earliest_reply,
            attempt,
        });
        Output::Transmit(frame)
    }

    fn attempt_failed(&mut self, now: Instant, flight: InFlight, failure: Failure) {
        self.in_flight = None;
        let axis = flight.request.axis;
        match failure {
            Failure::Timeout => {
                self.free_at = now;
                self.deframer.reset();
                if let Some(state) = self.state(axis) {
                    state.counters.timeouts = state.counters.timeouts.wrapping_add(1);
                }
            }
            Failure::Corrupted => self.free_at = now + timing::HOST_GAP,
        }
        let may_retry = flight.attempt < self.config.retries
            && flight.request.command.resendable()
            && !matches!(
                flight.origin,
                Origin::Probe | Origin::Rejoin | Origin::Cancelled
            );
        if may_retry {
            let attempt = flight.attempt.saturating_add(1);
            let is_w4 = matches!(flight.request.command, Command::WriteMemory { .. });
            if flight.origin == Origin::Job {
                if let Some(active) = self.active.get_mut(index(axis)).and_then(Option::as_mut) {
                    active.attempt = attempt;
                    if is_w4 {
                        // §5 (1): the write address may have moved on; set it again first. A W4
                        // whose T4 is not the op before it cannot be resent.
                        let t4_before = active
                            .cursor
                            .checked_sub(1)
                            .and_then(|c| program(&active.job, usize::from(c)))
                            .is_some_and(|op| {
                                matches!(op, Op::Send(step) if matches!(step.request.command, Command::SetWriteAddress { .. }))
                            });
                        if !t4_before {
                            self.fail_job(axis, JobError::Timeout);
                            return;
                        }
                        active.cursor = active.cursor.saturating_sub(1);
                    }
                }
            } else if flight.origin == Origin::Establish && is_w4 {
                // The same rule during establishment: back to the T4 of this W4.
                if let Some(Phase::Configure { axis: a, step }) = self.phase {
                    self.phase = Some(Phase::Configure {
                        axis: a,
                        step: step.saturating_sub(1),
                    });
                }
            } else if let Origin::Stop(id) = flight.origin {
                // Stops keep their own resend: the shared slot may hold another one.
                self.requeue_stop(axis, id, attempt);
            } else {
                self.retry = Some(InFlight { attempt, ..flight });
            }
            return;
        }
        if let Some(state) = self.state(axis) {
            state.last_error = Some(LinkError::Timeout);
        }
        match flight.origin {
            Origin::Probe => self.probe_after(now, axis),
            Origin::Cancelled => {}
            Origin::Poll | Origin::Position => {
                self.set_link(now, axis, Link::Offline);
            }
            Origin::Job => {
                let error = if matches!(flight.request.command, Command::MoveRelative(_)) {
                    // It may have moved: never resend, read where it is.
                    self.position_due = self.position_due.with(axis);
                    JobError::OutcomeUnknown
                } else {
                    JobError::Timeout
                };
                self.fail_job(axis, error);
                if flight.request.command.resendable() {
                    // 1 + Nrt time-outs in a row: the axis is gone. (After one lost answer to a
                    // command that may not be resent, the next poll decides.)
                    self.set_link(now, axis, Link::Offline);
                }
            }
            Origin::Stop(id) => {
                self.emit(Event::JobDone {
                    id,
                    axis,
                    result: Err(JobError::Timeout),
                });
                self.set_link(now, axis, Link::Offline);
            }
            Origin::Establish => {
                self.set_link(now, axis, Link::Offline);
                self.establish_next_axis(axis);
            }
            Origin::Rejoin => self.abort_rejoin(),
        }
    }

    fn expire_waits(&mut self, now: Instant) {
        for axis in Axis::all() {
            let expired = self
                .active
                .get(index(axis))
                .copied()
                .flatten()
                .and_then(|a| a.wait_deadline)
                .is_some_and(|deadline| now >= deadline);
            if expired {
                self.fail_job(axis, JobError::WaitTimeout);
            }
        }
    }

    /// Put a stop back in its slot, unless a newer stop for the axis supersedes it.
    fn requeue_stop(&mut self, axis: Axis, id: JobId, attempt: u8) {
        match self.stops.get_mut(index(axis)) {
            Some(slot @ None) => *slot = Some((id, attempt)),
            _ => self.emit(Event::JobDone {
                id,
                axis,
                result: Err(JobError::Cancelled),
            }),
        }
    }

    /// The next stop (`d`) waiting to go, if any.
    fn next_stop(&mut self) -> Option<(Request, Origin, u8)> {
        Axis::all().find_map(|axis| {
            self.stops
                .get_mut(index(axis))
                .and_then(Option::take)
                .map(|(id, attempt)| {
                    (
                        Request::new(axis, Command::CancelMotion),
                        Origin::Stop(id),
                        attempt,
                    )
                })
        })
    }

    fn next_transaction(&mut self, now: Instant) -> Option<(Request, Origin, u8)> {
        // 1. Stops, before anything else (poll() has taken them already; this is for safety).
        if let Some(stop) = self.next_stop() {
            return Some(stop);
        }
        // 2. A resend.
        if let Some(retry) = self.retry.take() {
            return Some((retry.request, retry.origin, retry.attempt));
        }
        // 3. Job frames.
        self.activate_jobs(now);
        if let Some(next) = self.next_job_frame() {
            return Some(next);
        }
        // 4. A rejoining axis' next step, every other turn with polling (and whenever polling
        //    has nothing to send).
        self.rejoin_turn = !self.rejoin_turn;
        if self.rejoin_turn {
            if let Some(next) = self.next_rejoin_frame() {
                return Some(next);
            }
        }
        // 5. Polling.
        self.next_poll(now).or_else(|| self.next_rejoin_frame())
    }

    fn activate_jobs(&mut self, now: Instant) {
        for _ in 0..self.queue.len() {
            let Some((id, job)) = self.queue.pop_front() else {
                break;
            };
            let slot = self.active.get_mut(index(job.axis));
            match slot {
                Some(slot @ None) => {
                    *slot = Some(Active {
                        id,
                        job,
                        cursor: 0,
                        high_water: 0,
                        attempt: 0,
                        since: now,
                        wait_deadline: None,
                        readback: PointReadback::default(),
                        last: JobOutput::Done,
                    });
                    if let Some(Op::Await(_)) = program(&job, 0) {
                        if let Some(Some(active)) = self.active.get_mut(index(job.axis)) {
                            active.wait_deadline = Some(now + self.config.motion_timeout);
                        }
                    }
                }
                _ => {
                    let _ = self.queue.push_back((id, job));
                }
            }
        }
    }

    fn next_job_frame(&mut self) -> Option<(Request, Origin, u8)> {
        for offset in 0..AXES {
            let i = (usize::from(self.job_cursor) + offset) % AXES;
            let Some(Some(active)) = self.active.get(i) else {
                continue;
            };
            if let Some(Op::Send(step)) = program(&active.job, usize::from(active.cursor)) {
                self.job_cursor = u8::try_from((i + 1) % AXES).unwrap_or(0);
                return Some((step.request, Origin::Job, active.attempt));
            }
        }
        None
    }

    fn next_poll(&mut self, now: Instant) -> Option<(Request, Origin, u8)> {
        if self.position_credit > 0 {
            if let Some(axis) = self.oldest_position_due() {
                self.position_credit -= 1;
                self.position_due = AxisSet(self.position_due.0 & !(1 << axis.get()));
                let read = Command::ReadMemory { address: PNOW };
                return Some((Request::new(axis, read), Origin::Position, 0));
            }
        }
        for _ in 0..AXES {
            let axis = Axis::new(self.poll_cursor)?;
            self.poll_cursor = (self.poll_cursor + 1) % 16;
            if self.poll_cursor == 0 {
                self.position_credit = self.config.position_reads_per_cycle;
            }
            let state = self.axis(axis);
            if !state.enabled {
                continue;
            }
            if state.link == Link::Offline {
                if self.rejoin.is_some_and(|(a, _)| a == axis) {
                    // Being reconfigured at the power-up rate: not there at ours.
                    continue;
                }
                let due = self.probe_due.get(index(axis)).copied().unwrap_or(now);
                if now < due {
                    continue;
                }
                if self.start_rejoin(now, axis) {
                    self.probe_after(now, axis);
                    continue;
                }
                return Some((Request::new(axis, Command::Status), Origin::Probe, 0));
            }
            return Some((Request::new(axis, Command::Status), Origin::Poll, 0));
        }
        None
    }

    /// Schedule the next probe of an offline axis: twice the last wait, up to
    /// [`Config::probe_interval`], counted from now (the end of the failed attempt).
    fn probe_after(&mut self, now: Instant, axis: Axis) {
        let max = self.config.probe_interval;
        let i = index(axis);
        let wait = self
            .probe_backoff
            .get(i)
            .map_or(max, |b| Duration(b.0.saturating_mul(2)).min(max));
        if let Some(backoff) = self.probe_backoff.get_mut(i) {
            *backoff = wait;
        }
        if let Some(due) = self.probe_due.get_mut(i) {
            *due = now + wait;
        }
    }

    fn oldest_position_due(&self) -> Option<Axis> {
        self.position_due
            .iter()
            .filter(|&a| self.axis(a).link == Link::Online)
            .min_by_key(|&a| self.axis(a).position_at.map_or(0, |t| t.0))
    }

    fn next_deadline(&self) -> Option<Instant> {
        let probes = self
            .config
            .axes
            .iter()
            .filter(|&a| self.axis(a).link == Link::Offline)
            .filter_map(|a| self.probe_due.get(index(a)).copied());
        let waits = self.active.iter().flatten().filter_map(|a| a.wait_deadline);
        probes.chain(waits).min()
    }

    // ------------------------------------------------------------ rejoin of one axis

    /// Begin reconfiguring `axis` at the power-up settings, if it is time to try.
    fn start_rejoin(&mut self, now: Instant, axis: Axis) -> bool {
        let due = self.rejoin_due.get(index(axis)).copied().unwrap_or(now);
        if !self.config.establish || self.rejoin.is_some() || now < due {
            return false;
        }
        if let Some(slot) = self.rejoin_due.get_mut(index(axis)) {
            *slot = now + self.config.rejoin_interval;
        }
        if let Some(state) = self.state(axis) {
            state.rtim = RTIM_AFTER_BREAK;
        }
        self.rejoin = Some((axis, 0));
        true
    }

    /// Give up the rejoin in progress: the axis is probed at the bus' settings again.
    fn abort_rejoin(&mut self) {
        if let Some((axis, _)) = self.rejoin.take() {
            let rtim = self.config.rtim;
            if let Some(state) = self.state(axis) {
                state.rtim = rtim;
            }
        }
    }

    /// Steps 0-4 are the frames of §6-1 steps 2-6 for the axis.
    fn next_rejoin_frame(&mut self) -> Option<(Request, Origin, u8)> {
        let (axis, step) = self.rejoin?;
        let command = establish::configure(step, self.config.baud, self.config.rtim)?;
        Some((Request::new(axis, command), Origin::Rejoin, 0))
    }

    fn rejoin_reply(&mut self, axis: Axis, request: &Request, reply: &Reply) {
        if reply.rejection().is_some() {
            self.abort_rejoin();
            return;
        }
        if let Command::SetResponseDelay(rtim) = request.command {
            if let Some(state) = self.state(axis) {
                state.rtim = rtim;
            }
        }
        if let Some((a, step)) = self.rejoin {
            self.rejoin = Some((a, step.saturating_add(1)));
        }
    }

    /// After the five frames: the broadcast (three times, at the power-up rate, where only the
    /// rejoining axis listens), then the axis takes the new settings 150 ms later.
    fn rejoin_line_action(&mut self, now: Instant) -> Option<Output> {
        let (axis, step) = self.rejoin?;
        let configured = establish::configure(step, self.config.baud, self.config.rtim).is_some();
        if configured {
            return None;
        }
        let sent = step.saturating_sub(5);
        if sent < COMM_CHANGE_REPEATS {
            if self.line_baud != crate::line::BAUD_AFTER_BREAK {
                self.line_baud = crate::line::BAUD_AFTER_BREAK;
                self.deframer.reset();
                return Some(Output::Line(LineAction::SetBaud(self.line_baud)));
            }
            self.rejoin = Some((axis, step.saturating_add(1)));
            self.free_at = now + timing::frame_time(self.line_baud);
            return Some(Output::Line(LineAction::CommChange));
        }
        self.rejoin = None;
        let settle = Duration::from_millis(u64::from(COMM_CHANGE_SETTLE_MS) + 10);
        let rtim = self.config.rtim;
        if let Some(state) = self.state(axis) {
            state.rtim = rtim;
        }
        if let Some(slot) = self.probe_due.get_mut(index(axis)) {
            *slot = now + settle;
        }
        None
    }

    // ------------------------------------------------------------ establishment (§6-1)

    fn establish_step(&mut self, now: Instant) -> Option<Output> {
        let phase = self.phase?;
        if phase == Phase::Settle {
            if now < self.settle_until {
                return Some(Output::Idle(Some(self.settle_until)));
            }
            self.phase = None;
            let rtim = self.config.rtim;
            for state in self.axes.iter_mut().filter(|s| s.enabled) {
                state.rtim = rtim;
            }
            self.bus.establishments = self.bus.establishments.wrapping_add(1);
            self.emit(Event::Established);
            return None;
        }
        if let Some(retry) = self.retry.take() {
            return Some(self.start(now, retry.request, retry.origin, retry.attempt));
        }
        match establish::next(phase, self.config.baud, self.config.rtim) {
            Some(Next::Line(action)) => {
                self.phase = Some(self.after(phase));
                match action {
                    LineAction::SetBaud(baud) => {
                        self.line_baud = baud;
                        self.deframer.reset();
                    }
                    LineAction::Break => {
                        self.free_at = now + Duration::from_millis(u64::from(BREAK_MS));
                        self.deframer.reset();
                        for state in self.axes.iter_mut() {
                            state.rtim = RTIM_AFTER_BREAK;
                        }
                    }
                    LineAction::CommChange => {
                        self.free_at = now + timing::frame_time(self.line_baud);
                    }
                }
                if self.phase == Some(Phase::Settle) {
                    self.settle_until =
                        now + Duration::from_millis(u64::from(COMM_CHANGE_SETTLE_MS));
                }
                Some(Output::Line(action))
            }
            Some(Next::Send(axis, command)) => {
                Some(self.start(now, Request::new(axis, command), Origin::Establish, 0))
            }
            None => None,
        }
    }

    /// The phase after a line action.
    fn after(&self, phase: Phase) -> Phase {
        match phase {
            Phase::SlowBaud => Phase::Break,
            Phase::Break => self.configure_from(0),
            Phase::Broadcast { sent } if sent.saturating_add(1) < COMM_CHANGE_REPEATS => {
                Phase::Broadcast { sent: sent + 1 }
            }
            Phase::Broadcast { .. } => Phase::FastBaud,
            Phase::FastBaud | Phase::Settle => Phase::Settle,
            Phase::Configure { .. } => phase,
        }
    }

    /// Configure the first enabled axis numbered `from` or above, or broadcast if none is left.
    fn configure_from(&self, from: u8) -> Phase {
        self.config.axes.iter().find(|a| a.get() >= from).map_or(
            Phase::Broadcast { sent: 0 },
            |axis| Phase::Configure { axis, step: 0 },
        )
    }

    fn establish_next_axis(&mut self, axis: Axis) {
        self.phase = Some(self.configure_from(axis.get().saturating_add(1)));
        if axis.get() == 15 {
            self.phase = Some(Phase::Broadcast { sent: 0 });
        }
    }

    fn establish_reply(&mut self, axis: Axis, request: &Request, reply: &Reply) {
        let Some(Phase::Configure { step, .. }) = self.phase else {
            return;
        };
        if reply.rejection().is_some() {
            // A refused step (e.g. `p` during motor initialisation, warning 74): the axis keeps
            // its power-up settings; it will be offline at the new rate and rejoin later.
            if let Some(state) = self.state(axis) {
                state.rtim = RTIM_AFTER_BREAK;
            }
            self.establish_next_axis(axis);
            return;
        }
        if let Command::SetResponseDelay(rtim) = request.command {
            // §6-1 step 2: the new delay is in force from this reply on.
            if let Some(state) = self.state(axis) {
                state.rtim = rtim;
            }
        }
        if establish::configure(step.saturating_add(1), self.config.baud, self.config.rtim)
            .is_some()
        {
            self.phase = Some(Phase::Configure {
                axis,
                step: step + 1,
            });
        } else {
            self.establish_next_axis(axis);
        }
    }
}
