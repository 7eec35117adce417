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
//!         Output::Line(action)    => do it (break start/end, baud change, COMM_CHANGE bytes),
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
//! - order: every axis' first stop (`d`) before everything (before any resend, the
//!   establishment's next step, a rejoin or a poll; axes that answer first), then resends of
//!   stops, then a pending retry, then job frames, then polling (`schedule`);
//! - a stop is never given up: one that gets no answer leaves the axis owed it, and the next
//!   frame the axis answers is that stop ([`Engine::stop_owed`]);
//! - a job never runs late: one for an axis that is offline fails at once, and an axis that
//!   goes offline takes its running and waiting jobs with it ([`JobError::Offline`]);
//! - nothing, not even a stop, goes to an axis after it leaves the bus
//!   ([`Engine::reconfigure`]): it may be another master's now (AXISBASE); its jobs and its stop
//!   end as [`JobError::Cancelled`];
//! - at start, the communication establishment procedure (§6-1, `establish`) if configured,
//!   and later the rejoin of a power-cycled axis (`rejoin`).
//!
//! | Module | What it holds |
//! |---|---|
//! | `config` | [`Config`] |
//! | `output` | [`Output`], [`Event`], [`SubmitError`], [`BusCounters`] |
//! | `axis` | What the engine knows about each axis ([`AxisState`]) |
//! | `job` | Jobs as programs of frames and waits |
//! | [`point_jobs`] | Point-table reads and writes as frame sequences (a `job`'s frames) |
//! | `run` | Running the jobs: activation, responses, waits, completion |
//! | `schedule` | Polling: status round robin, position reads, probes of offline axes |
//! | `approach` | When a mover is expected at its target (the schedule polls it then) |
//! | `transaction` | One frame and its answer: time-out, matching, resends |
//! | `reply` | What an answer changes: the axis' status, link and position, its job, the estimate |
//! | `establish`, `rejoin` | §6-1 for the whole bus, and for one power-cycled axis |
//! | [`timing`] | §2 and §5 timing formulas |

mod approach;
mod axis;
mod config;
mod establish;
mod job;
mod output;
pub mod point_jobs;
mod rejoin;
mod reply;
mod run;
mod schedule;
pub mod timing;
mod transaction;

pub use axis::{AxisState, Counters, Link, LinkError};
pub use config::{Config, MAX_RETRIES};
pub use job::{Job, JobError, JobId, JobKind, JobOutput, PointAim};
pub use output::{BusCounters, Event, Output, SubmitError};

use establish::Phase;
use heapless::Deque;
use rejoin::Rejoin;
use run::Active;
use schedule::Schedule;

use crate::axes::{AxisMap, AxisSet};
use crate::line::{Baud, LineAction};
use crate::memory::PNOW;
use crate::time::{Duration, Instant};
use crate::{Axis, Command, Deframer, Packet, Reply, Request, StatusReport, RTIM_AFTER_BREAK};

/// Jobs waiting for their axis; more are refused with [`SubmitError::QueueFull`].
pub const QUEUE_LEN: usize = 32;
/// Jobs waiting for one axis (besides the one running); more are refused with
/// [`SubmitError::QueueFull`]. This also bounds the events one stop can cause (each job it
/// cancels reports once), so that a reader that drains events after each call loses none.
pub const WAITING_PER_AXIS: usize = 6;
/// Events kept until read; older ones are dropped and counted when it overflows.
pub const EVENT_LEN: usize = 32;

/// The first probe of an axis that just went offline follows this soon.
pub const FIRST_PROBE: Duration = Duration::from_millis(20);

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

/// A transaction to start: the frame, who asked, and which attempt it is.
type Next = (Request, Origin, u8);

#[derive(Clone, Copy, Debug)]
struct InFlight {
    request: Request,
    origin: Origin,
    /// No valid response by then: a time-out.
    deadline: Instant,
    /// With [`Config::wire_timing`], the answer cannot be complete before this (command, RTIM,
    /// response on the wire): a frame that ends earlier is someone else's.
    earliest_reply: Instant,
    /// When the command was handed over to go on the wire.
    sent: Instant,
    attempt: u8,
    /// The frame is the stop the axis is owed, sent in place of `origin`'s (see
    /// [`Engine::stop_owed`]): its answer clears the debt and moves `origin` on by nothing, its
    /// loss counts as `origin`'s.
    stands_in: bool,
}

/// A stop (`d`) waiting to go.
#[derive(Clone, Copy, Debug)]
struct WaitingStop {
    id: JobId,
    /// The tries used so far (of this stop, or of the ones it superseded).
    tries: u8,
    /// When it was first asked for (a job number): the first stops go in that order.
    asked: u32,
    /// The axis' first stop since it was asked for (none went since): it goes before resends.
    first: bool,
}

/// Why an attempt failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Failure {
    /// Nothing valid within Trt.
    Timeout,
    /// The answer arrived corrupted (bad BCC): the line is free now, no need to wait for Trt.
    Corrupted,
}

/// The bus master; see the [module documentation](self).
#[derive(Debug)]
pub struct Engine {
    config: Config,
    axes: AxisMap<AxisState>,
    active: AxisMap<Option<Active>>,
    /// Each axis' stop waiting to go.
    stops: AxisMap<Option<WaitingStop>>,
    /// Axes owed a stop: theirs got no answer ([`Engine::stop_owed`]).
    owed: AxisSet,
    queue: Deque<(JobId, Job), QUEUE_LEN>,
    events: Deque<Event, EVENT_LEN>,
    in_flight: Option<InFlight>,
    /// A transaction to send again (only what starts it: its time limits are new).
    retry: Option<Next>,
    /// A transaction parked while the line changes rate for it.
    pending: Option<Next>,
    deframer: Deframer,
    /// When the last bytes came in.
    received_at: Instant,
    line_baud: Baud,
    /// No command before this (host gap, a break, a broadcast on the wire).
    free_at: Instant,
    /// A break in progress ends then ([`LineAction::BreakEnd`]).
    break_until: Option<Instant>,
    phase: Option<Phase>,
    settle_until: Instant,
    schedule: Schedule,
    rejoin: Rejoin,
    job_cursor: u8,
    next_id: u32,
    bus: BusCounters,
}

impl Engine {
    /// An engine for `config`. With [`Config::establish`], the first outputs run §6-1.
    ///
    /// Not inlined: built in its caller's result (see [`Node::new`](crate::node::Node::new)).
    #[inline(never)]
    pub const fn new(config: Config) -> Engine {
        // Changed in place (the copy a `Config { retries, ..config }` made was field by field).
        let mut config = config;
        if config.retries > MAX_RETRIES {
            config.retries = MAX_RETRIES;
        }
        // §6-1 first (every axis at the power-up RTIM after its break), or polling at once.
        let (rtim, phase) = if config.establish {
            (RTIM_AFTER_BREAK, Some(Phase::SlowBaud))
        } else {
            (config.rtim, None)
        };
        Engine {
            config,
            axes: AxisMap::new(AxisState::new(rtim)),
            active: AxisMap::new(None),
            stops: AxisMap::new(None),
            owed: AxisSet::EMPTY,
            queue: Deque::new(),
            events: Deque::new(),
            in_flight: None,
            retry: None,
            pending: None,
            deframer: Deframer::new(),
            received_at: Instant::ZERO,
            line_baud: config.baud,
            free_at: Instant::ZERO,
            break_until: None,
            phase,
            settle_until: Instant::ZERO,
            schedule: Schedule::new(config.position_reads_per_cycle),
            rejoin: Rejoin::new(),
            job_cursor: 0,
            next_id: 0,
            bus: BusCounters::ZERO,
        }
    }

    /// The configuration in force.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// What the engine knows about `axis`.
    pub fn axis(&self, axis: Axis) -> &AxisState {
        &self.axes[axis]
    }

    /// When the axis' move in progress is expected at its target (`approach`), if the engine
    /// has an estimate: the schedule polls its status from just before then.
    pub fn expected_arrival(&self, axis: Axis) -> Option<Instant> {
        self.schedule.eta(axis)
    }

    /// Whether `axis` is on the bus (configured).
    pub fn configured(&self, axis: Axis) -> bool {
        self.config.axes.contains(axis)
    }

    /// Whether `axis` answers at the bus' settings.
    pub fn online(&self, axis: Axis) -> bool {
        self.axes[axis].link == Link::Online
    }

    /// Whether `axis` is owed a stop: one was due and got no answer after its resends (the
    /// axis was offline, or the wire cut). The debt stands until the axis answers a `d`: every
    /// frame the engine would send it meanwhile (a probe, a rejoin's try, an establishment
    /// step, a poll) goes out as `d` instead, so the first frame it answers is its stop. A stop
    /// is never given up; an axis taken off the bus is no longer owed one (it may be another
    /// master's now).
    pub fn stop_owed(&self, axis: Axis) -> bool {
        self.owed.contains(axis)
    }

    /// The command on the wire, waiting for its answer (or its time-out), if any.
    pub fn in_flight(&self) -> Option<Request> {
        self.in_flight.map(|f| f.request)
    }

    /// Bus-level counters.
    pub fn bus_counters(&self) -> BusCounters {
        self.bus
    }

    /// Counters of the receive path (noise, echoes, rejected candidates).
    pub fn deframer(&self) -> &Deframer {
        &self.deframer
    }

    /// When the frame whose first bytes came in will have arrived whole (the rest at the line's
    /// character time after the last bytes given to [`receive`](Self::receive)); `None` between
    /// frames. Until then a caller may leave the bytes in its UART buffer and take them in one
    /// go: a wake per frame instead of one per byte, the same frames at the same moments.
    pub fn frame_due(&self) -> Option<Instant> {
        let missing = self.deframer.missing() as u64;
        (missing > 0).then(|| {
            let char_time = timing::char_time(self.line_baud).0;
            self.received_at + Duration(char_time.saturating_mul(missing))
        })
    }

    /// The line rate the engine has the UART at.
    pub fn line_baud(&self) -> Baud {
        self.line_baud
    }

    /// Jobs waiting for their axis.
    pub fn queued(&self) -> usize {
        self.queue.len()
    }

    /// How many more jobs `axis` can take now (0 when the queue or the axis' share is full).
    pub fn room(&self, axis: Axis) -> usize {
        let waiting = self
            .queue
            .iter()
            .filter(|(_, job)| job.axis == axis)
            .count();
        QUEUE_LEN
            .saturating_sub(self.queue.len())
            .min(WAITING_PER_AXIS.saturating_sub(waiting))
    }

    /// Whether the establishment procedure is running.
    pub fn establishing(&self) -> bool {
        self.phase.is_some()
    }

    /// Whether `axis` has a job running or waiting, or a stop waiting.
    pub fn busy(&self, axis: Axis) -> bool {
        self.active[axis].is_some()
            || self.stops[axis].is_some()
            || (!self.queue.is_empty() && self.queue.iter().any(|(_, job)| job.axis == axis))
    }

    /// Whether job `id` is still running or waiting.
    pub fn pending(&self, id: JobId) -> bool {
        self.active.values().flatten().any(|a| a.id == id)
            || self.stops.values().flatten().any(|s| s.id == id)
            || self.queue.iter().any(|(j, _)| *j == id)
    }

    /// Move the bus to another set of axes, rate and RTIM: the establishment procedure runs
    /// with them (a break first, so every axis takes them). An axis that leaves the bus gets
    /// nothing more, not even a stop: it may be another master's now (several gateways share a
    /// line through AXISBASE), and the PLC took it off deliberately. Its running and waiting
    /// jobs and its stop end as [`JobError::Cancelled`].
    pub fn reconfigure(&mut self, axes: AxisSet, baud: Baud, rtim: crate::Rtim) {
        let left = AxisSet(self.config.axes.0 & !axes.0);
        self.config.axes = axes;
        self.owed = AxisSet(self.owed.0 & axes.0);
        self.config.baud = baud;
        self.config.rtim = rtim;
        self.config.establish = true;
        for axis in left.iter() {
            self.leave(axis);
        }
        self.establish();
    }

    /// `axis` has left the bus ([`reconfigure`](Self::reconfigure) says why nothing more goes
    /// to it): drop everything that would still send it a frame. Its jobs and its stop are
    /// reported cancelled, so that no CMST stays "taken". A frame of it still on the wire turns
    /// `Origin::Cancelled` (never resent), and its answer is ignored
    /// ([`complete`](Self::complete)), so that an Online, a status or a position cannot put the
    /// axis back into the schedule. Polls, probes and the establishment look only at the axes on
    /// the bus.
    // Not inlined: inlined in the gateway's APPLY it took 12 B more of the F103's flash.
    #[inline(never)]
    fn leave(&mut self, axis: Axis) {
        self.cancel_jobs(axis, JobError::Cancelled);
        if let Some(WaitingStop { id, .. }) = self.stops[axis].take() {
            self.job_failed(id, axis, JobError::Cancelled);
        }
        // Its stop may also be on the wire or parked for a baud change (not both: a stop starts
        // only with nothing parked, and nothing is parked while it is on the wire).
        let mut held = None;
        if let Some(flight) = self.in_flight.as_mut().filter(|f| f.request.axis == axis) {
            held = Some(core::mem::replace(&mut flight.origin, Origin::Cancelled));
        }
        if matches!(self.pending, Some((r, _, _)) if r.axis == axis) {
            held = self.pending.take().map(|(_, origin, _)| origin);
        }
        if let Some(Origin::Stop(id)) = held {
            self.job_failed(id, axis, JobError::Cancelled);
        }
        if matches!(self.retry, Some((r, _, _)) if r.axis == axis) {
            self.retry = None;
        }
        if self.rejoining(axis) {
            self.abort_rejoin();
        }
        self.schedule.forget(axis);
    }

    /// Resends after a time-out, from now on (0-3).
    pub fn set_retries(&mut self, retries: u8) {
        self.config.retries = retries.min(MAX_RETRIES);
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

    /// Ask for a job. A [`JobKind::Stop`] jumps every queue and cancels the axis' other jobs.
    pub fn submit(&mut self, job: Job) -> Result<JobId, SubmitError> {
        if !self.configured(job.axis) {
            return Err(SubmitError::AxisDisabled);
        }
        let id = JobId(self.next_id);
        if job.kind == JobKind::Stop {
            self.next_id = self.next_id.wrapping_add(1);
            self.cancel_jobs(job.axis, JobError::Cancelled);
            // A stop for an axis whose stop is still unanswered takes over the tries that one
            // has used (here, or in `requeue_stop` when the one on the wire fails), so the axis
            // still goes offline, owing it, after 1 + retries time-outs; the PIO repeats its
            // stop while *STP is off, and a fresh round at every repeat kept a cut axis online
            // for ever. It keeps that one's place among the stops waiting, and it is the axis'
            // first stop unless a `d` to the axis is on the wire (that one is).
            let on_wire = matches!(self.in_flight,
                Some(f) if f.request.axis == job.axis
                    && matches!(f.request.command, Command::CancelMotion));
            let waiting = WaitingStop {
                id,
                tries: 0,
                asked: id.0,
                first: !on_wire,
            };
            let waiting = match self.stops[job.axis] {
                Some(old) => WaitingStop {
                    tries: old.tries,
                    asked: old.asked,
                    ..waiting
                },
                None => waiting,
            };
            if let Some(WaitingStop { id: old, .. }) = self.stops[job.axis].replace(waiting) {
                // Two stops in a row: the first is superseded by the second.
                self.job_failed(old, job.axis, JobError::Cancelled);
            }
            return Ok(id);
        }
        if self.room(job.axis) == 0 || self.queue.push_back((id, job)).is_err() {
            self.bus.queue_full = self.bus.queue_full.wrapping_add(1);
            return Err(SubmitError::QueueFull);
        }
        self.next_id = self.next_id.wrapping_add(1);
        Ok(id)
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
        if let Some(end) = self.break_until {
            if now < end {
                return Output::Idle(Some(end));
            }
            self.break_until = None;
            return Output::Line(LineAction::BreakEnd);
        }
        if now < self.free_at {
            return Output::Idle(Some(self.free_at));
        }
        // A stop goes before everything: before the establishment's next step, a frame parked
        // for a baud change and the broadcasts of a rejoin.
        // A stop parked for a baud change is one of the stops: it goes on first.
        let parked = match self.pending {
            Some((_, Origin::Stop(_), _)) => self.pending.take(),
            _ => None,
        };
        let next = match parked.or_else(|| self.next_stop()) {
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
                if self.phase.is_some() {
                    if let Some(output) = self.establish_step(now) {
                        return output;
                    }
                }
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
        // During §6-1 a stop goes at the rate the procedure has the line at: the axes listen
        // there until its broadcast.
        let baud = match next.1 {
            Origin::Rejoin => crate::line::BAUD_AFTER_BREAK,
            _ if self.phase.is_some() => self.line_baud,
            _ => self.config.baud,
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

    /// What goes when no stop waits: [`poll`](Self::poll), the only caller, has taken the
    /// stops (rule 1, before everything) just before.
    fn next_transaction(&mut self, now: Instant) -> Option<Next> {
        // 2. A resend.
        if let Some(retry) = self.retry.take() {
            return Some(retry);
        }
        // 3. A mover at its expected arrival (a few in a row at most), then job frames.
        if let Some(poll) = self.arrival_poll(now) {
            return Some(poll);
        }
        self.activate_jobs(now);
        let cursor = self.job_cursor;
        let job = self.next_job_frame();
        if self.job_turn(job.is_some()) {
            return job;
        }
        // 4. A rejoining axis' next step, every other turn with polling (and whenever polling
        //    has nothing to send); not on a turn taken from a job frame, as it holds the bus up
        //    to 300 ms.
        if job.is_none() && self.rejoin.take_turn() {
            if let Some(next) = self.next_rejoin_frame() {
                return Some(next);
            }
        }
        // 5. Polling. On its turn taken from a job frame, the frame waits, first in turn still,
        //    and goes if polling has nothing to send.
        let poll = self.next_poll(now);
        if job.is_some() {
            if poll.is_some() {
                self.job_cursor = cursor;
            }
            return poll.or(job);
        }
        poll.or_else(|| self.next_rejoin_frame())
    }
}
