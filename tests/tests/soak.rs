//! Soak: a million transactions on a faulty 16-axis bus, in virtual time, checked frame by
//! frame against what the simulated controllers really sent.
//!
//! Set-up: 16 controllers already at 115.2 kbit/s and RTIM 3 ms (stored in their non-volatile
//! memory, `ControllerConfig::stored_line`), an engine that assumes so (`Config::establish`
//! false, Nrt = 2). Faults: 1 % of the bytes corrupted in both directions, 0.5 % of the replies
//! dropped, 0.5 % sent late (21-45 ms late, changed every 250 ms: after Trt = 20 ms + RTIM +
//! one frame, so they land in a later transaction, cleanly or colliding; only a V5, with its
//! 200 ms Trt, still gets them in time), and a little line noise. A seeded PLC workload keeps
//! every axis busy: homing first, then relative moves (most of them, often two or three queued,
//! some as DirectMove), absolute moves, SetMotion, servo off/on, point writes followed by a move
//! to the point, single-field writes, point reads, stops (some of them 0-30 ms after a move, so
//! while its frame is on the wire), and alarm resets when a move to an empty point raised alarm
//! B1. After 1,000,000 frames it stops submitting and drains. `SOAK_SEED` and
//! `SOAK_TRANSACTIONS` change the seed and the length. Run with `--nocapture` for the counts.
//!
//! # The oracle
//!
//! The test drives the engine and the bus itself (the loop of `Harness::step`, byte by byte),
//! so that it sees everything between two bytes:
//!
//! * **What each controller really sent.** A controller's prepared reply
//!   (`Controller::pending_reply`: 16 bytes and the instant they go out) is read whenever a
//!   controller may have prepared or sent one (`replies_scheduled`/`replies_sent` moved). When
//!   `replies_sent` moves, the reply that was pending is the one put on the line, as it was
//!   *before* the bus corrupted it (`Bus::start_reply` corrupts a copy). The transaction in
//!   flight when it was prepared is the command it answers. So for every reply on the wire the
//!   test knows the sender, the intact bytes, start and end, and the command it answers.
//! * **What the host received.** Each byte given to `Engine::receive` is attributed to the reply
//!   whose byte slot falls on exactly that microsecond (byte k of a transmission starting at t0
//!   arrives at t0 + byte_offset(k + 1)); bytes that fit no reply are noise or collision
//!   debris. A reply arrived *intact* iff each of its 16 slots got exactly one byte, the byte
//!   sent.
//! * **What the engine saw.** A mirror `Deframer` gets the same bytes; after every byte its
//!   counters must equal the engine's (`Engine::deframer`), so its candidates are the engine's.
//!   (The engine resets its deframer at a time-out: after `poll` the difference is exactly the
//!   dropped partial candidate, and the mirror resets too.)
//!
//! Then every candidate frame must change exactly the counter the rules say, and nothing else:
//! a valid answer to the request in flight `replies`; another valid frame or a broken candidate
//! `bad_replies`/`bcc_errors` of the axis in flight; anything while nothing is in flight
//! `unsolicited`. **(1)** is checked where the engine may change what it knows about an axis:
//!
//! * `report`/`report_at`/`position`/`position_at` of an axis change only on the byte that
//!   completes a frame that passed validation (good BCC, parses, answers the request in flight:
//!   same axis, same command character), only for the axis in flight, and to the frame's values
//!   (a position only from an R4 of PNOW); a valid answer in time is always accepted;
//! * the accepted frame is traced back to the wire: it must be byte for byte a reply that
//!   controller A, the axis updated, sent intact and that ended at that very microsecond:
//!   the answer to this command (*fresh*), or an intact late answer of A to an earlier command
//!   with the same command character (*stale*: A never got the new command, so its late reply
//!   was not superseded; the protocol has no sequence numbers, so this is legitimate, counted
//!   and printed by command). The only other possibility is a frame altered on the wire into
//!   another valid frame (the BCC is an 8-bit sum: compensating errors pass it); no receiver
//!   can tell, so those are counted and printed. A frame from another controller, or one that
//!   failed validation, is a violation; so is a frame complete before the command could have
//!   been answered (command, RTIM, answer: `earliest`), which is always an earlier answer.
//!
//! **(2)** Every JobId comes back exactly once, on its axis, jobs of an axis finish in the
//! order they were submitted (a stop's cancellation finishes them all at once), none is left
//! after the drain. **(3)** Every frame the engine sends is attributed: `n` and R4 PNOW are
//! polls, `d` belongs to an outstanding stop, anything else must be a frame of the axis' active
//! job (its oldest unfinished one); every `m` transmission is counted for that job and, by its
//! exact request (distances are unique per axis among outstanding jobs), for every job it could
//! belong to. An `m` job must see exactly one `m` when its outcome says it went out (done,
//! OutcomeUnknown, a rejection, an alarm or wait time-out after it) and at most one otherwise.
//! An axis may only go offline after 1 + Nrt failed attempts in a row.
//!
//! **(4)** Counters. Each transaction ends exactly once: answered, timed out, or (engine rule)
//! ended at once by a corrupted answer. So per axis, exactly, frames_sent = replies + timeouts
//! plus the corrupted-answer ends (plus 1 if in flight at the end), and replies and timeouts
//! equal the test's own counts. Each resend follows a failed attempt of its axis: retries is at
//! most timeouts plus corrupted-answer ends, and equals the resends the test saw. Σ frames_sent
//! is the sim's host transmissions. Every injected drop, delay and host-frame corruption
//! happens inside one transaction's window (between its command and its end), so the
//! per-transaction counts add up to the sim's totals exactly. Each failed transaction is
//! explained by a fault, checked one by one: the command never reached the controller valid
//! (corrupted, or collided with a late reply) or was corrupted into another valid command, the
//! reply was dropped, late, corrupted or collided. Conversely a transaction with a fault fails
//! unless a stale or altered frame answered it. Hence failures = faulted transactions less
//! those answered anyway, and in particular Σ failures is at least the dropped replies of
//! in-flight commands less those answered anyway. Every rejected candidate is traced to an
//! altered reply, noise or collision debris, or an intact frame answering something else (a
//! late reply), never to an intact answer; every altered reply whose STX arrived is noticed (a
//! candidate ends within it); Σ (bcc_errors + bad_replies) and unsolicited equal the
//! candidates the mirror saw.
//!
//! Violations are collected and asserted after the counts are printed.

use std::collections::{BTreeMap, VecDeque};

use protocol::engine::{
    timing, Config, Counters, Engine, Event, Job, JobError, JobKind, JobOutput, Link, Output,
    SubmitError,
};
use protocol::jobs::{self, PointData};
use protocol::line::Baud;
use protocol::memory::{PointField, PNOW};
use protocol::nb;
use protocol::time::{Duration, Instant};
use protocol::AxisSet;
use protocol::{
    Acceleration, Axis, Command, Deframer, Error, Frame, HomeDirection, Packet, PositionNo, Pulses,
    Reply, Request, Rtim, StatusReport, Velocity,
};
use rc_host::harness::Harness;
use rc_host::sim::rng::Rng;
use rc_host::sim::wire::{byte_offset, transmit_time};
use rc_host::sim::{Bus, BusConfig, ControllerConfig, Faults};

const MS: u64 = 1_000;
const S: u64 = 1_000_000;
const FRAME_LEN: usize = 16;
const STX: u8 = 0x02;
const BAUD: Baud = Baud::B115200;

/// Frames the engine sends before the workload stops and the run drains.
const TRANSACTIONS: u64 = 1_000_000;
const SEED: u64 = 0x50A4_0003;
const RETRIES: u8 = 2;

/// `SOAK_SEED` and `SOAK_TRANSACTIONS` override the seed and the length, to soak longer or
/// differently by hand.
fn seed() -> u64 {
    std::env::var("SOAK_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(SEED)
}

fn axis(n: usize) -> Axis {
    Axis::new(u8::try_from(n).unwrap()).unwrap()
}

// ------------------------------------------------------------------------------ the wire

/// A reply a controller prepared (not yet on the line).
#[derive(Clone, Copy)]
struct Pending {
    at: u64,
    bytes: [u8; FRAME_LEN],
    /// The transaction in flight when it was scheduled: the command it answers.
    txn: Option<u64>,
}

/// A reply a controller put on the line, and how it arrived.
struct SentReply {
    axis: Axis,
    start: u64,
    end: u64,
    /// As sent, before the bus corrupted anything.
    bytes: [u8; FRAME_LEN],
    txn: Option<u64>,
    /// Bytes the host received in this reply's slots.
    got: [u8; FRAME_LEN],
    got_mask: u32,
    /// Two bytes arrived in one slot (another talker at the same microsecond).
    clash: bool,
    /// A candidate frame (good or bad) ended while this reply was on the line.
    noticed: bool,
    /// The engine reset its deframer while this reply was on the line.
    reset_during: bool,
    finished: bool,
    altered: bool,
}

impl SentReply {
    fn intact_so_far(&self, k: usize) -> bool {
        !self.clash && self.got.get(k) == self.bytes.get(k) && self.got_mask & (1 << k) != 0
    }
}

/// A byte the host received, and which reply slot it filled.
#[derive(Clone, Copy, Default)]
struct Rx {
    byte: u8,
    /// (reply id, byte index)
    tag: Option<(u64, usize)>,
}

// ------------------------------------------------------------------------------ transactions

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Acceptance {
    /// The answer to this very command, intact.
    Fresh,
    /// An intact late answer of the same controller to an earlier command.
    Stale,
    /// A frame altered on the wire that still has a valid BCC (undetectable).
    Altered,
}

/// How a transaction ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum End {
    Accepted(Acceptance),
    /// No valid answer within Trt.
    Timeout,
    /// Ended before Trt by a corrupted answer (or, a violation, by nothing).
    Corrupted,
}

struct Txn {
    seq: u64,
    axis: Axis,
    request: Request,
    start: u64,
    deadline: u64,
    earliest: u64,
    host_corrupted: bool,
    sched0: u64,
    drop0: u64,
    delay0: u64,
    coll0: u64,
    /// A bad-BCC candidate ended at or after `earliest` while in flight: the engine may end the
    /// attempt there ("a corrupted response ends the attempt at once").
    bcc_end_at: Option<u64>,
    /// The engine no longer has it in flight (it counted the next candidate as unsolicited).
    engine_ended: bool,
}

/// What the test knows the engine knew about an axis.
#[derive(Clone, Copy, PartialEq, Eq)]
struct Snap {
    counters: Counters,
    report: Option<StatusReport>,
    report_at: Option<Instant>,
    position: Option<Pulses>,
    position_at: Option<Instant>,
    link: Link,
}

fn snap(engine: &Engine, a: Axis) -> Snap {
    let s = engine.axis(a);
    Snap {
        counters: s.counters,
        report: s.report,
        report_at: s.report_at,
        position: s.position,
        position_at: s.position_at,
        link: s.link,
    }
}

// ------------------------------------------------------------------------------ jobs

struct JobRec {
    axis: Axis,
    kind: JobKind,
    submitted: u64,
    done: Option<Result<JobOutput, JobError>>,
    /// Transmissions of this job's `m`, attributed to it as the axis' active job.
    m_sends: u32,
    /// Transmissions of this exact `m` request on the axis between submit and JobDone.
    m_literal: u32,
    /// For a stop: `d` transmissions on its axis while it was outstanding.
    d_sends: u32,
}

/// The requests a job's program may send.
fn job_requests(job: &Job) -> Vec<Request> {
    let a = job.axis;
    let one = |c: Command| vec![Request::new(a, c)];
    let steps = |s: &[jobs::Step]| s.iter().map(|s| s.request).collect::<Vec<_>>();
    match job.kind {
        JobKind::Command(c) => one(c),
        JobKind::Servo(on) => one(Command::Servo(on)),
        JobKind::Home(d) => one(Command::Home(d)),
        JobKind::MoveToPoint(p) => one(Command::MoveToPoint(p)),
        JobKind::MoveAbsolute(x) | JobKind::Jog(x) => one(Command::MoveAbsolute(x)),
        JobKind::MoveRelative(d) => one(Command::MoveRelative(d)),
        JobKind::DirectMove {
            target,
            relative,
            velocity,
            acceleration,
        } => vec![
            Request::new(
                a,
                Command::SetVelocityAcceleration {
                    velocity,
                    acceleration,
                },
            ),
            Request::new(
                a,
                if relative {
                    Command::MoveRelative(target)
                } else {
                    Command::MoveAbsolute(target)
                },
            ),
        ],
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
fn relative_distance(kind: &JobKind) -> Option<Pulses> {
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

fn kind_name(kind: &JobKind) -> &'static str {
    match kind {
        JobKind::Command(_) => "Command",
        JobKind::Servo(_) => "Servo",
        JobKind::Home(_) => "Home",
        JobKind::MoveToPoint(_) => "MoveToPoint",
        JobKind::MoveAbsolute(_) => "MoveAbsolute",
        JobKind::MoveRelative(_) => "MoveRelative",
        JobKind::DirectMove { relative: true, .. } => "DirectMove (m)",
        JobKind::DirectMove { .. } => "DirectMove (a)",
        JobKind::Jog(_) => "Jog",
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

fn result_name(result: &Result<JobOutput, JobError>) -> String {
    match result {
        Ok(_) => "ok".into(),
        Err(JobError::Rejected(code)) => format!("Rejected({:02X})", code.0),
        Err(JobError::Alarm(code)) => format!("Alarm({:02X})", code.0),
        Err(e) => format!("{e:?}"),
    }
}

/// The PLC's view of one axis.
#[derive(Default)]
struct Plc {
    homed: bool,
    next_at: u64,
    /// Points it believes hold data (a WritePoint or WriteField succeeded).
    written: u16,
    /// An alarm reset (and the servo-on after it) is outstanding.
    resetting: bool,
}

// ------------------------------------------------------------------------------ the soak

#[derive(Default)]
struct Tally {
    accepted: [u64; 3],
    accepted_early: u64,
    stale_by_command: BTreeMap<&'static str, u64>,
    timeouts: u64,
    early_ends: u64,
    causes: BTreeMap<&'static str, u64>,
    /// Transactions that met a fault but were answered anyway (stale or altered frame).
    faulted_but_accepted: u64,
    faulted_txns: u64,
    drops_in_flight: u64,
    delays_in_flight: u64,
    host_corrupted_txns: u64,
    /// Corrupted commands that still reached the addressed controller as a valid frame.
    corrupted_commands_taken: u64,
    cmd_received: u64,
    candidates: BTreeMap<&'static str, u64>,
    replies_on_wire: u64,
    replies_altered: u64,
    altered_valid_on_wire: u64,
    offline_events: u64,
    retries_seen: u64,
    queue_full: u64,
    deframer_resets: u64,
}

struct Soak {
    h: Harness,
    rng: Rng,
    // wire
    pending: [Option<Pending>; 16],
    sched_seen: [u64; 16],
    scan_marks: (u64, u64, u64),
    sent_seen: [u64; 16],
    replies: VecDeque<SentReply>,
    /// Index of the first reply not yet complete (replies complete in order).
    open_from: usize,
    next_reply_id: u64,
    /// Arrival of byte k after the start of a transmission.
    offsets: [u64; FRAME_LEN],
    ring: [Rx; FRAME_LEN],
    ring_pos: usize,
    mirror: Deframer,
    // engine
    snaps: [Snap; 16],
    unsolicited: u32,
    cur: Option<Txn>,
    next_seq: u64,
    frames: u64,
    per_axis: [[u64; 3]; 16], // accepted, timeouts, early ends
    history: [VecDeque<(Request, bool)>; 16],
    offline_checks: Vec<Axis>,
    // jobs
    jobs: Vec<JobRec>,
    fifo: [VecDeque<u32>; 16],
    stops: [Vec<u32>; 16],
    /// The last jobs a stop cancelled, per axis.
    cancelled: [VecDeque<u32>; 16],
    plc: [Plc; 16],
    stop_at: Vec<(u64, Axis)>,
    submitting: bool,
    plc_check_at: u64,
    // results
    tally: Tally,
    violations: BTreeMap<&'static str, u64>,
    details: Vec<String>,
}

impl Soak {
    fn new() -> Soak {
        let seed = seed();
        let mut rng = Rng::new(seed);
        let faults = Faults {
            host_byte_corruption: 0.01,
            reply_byte_corruption: 0.01,
            reply_drop: 0.005,
            reply_delay: 0.005,
            reply_delay_us: 30 * MS,
            noise: 0.002,
            noise_max_bytes: 3,
        };
        let mut bus = Bus::new(BusConfig {
            seed,
            faults,
            host_echo: false,
            host_baud: BAUD,
        });
        for n in 0..16 {
            let start = 1_000 + u32::try_from(rng.below(8_000)).unwrap();
            bus.add_controller(
                axis(n),
                ControllerConfig {
                    stored_line: Some((BAUD, Rtim::MIN)),
                    start_from_motor_end: start,
                    ..ControllerConfig::default()
                },
            );
        }
        let engine = Engine::new(Config {
            axes: AxisSet::ALL,
            baud: BAUD,
            rtim: Rtim::MIN,
            retries: RETRIES,
            establish: false,
            motion_timeout: Duration::from_millis(20_000),
            ..Config::default()
        });
        let h = Harness::new(engine, bus);
        let snaps = std::array::from_fn(|n| snap(&h.engine, axis(n)));
        Soak {
            h,
            rng,
            pending: [None; 16],
            sched_seen: [0; 16],
            scan_marks: (0, 0, 0),
            sent_seen: [0; 16],
            replies: VecDeque::new(),
            open_from: 0,
            next_reply_id: 0,
            offsets: std::array::from_fn(|k| byte_offset(k + 1, BAUD)),
            ring: [Rx::default(); FRAME_LEN],
            ring_pos: 0,
            mirror: Deframer::new(),
            snaps,
            unsolicited: 0,
            cur: None,
            next_seq: 0,
            frames: 0,
            per_axis: [[0; 3]; 16],
            history: std::array::from_fn(|_| VecDeque::new()),
            offline_checks: Vec::new(),
            jobs: Vec::new(),
            fifo: std::array::from_fn(|_| VecDeque::new()),
            stops: std::array::from_fn(|_| Vec::new()),
            cancelled: std::array::from_fn(|_| VecDeque::new()),
            plc: std::array::from_fn(|_| Plc::default()),
            stop_at: Vec::new(),
            submitting: true,
            plc_check_at: 0,
            tally: Tally::default(),
            violations: BTreeMap::new(),
            details: Vec::new(),
        }
    }

    fn violation(&mut self, kind: &'static str, detail: String) {
        let count = self.violations.entry(kind).or_default();
        *count += 1;
        if *count <= 3 {
            self.details
                .push(format!("t={} µs {kind}: {detail}", self.h.now));
        }
    }

    fn now(&self) -> u64 {
        self.h.now
    }

    // -------------------------------------------------------------------- the loop

    fn step(&mut self, limit: u64) {
        let output = self.h.engine.poll(Instant(self.now()));
        self.after_poll(&output);
        match output {
            Output::Transmit(frame) => self.transmit(&frame),
            Output::Line(action) => {
                self.violation("line action", format!("{action:?} (none expected)"));
            }
            Output::Idle(until) => {
                let wake = [until.map(|t| t.0), self.h.bus.next_event(), Some(limit)]
                    .into_iter()
                    .flatten()
                    .min()
                    .unwrap_or(limit)
                    .max(self.now());
                let bytes = self.h.bus.advance(wake);
                // Controllers prepare replies when a frame's last byte reaches them (normally the
                // host's, but a corrupted reply can pass for a command) and send them when the
                // bus says so. Look closer only when something may have happened.
                if !bytes.is_empty() || wake == self.h.bus.host_busy_until() {
                    let stats = self.h.bus.stats();
                    let sent = stats.replies_sent;
                    let (dropped, delayed) = (stats.replies_dropped, stats.replies_delayed);
                    let scheduled: u64 = self
                        .h
                        .bus
                        .controllers()
                        .map(|c| c.stats().replies_scheduled)
                        .sum();
                    let marks = (sent + scheduled, dropped, delayed);
                    if marks != self.scan_marks {
                        self.scan_marks = marks;
                        self.scan_controllers(wake);
                    }
                }
                for (at, byte) in bytes {
                    self.on_byte(at, byte);
                }
                self.h.now = wake;
                self.drain_events();
            }
        }
    }

    /// After `poll`: time-outs, the end of an attempt without a time-out, deframer resets, the
    /// frame it is about to send.
    fn after_poll(&mut self, output: &Output) {
        let now = self.now();
        self.finish_replies(now, true);
        // A deframer reset shows as the partial candidate counted as noise.
        let (engine_c, mirror_c) = (self.h.engine.deframer().counters(), self.mirror.counters());
        if engine_c != mirror_c {
            let dropped = u32::try_from(self.mirror.pending().len()).unwrap();
            let reset = self.h.engine.deframer().pending().is_empty()
                && engine_c.noise_bytes == mirror_c.noise_bytes.wrapping_add(dropped)
                && (engine_c.packets, engine_c.errors) == (mirror_c.packets, mirror_c.errors);
            if reset {
                self.mirror.reset();
                self.tally.deframer_resets += 1;
                for r in self
                    .replies
                    .iter_mut()
                    .filter(|r| r.start < now && now < r.end)
                {
                    r.reset_during = true;
                }
            } else {
                self.violation(
                    "deframer diverged",
                    format!("engine {engine_c:?} mirror {mirror_c:?}"),
                );
                self.mirror = self.h.engine.deframer().clone();
            }
        }
        let open = self
            .cur
            .as_ref()
            .map(|c| (c.axis, c.deadline, c.bcc_end_at, c.request));
        if let Some((a, deadline, bcc_end_at, request)) = open {
            let i = usize::from(a.get());
            let timeouts = self.h.engine.axis(a).counters.timeouts;
            if timeouts == self.snaps[i].counters.timeouts.wrapping_add(1) {
                if now < deadline {
                    self.violation(
                        "early time-out",
                        format!("{request:?} at {now}, Trt ends {deadline}"),
                    );
                }
                self.snaps[i].counters.timeouts = timeouts;
                self.resolve(End::Timeout);
            } else if *output != Output::Idle(Some(Instant(deadline))) {
                // The engine is not waiting for this answer any more.
                if bcc_end_at.is_none() {
                    self.violation(
                        "attempt ended without reply, time-out or corrupted answer",
                        format!("{request:?} output {output:?}"),
                    );
                }
                self.resolve(End::Corrupted);
            }
        }
        if let Output::Transmit(frame) = output {
            if let Ok(request) = Request::parse(frame) {
                let i = usize::from(request.axis.get());
                let before = self.snaps[i].counters;
                let after = self.h.engine.axis(request.axis).counters;
                if after.frames_sent != before.frames_sent.wrapping_add(1) {
                    self.violation("frames_sent not counted", format!("{request:?}"));
                }
                if after.retries == before.retries.wrapping_add(1) {
                    self.tally.retries_seen += 1;
                }
                self.snaps[i].counters.frames_sent = after.frames_sent;
                self.snaps[i].counters.retries = after.retries;
            }
        }
        // Between polls only candidates change what the engine knows (checked there); a poll may
        // count a time-out or a transmission. Check every axis then.
        if matches!(output, Output::Transmit(_)) || open.is_some() && self.cur.is_none() {
            self.check_all_axes("poll");
        }
        let checks = std::mem::take(&mut self.offline_checks);
        for a in checks {
            self.check_offline(a);
        }
        self.drain_events();
    }

    /// Replies whose last byte has arrived (at `t`, or before it) are complete: did they arrive
    /// as sent, and if not, did the engine notice?
    fn finish_replies(&mut self, t: u64, inclusive: bool) {
        while let Some(r) = self.replies.get_mut(self.open_from) {
            if !(r.end < t || (inclusive && r.end == t)) {
                break;
            }
            self.open_from += 1;
            r.finished = true;
            r.altered = r.clash || r.got_mask != 0xFFFF || r.got != r.bytes;
            if !r.altered {
                continue;
            }
            self.tally.replies_altered += 1;
            let stx_intact = r.got_mask & 1 != 0 && r.got[0] == STX;
            if stx_intact && !r.reset_during && !r.noticed {
                let detail = format!(
                    "from {:?} at {}: sent {:02X?} got {:02X?}",
                    r.axis, r.start, r.bytes, r.got
                );
                self.violation("altered reply went unnoticed", detail);
            }
        }
    }

    /// Nothing the engine knows may change outside an acceptance (and the counters the caller
    /// has accounted for already).
    fn check_all_axes(&mut self, at: &'static str) {
        for n in 0..16 {
            let now_snap = snap(&self.h.engine, axis(n));
            if now_snap != self.snaps[n] {
                let mut expected = self.snaps[n];
                // Links change on time-outs and replies; frames_sent/retries on transmission.
                expected.link = now_snap.link;
                if now_snap != expected {
                    let (b, c) = (self.snaps[n].counters, now_snap.counters);
                    self.violation(
                        "axis state changed without an accepted frame",
                        format!("{at}: axis {n}: counters {b:?} -> {c:?}"),
                    );
                }
                self.snaps[n] = now_snap;
            }
        }
        let unsolicited = self.h.engine.bus_counters().unsolicited;
        if unsolicited != self.unsolicited {
            self.violation("unsolicited counted outside a candidate", at.into());
            self.unsolicited = unsolicited;
        }
    }

    fn transmit(&mut self, frame: &Frame) {
        let now = self.now();
        let Ok(request) = Request::parse(frame) else {
            self.violation("unparsable transmission", format!("{frame:?}"));
            return;
        };
        if self.cur.is_some() {
            self.violation(
                "transmitted while a transaction is open",
                format!("{request:?}"),
            );
            self.resolve(End::Corrupted);
        }
        let a = request.axis;
        self.attribute(now, request);

        let stats0 = self.h.bus.stats().clone();
        let sched0 = self
            .h
            .bus
            .controller(a)
            .map_or(0, |c| c.stats().replies_scheduled);
        self.h.bus.host_send(now, &frame.to_bytes());
        let stats1 = self.h.bus.stats();
        let host_corrupted = stats1.host_frames_corrupted > stats0.host_frames_corrupted;
        self.tally.host_corrupted_txns += u64::from(host_corrupted);
        let rtim = self.h.engine.axis(a).rtim;
        let is_v5 = matches!(request.command, Command::StoreFromEdit(_));
        let frame_time = timing::frame_time(BAUD).as_micros();
        let deadline = now + frame_time + timing::response_timeout(BAUD, rtim, is_v5).as_micros();
        let earliest = now + 2 * frame_time + u64::from(rtim.get()) * MS;
        self.cur = Some(Txn {
            seq: self.next_seq,
            axis: a,
            request,
            start: now,
            deadline,
            earliest,
            host_corrupted,
            sched0,
            drop0: stats0.replies_dropped,
            delay0: stats0.replies_delayed,
            coll0: stats0.collisions,
            bcc_end_at: None,
            engine_ended: false,
        });
        self.next_seq += 1;
        self.frames += 1;
        self.scan_controllers(now);
    }

    // -------------------------------------------------------------------- the wire

    /// Read every controller's prepared reply: record those that went on the line, and tag new
    /// ones with the transaction in flight.
    fn scan_controllers(&mut self, now: u64) {
        let txn = self.cur.as_ref().map(|c| c.seq);
        for n in 0..16 {
            let Some(c) = self.h.bus.controller(axis(n)) else {
                continue;
            };
            let (sched, sent) = (c.stats().replies_scheduled, c.stats().replies_sent);
            let pending = c.pending_reply().copied();
            if sent != self.sent_seen[n] {
                match self.pending[n].take() {
                    Some(p) if sent == self.sent_seen[n] + 1 && p.at <= now => {
                        self.next_reply_id += 1;
                        self.replies.push_back(SentReply {
                            axis: axis(n),
                            start: p.at,
                            end: p.at + transmit_time(FRAME_LEN, BAUD),
                            bytes: p.bytes,
                            txn: p.txn,
                            got: [0; FRAME_LEN],
                            got_mask: 0,
                            clash: false,
                            noticed: false,
                            reset_during: false,
                            finished: false,
                            altered: false,
                        });
                        self.tally.replies_on_wire += 1;
                    }
                    other => {
                        let detail = format!(
                            "axis {n}: mirror {:?}, pending now {:?}, sent {sent} seen {}, sched {sched} seen {}, host busy until {}",
                            other.map(|p| (p.at, p.txn)),
                            pending.map(|p| p.at),
                            self.sent_seen[n],
                            self.sched_seen[n],
                            self.h.bus.host_busy_until()
                        );
                        self.violation("reply sent that was not pending", detail)
                    }
                }
                self.sent_seen[n] = sent;
            }
            if sched != self.sched_seen[n] {
                self.sched_seen[n] = sched;
                self.pending[n] = pending.map(|p| Pending {
                    at: p.at,
                    bytes: p.bytes,
                    txn,
                });
            } else if pending.map(|p| (p.at, p.bytes)) != self.pending[n].map(|p| (p.at, p.bytes)) {
                // Cancelled (a break or power loss; neither happens here) or sent (handled).
                self.pending[n] = pending.map(|p| Pending {
                    at: p.at,
                    bytes: p.bytes,
                    txn: None,
                });
            }
        }
        // Forget replies long gone (kept for a second for byte attribution).
        while self
            .replies
            .front()
            .is_some_and(|r| r.finished && r.end + S < now)
        {
            self.replies.pop_front();
            self.open_from -= 1;
        }
    }

    fn reply_index(&self, id: u64) -> Option<usize> {
        let front = self.next_reply_id - self.replies.len() as u64;
        id.checked_sub(front).map(|i| i as usize)
    }

    fn on_byte(&mut self, at: u64, byte: u8) {
        self.finish_replies(at, false);
        // Which reply slot does it fill? (Only replies still on the line can.)
        let mut tag = None;
        let front = self.next_reply_id - self.replies.len() as u64;
        for i in self.open_from..self.replies.len() {
            let r = &mut self.replies[i];
            if at <= r.start || at > r.end {
                continue;
            }
            let offset = at - r.start;
            if let Some(k) = self.offsets.iter().position(|&o| o == offset) {
                if r.got_mask & (1 << k) != 0 {
                    r.clash = true;
                }
                r.got_mask |= 1 << k;
                r.got[k] = byte;
                tag = Some((front + i as u64, k));
                break;
            }
        }
        self.ring[self.ring_pos] = Rx { byte, tag };
        self.ring_pos = (self.ring_pos + 1) % FRAME_LEN;

        let outcome = self.mirror.push(byte);
        self.h.engine.receive(Instant(at), &[byte]);
        if self.h.engine.deframer().counters() != self.mirror.counters() {
            let (e, m) = (self.h.engine.deframer().counters(), self.mirror.counters());
            self.violation("deframer diverged", format!("engine {e:?} mirror {m:?}"));
            self.mirror = self.h.engine.deframer().clone();
        }
        match outcome {
            Err(nb::Error::WouldBlock) | Ok(Packet::CommChange) => {
                if let Some(a) = self.cur.as_ref().map(|c| c.axis) {
                    let i = usize::from(a.get());
                    if self.h.engine.axis(a).counters != self.snaps[i].counters {
                        self.violation("counters changed without a candidate", format!("{a:?}"));
                        self.snaps[i].counters = self.h.engine.axis(a).counters;
                    }
                }
            }
            Ok(Packet::Frame(frame)) => self.on_candidate(at, Ok(frame)),
            Err(nb::Error::Other(error)) => self.on_candidate(at, Err(error)),
        }
    }

    /// The last `len` bytes received (oldest first).
    fn window(&self, len: usize) -> Vec<Rx> {
        (0..len)
            .map(|j| self.ring[(self.ring_pos + FRAME_LEN - len + j) % FRAME_LEN])
            .collect()
    }

    /// The reply a window of bytes is, intact, if it is one.
    fn intact_source(&self, window: &[Rx]) -> Option<usize> {
        let (id, _) = window.first()?.tag?;
        let index = self.reply_index(id)?;
        let r = self.replies.get(index)?;
        let whole = window.len() == FRAME_LEN
            && window
                .iter()
                .enumerate()
                .all(|(k, rx)| rx.tag == Some((id, k)) && r.bytes[k] == rx.byte);
        whole.then_some(index)
    }

    fn describe(&self, window: &[Rx], outcome: &Result<Frame, Error>) -> String {
        let parts: Vec<String> = window
            .iter()
            .map(|rx| match rx.tag {
                Some((id, k)) => {
                    let r = self.reply_index(id).and_then(|i| self.replies.get(i));
                    format!(
                        "{:02X}@{id}.{k}{}",
                        rx.byte,
                        if r.is_some_and(|r| r.intact_so_far(k)) {
                            ""
                        } else {
                            "!"
                        }
                    )
                }
                None => format!("{:02X}@-", rx.byte),
            })
            .collect();
        format!("{outcome:?} [{}]", parts.join(" "))
    }

    /// What a candidate that is not a valid answer is made of.
    fn trace(&self, window: &[Rx]) -> &'static str {
        let mut any_reply = false;
        for rx in window {
            if let Some((id, k)) = rx.tag {
                any_reply = true;
                let altered = self
                    .reply_index(id)
                    .and_then(|i| self.replies.get(i))
                    .is_none_or(|r| !r.intact_so_far(k));
                if altered {
                    return "altered reply";
                }
            }
        }
        if any_reply {
            if self.intact_source(window).is_some() {
                "intact frame answering something else"
            } else {
                "pieces of intact replies"
            }
        } else {
            "noise or collision debris"
        }
    }

    fn on_candidate(&mut self, at: u64, outcome: Result<Frame, Error>) {
        for r in self.replies.iter_mut().skip(self.open_from) {
            if r.start < at && at <= r.end {
                r.noticed = true;
            }
        }
        let (len, what) = match &outcome {
            Ok(_) => (FRAME_LEN, "valid frame"),
            Err(Error::Truncated { len }) => (usize::from(*len) + 1, "truncated"),
            Err(Error::BadBcc { .. }) => (FRAME_LEN, "bad BCC"),
            Err(_) => (FRAME_LEN, "malformed"),
        };
        let window = self.window(len.min(FRAME_LEN));
        // (A truncated candidate is traced with the STX that cut it.)
        let traced = &window[..];
        let reply = outcome.as_ref().ok().map(Reply::parse);

        // The engine's view: in flight (per the model) and the counters.
        let in_flight = self.cur.as_ref().is_some_and(|c| !c.engine_ended);
        let unsolicited = self.h.engine.bus_counters().unsolicited;
        let d_unsol = unsolicited.wrapping_sub(self.unsolicited);
        self.unsolicited = unsolicited;
        if !in_flight {
            if d_unsol != 1 {
                self.violation(
                    "candidate without transaction not counted unsolicited",
                    what.into(),
                );
            }
            *self
                .tally
                .candidates
                .entry(if outcome.is_ok() {
                    "unsolicited: valid frame"
                } else {
                    "unsolicited: broken candidate"
                })
                .or_default() += 1;
            if outcome.is_err() && self.trace(traced) == "pieces of intact replies" {
                let d = self.describe(traced, &outcome);
                self.violation(
                    "broken candidate without a fault",
                    format!("unsolicited: {d}"),
                );
            }
            self.check_all_axes("unsolicited candidate");
            return;
        }
        let (a, request, seq, earliest, deadline) = {
            let c = self.cur.as_ref().unwrap();
            (c.axis, c.request, c.seq, c.earliest, c.deadline)
        };
        let i = usize::from(a.get());
        let before = self.snaps[i].counters;
        let after = self.h.engine.axis(a).counters;
        if d_unsol == 1 {
            // The engine had already ended the attempt: legitimate only after a corrupted answer.
            if self.cur.as_ref().unwrap().bcc_end_at.is_none() {
                self.violation(
                    "attempt ended without reply, time-out or corrupted answer",
                    format!("{request:?}: a later {what} counted unsolicited"),
                );
            }
            self.cur.as_mut().unwrap().engine_ended = true;
            self.check_all_axes("candidate after end");
            return;
        }
        let answers = matches!(&reply, Some(Ok(r)) if r.answers(&request).is_ok());
        // A frame complete before `earliest` (command, RTIM, answer on the wire) cannot be the
        // answer, valid as it may be: it is a late answer to an earlier command. The engine may
        // reject it (as bad_replies); accepting it is a violation.
        let impossible = at < earliest;
        if answers && !(impossible && after.replies == before.replies) {
            if impossible {
                self.violation(
                    "accepted an answer complete before the command could be answered",
                    format!("{request:?}: ended at {at}, earliest possible {earliest}"),
                );
            }
            if after.replies != before.replies.wrapping_add(1) {
                self.violation(
                    "valid answer in time not accepted",
                    format!("{request:?} at {at}"),
                );
                self.check_all_axes("answer not accepted");
                return;
            }
            if at > deadline {
                self.violation("accepted after Trt", format!("{request:?} at {at}"));
            }
            let Some(Ok(reply)) = reply else {
                unreachable!()
            };
            self.accept(at, &reply, &window, seq, earliest);
            return;
        }
        if after.replies != before.replies {
            // The engine took a frame that is not a valid answer to the request in flight.
            let why = match &reply {
                Some(Ok(r)) if r.axis() != request.axis => "from another axis",
                Some(Ok(_)) => "echoing another command",
                Some(Err(_)) => "that does not parse",
                None => "that failed validation",
            };
            self.violation(
                "accepted a frame that does not answer the request",
                format!("{what} {why} while {request:?} in flight"),
            );
            if let Some(Ok(reply)) = reply {
                self.accept(at, &reply, &window, seq, earliest);
            } else {
                self.snaps[i] = snap(&self.h.engine, a);
                self.resolve(End::Accepted(Acceptance::Altered));
            }
            return;
        }
        let bcc = matches!(outcome, Err(Error::BadBcc { .. }));
        let (counted, name) = if bcc {
            (
                after.bcc_errors == before.bcc_errors.wrapping_add(1),
                "bcc_errors",
            )
        } else {
            (
                after.bad_replies == before.bad_replies.wrapping_add(1),
                "bad_replies",
            )
        };
        if !counted {
            self.violation(
                "candidate not counted as the rules say",
                format!("{what} while {request:?} in flight: expected {name} + 1"),
            );
        }
        let cause = self.trace(traced);
        if outcome.is_err() && cause == "pieces of intact replies" {
            let d = self.describe(traced, &outcome);
            self.violation(
                "broken candidate without a fault",
                format!("{request:?}: {d}"),
            );
        }
        let key = match (bcc, outcome.is_ok(), cause) {
            (true, _, "altered reply") => "bcc_errors: altered reply",
            (true, _, _) => "bcc_errors: noise or collision debris",
            (false, true, "intact frame answering something else") => {
                "bad_replies: intact late/foreign reply"
            }
            (false, true, _) => "bad_replies: altered frame with a valid BCC",
            (false, false, "altered reply") => "bad_replies: altered reply",
            (false, false, _) => "bad_replies: noise or collision debris",
        };
        *self.tally.candidates.entry(key).or_default() += 1;
        if outcome.is_ok() && self.intact_source(&window).is_none() {
            self.tally.altered_valid_on_wire += 1;
        }
        self.snaps[i].counters.bcc_errors = after.bcc_errors;
        self.snaps[i].counters.bad_replies = after.bad_replies;
        if bcc && at >= earliest {
            if let Some(c) = self.cur.as_mut() {
                c.bcc_end_at.get_or_insert(at);
            }
        }
        self.check_all_axes("rejected candidate");
    }

    /// The engine accepted `reply` (completed at `at`) for the transaction in flight.
    fn accept(&mut self, at: u64, reply: &Reply, window: &[Rx], seq: u64, earliest: u64) {
        let cur = self.cur.as_ref().unwrap();
        let (a, request) = (cur.axis, cur.request);
        let i = usize::from(a.get());
        let kind = match self.intact_source(window) {
            Some(index) => {
                let (from, txn) = (self.replies[index].axis, self.replies[index].txn);
                if from != a {
                    self.violation(
                        "frame accepted for the wrong axis",
                        format!("{request:?} answered by {from:?}'s intact reply"),
                    );
                }
                if txn == Some(seq) {
                    Acceptance::Fresh
                } else {
                    Acceptance::Stale
                }
            }
            None => {
                self.tally.altered_valid_on_wire += 1;
                if self.details.len() < 40 {
                    self.details.push(format!(
                        "note t={at}: accepted an altered frame with a valid BCC for {request:?}: \
                         {:02X?}",
                        window.iter().map(|rx| rx.byte).collect::<Vec<_>>()
                    ));
                }
                Acceptance::Altered
            }
        };
        self.tally.accepted[kind as usize] += 1;
        if kind == Acceptance::Stale {
            *self
                .tally
                .stale_by_command
                .entry(request.command.mnemonic())
                .or_default() += 1;
            if at < earliest {
                self.tally.accepted_early += 1;
            }
        }
        // The engine's new knowledge must be the frame's, and only for this axis.
        let new = snap(&self.h.engine, a);
        let old = self.snaps[i];
        if new.report_at != old.report_at || new.report != old.report {
            if reply.report().copied() != new.report || new.report_at != Some(Instant(at)) {
                self.violation(
                    "status not from the accepted frame",
                    format!(
                        "{request:?}: {:?} vs frame {:?}",
                        new.report,
                        reply.report()
                    ),
                );
            }
        } else if reply.report().is_some() {
            self.violation("accepted status not recorded", format!("{request:?}"));
        }
        if new.position_at != old.position_at || new.position != old.position {
            let pnow = request.command == Command::ReadMemory { address: PNOW };
            if !pnow || reply.position() != new.position || new.position_at != Some(Instant(at)) {
                self.violation(
                    "position not from the accepted frame",
                    format!(
                        "{request:?}: {:?} vs frame {:?}",
                        new.position,
                        reply.position()
                    ),
                );
            }
        }
        let mut expected = old.counters;
        expected.replies = expected.replies.wrapping_add(1);
        if let Some(code) = reply.rejection() {
            let _ = code;
            expected.rejections = new.counters.rejections;
        }
        if new.counters != expected {
            self.violation(
                "counters beyond replies changed on acceptance",
                format!("{:?} -> {:?}", old.counters, new.counters),
            );
        }
        self.snaps[i] = new;
        self.check_all_axes("acceptance");
        self.resolve(End::Accepted(kind));
    }

    /// The transaction in flight is over: accepted (with how), or failed.
    fn resolve(&mut self, end: End) {
        let Some(cur) = self.cur.take() else {
            return;
        };
        let a = cur.axis;
        let i = usize::from(a.get());
        let stats = self.h.bus.stats();
        let dropped = stats.replies_dropped - cur.drop0;
        let delayed = stats.replies_delayed - cur.delay0;
        let collided = stats.collisions > cur.coll0;
        let got_cmd = self
            .h
            .bus
            .controller(a)
            .is_some_and(|c| c.stats().replies_scheduled > cur.sched0);
        self.tally.drops_in_flight += dropped;
        self.tally.delays_in_flight += delayed;
        self.tally.cmd_received += u64::from(got_cmd);
        self.tally.corrupted_commands_taken += u64::from(got_cmd && cur.host_corrupted);
        // How the fresh answer (this command's) arrived, if it was sent.
        let fresh = self
            .replies
            .iter()
            .rev()
            .take(8)
            .find(|r| r.txn == Some(cur.seq) && r.axis == a)
            .map(|r| (r.start, r.end, r.finished, r.altered));
        let fresh_altered = fresh.is_some_and(|(_, _, finished, altered)| finished && altered);
        // Why the controller's answer did not make it back intact and in time (a V5 answer
        // delayed by 21-45 ms still comes within its 200 ms Trt: no fault).
        let cause = if end == End::Accepted(Acceptance::Fresh) {
            None
        } else if end == End::Accepted(Acceptance::Altered) {
            Some("reply altered into another valid frame")
        } else if !got_cmd {
            Some(if cur.host_corrupted {
                "command corrupted"
            } else if collided {
                "command collided with a late reply"
            } else {
                "command lost without corruption or collision"
            })
        } else if cur.host_corrupted {
            // Corrupted into another valid frame for this axis: it answered something else.
            Some("command corrupted into another valid command")
        } else if dropped > 0 {
            Some("reply dropped")
        } else if delayed > 0 {
            Some("reply late")
        } else if fresh_altered {
            Some(if collided {
                "reply collided"
            } else {
                "reply corrupted"
            })
        } else if end == End::Corrupted && fresh.is_none_or(|(_, end, ..)| end > self.h.now) {
            // Its answer was still to come (a V5 answers after its store time): the corrupted
            // frame that ended the attempt was someone else's.
            Some("ended by another talker's corrupted frame before the answer")
        } else {
            None
        };
        if cause == Some("ended by another talker's corrupted frame before the answer") {
            let (r, t) = (cur.request, cur.bcc_end_at);
            self.violation(
                "attempt ended by another talker's corrupted frame while its answer was coming",
                format!("{r:?} sent at {}, bad frame at {t:?}", cur.start),
            );
        }
        if cause.is_some() {
            self.tally.faulted_txns += 1;
        }
        match end {
            End::Accepted(kind) => {
                self.per_axis[i][0] += 1;
                if cause.is_some() {
                    self.tally.faulted_but_accepted += 1;
                } else if kind != Acceptance::Fresh {
                    let r = cur.request;
                    self.violation(
                        "stale or altered answer without a fault",
                        format!("{r:?}: got_cmd {got_cmd} dropped {dropped} delayed {delayed}"),
                    );
                }
            }
            End::Timeout | End::Corrupted => {
                if end == End::Timeout {
                    self.per_axis[i][1] += 1;
                    self.tally.timeouts += 1;
                } else {
                    self.per_axis[i][2] += 1;
                    self.tally.early_ends += 1;
                }
                match cause {
                    Some("command lost without corruption or collision") | None => {
                        let r = cur.request;
                        let f = fresh;
                        let c = self.h.bus.controller(a).map(|c| c.stats().clone());
                        self.violation(
                            "unexplained failed transaction",
                            format!(
                                "{r:?} sent at {}, {end:?} at {}, earliest {}, bcc end {:?}, \
                                 fresh {f:?}, controller {c:?}",
                                cur.start, self.h.now, cur.earliest, cur.bcc_end_at
                            ),
                        );
                    }
                    Some(c) => *self.tally.causes.entry(c).or_default() += 1,
                }
            }
        }
        let history = &mut self.history[i];
        history.push_back((cur.request, !matches!(end, End::Accepted(_))));
        if history.len() > 16 {
            history.pop_front();
        }
    }

    /// An axis went offline: its last 1 + Nrt attempts must have failed (a poll and its resends,
    /// a resendable job frame and its resends, a stop and its resends), never after a single
    /// lost answer. Answered frames that may legitimately come between the attempts of one
    /// request do not break the run: a W4 is resent after its T4 (and counts its attempts across
    /// both), and a newer stop's `d` goes before an older stop's resend.
    fn check_offline(&mut self, a: Axis) {
        let history = &self.history[usize::from(a.get())];
        let mut run = 0;
        for (request, failed) in history.iter().rev() {
            if *failed {
                run += 1;
            } else if !matches!(
                request.command,
                Command::SetWriteAddress { .. } | Command::CancelMotion
            ) {
                break;
            }
        }
        if run < 1 + usize::from(RETRIES) {
            let last = history.back().map(|(r, _)| *r);
            let kind = match last.and_then(|r| self.cancelled_owner(&r)) {
                Some(_) => "offline after one lost answer to a cancelled job's frame",
                None => "offline after fewer than 1 + Nrt failed attempts",
            };
            let recent: Vec<String> = history
                .iter()
                .rev()
                .take(5)
                .map(|(r, f)| {
                    format!(
                        "{}{}",
                        r.command.mnemonic(),
                        if *f { " failed" } else { "" }
                    )
                })
                .collect();
            self.violation(
                kind,
                format!("{a:?}: {run} failed attempt(s) in a row, the last {last:?}; newest first: {recent:?}"),
            );
        }
    }

    // -------------------------------------------------------------------- jobs

    fn drain_events(&mut self) {
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
    fn cancelled_owner(&self, request: &Request) -> Option<u32> {
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

    /// Which job sent this frame; counts `m` transmissions.
    fn attribute(&mut self, now: u64, request: Request) {
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

    fn submit(&mut self, a: Axis, kind: JobKind) -> bool {
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

    /// The PLC: every millisecond, each idle axis may get new work.
    fn plc(&mut self) {
        let now = self.now();
        while let Some(k) = self.stop_at.iter().position(|&(t, _)| t <= now) {
            let (_, a) = self.stop_at.swap_remove(k);
            if self.submitting {
                self.submit(a, JobKind::Stop);
            }
        }
        if !self.submitting || now < self.plc_check_at {
            return;
        }
        self.plc_check_at = now + MS;
        for n in 0..16 {
            if self.fifo[n].len() > 1 || now < self.plc[n].next_at {
                continue;
            }
            self.plc_act(axis(n));
        }
    }

    fn plc_act(&mut self, a: Axis) {
        let n = usize::from(a.get());
        let now = self.now();
        let think = self.rng.below(100 * MS);
        self.plc[n].next_at = now + think;
        let report = self.h.engine.axis(a).report;
        if !self.plc[n].homed {
            if self.fifo[n].is_empty() {
                self.submit(a, JobKind::Home(HomeDirection::MotorEnd));
            }
            return;
        }
        if report.is_some_and(|r| r.outputs.alarm_active()) {
            if !self.plc[n].resetting && self.fifo[n].is_empty() {
                self.plc[n].resetting = true;
                self.submit(a, JobKind::AlarmReset);
                self.submit(a, JobKind::Servo(true));
            }
            return;
        }
        let roll = self.rng.below(100);
        let position = self.h.engine.axis(a).position.map_or(-5_000, |p| p.0);
        match roll {
            0..=34 => {
                // Relative moves, often two or three in a row.
                let count = 1 + self.rng.below(3);
                let mut target = i64::from(position);
                for _ in 0..count {
                    let magnitude = 100 + self.rng.below(3_000) as i64;
                    let up = target + magnitude <= -200;
                    let down = target - magnitude >= -9_800;
                    let mut d = match (up, down) {
                        (true, true) if self.rng.chance(0.5) => magnitude,
                        (true, _) => magnitude,
                        (false, true) => -magnitude,
                        (false, false) if target < -5_000 => 100,
                        (false, false) => -100,
                    };
                    // Distinct from every outstanding `m` of the axis, so that a transmission
                    // names its job.
                    let taken = |soak: &Soak, d: i64| {
                        let d = Some(Pulses(i32::try_from(d).unwrap()));
                        soak.fifo[n]
                            .iter()
                            .any(|&id| relative_distance(&soak.jobs[id as usize].kind) == d)
                    };
                    while taken(self, d) {
                        d += 1;
                    }
                    target += d;
                    let d = Pulses(i32::try_from(d).unwrap());
                    if self.rng.chance(0.2) {
                        // IAI's direct numeric move: v2 then m.
                        let (velocity, acceleration) = self.random_motion();
                        self.submit(
                            a,
                            JobKind::DirectMove {
                                target: d,
                                relative: true,
                                velocity,
                                acceleration,
                            },
                        );
                    } else {
                        self.submit(a, JobKind::MoveRelative(d));
                    }
                }
                self.maybe_stop_soon(a);
            }
            35..=49 => {
                let x = Pulses(-(500 + self.rng.below(9_000) as i32));
                if self.rng.chance(0.3) {
                    let (velocity, acceleration) = self.random_motion();
                    self.submit(
                        a,
                        JobKind::DirectMove {
                            target: x,
                            relative: false,
                            velocity,
                            acceleration,
                        },
                    );
                } else {
                    self.submit(a, JobKind::MoveAbsolute(x));
                }
                self.maybe_stop_soon(a);
            }
            50..=57 => {
                let (velocity, acceleration) = self.random_motion();
                self.submit(
                    a,
                    JobKind::SetMotion {
                        velocity,
                        acceleration,
                    },
                );
            }
            58..=62 => {
                self.submit(a, JobKind::Servo(false));
                self.submit(a, JobKind::Servo(true));
            }
            63..=70 => {
                let point = PositionNo::new(1 + self.rng.below(15) as u8).unwrap();
                let data = PointData {
                    position: Pulses(-(500 + self.rng.below(9_000) as i32)),
                    velocity: Velocity::new(1_500 + self.rng.below(4_500) as u16).unwrap(),
                    acceleration: Acceleration::new(50 + self.rng.below(350) as u16).unwrap(),
                    flags: PointData::FLAGS_MOTION_AND_BAND,
                    band: 5 + self.rng.below(50) as u32,
                    max_acceleration: 0,
                };
                self.submit(
                    a,
                    JobKind::WritePoint {
                        point,
                        data,
                        verify: true,
                    },
                );
                self.submit(a, JobKind::MoveToPoint(point));
            }
            71..=75 => {
                let written = self.plc[n].written;
                if written != 0 {
                    let mut p = 1 + self.rng.below(15) as u8;
                    while written & (1 << p) == 0 {
                        p = p % 15 + 1;
                    }
                    self.submit(a, JobKind::MoveToPoint(PositionNo::new(p).unwrap()));
                }
            }
            76..=81 => {
                let point = PositionNo::new(1 + self.rng.below(15) as u8).unwrap();
                self.submit(a, JobKind::ReadPoint(point));
            }
            82..=87 => {
                let point = PositionNo::new(1 + self.rng.below(15) as u8).unwrap();
                let (field, value) = match self.rng.below(4) {
                    0 => (
                        PointField::Position,
                        Pulses(-(500 + self.rng.below(9_000) as i32)).to_wire(),
                    ),
                    1 => (PointField::Velocity, 1_500 + self.rng.below(4_500) as u32),
                    2 => (PointField::Acceleration, 50 + self.rng.below(350) as u32),
                    _ => (PointField::Band, 5 + self.rng.below(50) as u32),
                };
                self.submit(
                    a,
                    JobKind::WriteField {
                        point,
                        field,
                        value,
                    },
                );
            }
            _ => {
                self.submit(a, JobKind::Stop);
            }
        }
    }

    fn random_motion(&mut self) -> (Velocity, Acceleration) {
        let velocity = Velocity::new(1_500 + self.rng.below(4_500) as u16).unwrap();
        let acceleration = Acceleration::new(50 + self.rng.below(350) as u16).unwrap();
        (velocity, acceleration)
    }

    /// Sometimes stop a move just after submitting it, often while its frame is on the wire.
    fn maybe_stop_soon(&mut self, a: Axis) {
        if self.rng.chance(0.15) {
            let at = self.now() + self.rng.below(30 * MS);
            self.stop_at.push((at, a));
        }
    }

    fn outstanding(&self) -> usize {
        self.fifo.iter().map(VecDeque::len).sum::<usize>()
            + self.stops.iter().map(Vec::len).sum::<usize>()
    }

    fn run(&mut self) {
        let mut delay_change = 0;
        let target = std::env::var("SOAK_TRANSACTIONS")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(TRANSACTIONS);
        while self.frames < target {
            let now = self.now();
            if now >= delay_change {
                // Late replies 21-45 ms late: always after Trt (20 ms + RTIM + frame after the
                // command), landing in later transactions at varying points.
                let mut faults = self.h.bus.config().faults;
                faults.reply_delay_us = 21 * MS + self.rng.below(24 * MS);
                self.h.bus.set_faults(faults);
                delay_change = now + 250 * MS;
            }
            self.plc();
            self.step(now + 10 * MS);
        }
        // Drain: no new work; everything submitted must finish.
        self.submitting = false;
        let limit = self.now() + 120 * S;
        while (self.outstanding() > 0 || self.cur.is_some()) && self.now() < limit {
            let now = self.now();
            self.step(now + 10 * MS);
        }
    }
}

#[test]
fn a_million_transactions_on_a_faulty_bus() {
    let wall = std::time::Instant::now();
    let mut soak = Soak::new();
    soak.run();
    let elapsed = wall.elapsed();
    let s = &soak;
    let stats = s.h.bus.stats().clone();

    // Per-axis counters against the test's own account of every transaction.
    let mut sum = Counters::default();
    let mut findings: Vec<String> = Vec::new();
    for n in 0..16 {
        let c = s.h.engine.axis(axis(n)).counters;
        let [accepted, timeouts, early] = s.per_axis[n];
        let open = u64::from(
            s.cur
                .as_ref()
                .is_some_and(|t| usize::from(t.axis.get()) == n),
        );
        // Every attempt ends exactly once: answered, timed out, or ended by a corrupted answer.
        if u64::from(c.frames_sent) != u64::from(c.replies) + u64::from(c.timeouts) + early + open {
            findings.push(format!(
                "axis {n}: frames_sent {} != replies {} + timeouts {} + corrupted-answer ends {early} + open {open}",
                c.frames_sent, c.replies, c.timeouts
            ));
        }
        if (u64::from(c.replies), u64::from(c.timeouts)) != (accepted, timeouts) {
            findings.push(format!(
                "axis {n}: engine replies/timeouts {}/{} vs observed {accepted}/{timeouts}",
                c.replies, c.timeouts
            ));
        }
        // Each resend follows a failed attempt of the same axis.
        if u64::from(c.retries) > timeouts + early {
            findings.push(format!("axis {n}: retries {} > failures", c.retries));
        }
        sum.frames_sent += c.frames_sent;
        sum.replies += c.replies;
        sum.timeouts += c.timeouts;
        sum.bcc_errors += c.bcc_errors;
        sum.bad_replies += c.bad_replies;
        sum.retries += c.retries;
        sum.rejections += c.rejections;
    }
    let t = &s.tally;
    let bus = s.h.engine.bus_counters();
    // Σ frames_sent: every host transmission on the sim's side is one engine frame.
    if u64::from(sum.frames_sent) != stats.host_transmissions {
        findings.push(format!(
            "Σ frames_sent {} != host transmissions {}",
            sum.frames_sent, stats.host_transmissions
        ));
    }
    // Every injected fault happened inside some transaction's window, so the per-transaction
    // deltas add up to the sim's totals exactly.
    for (name, ours, sim) in [
        (
            "host frames corrupted",
            t.host_corrupted_txns,
            stats.host_frames_corrupted,
        ),
        ("replies dropped", t.drops_in_flight, stats.replies_dropped),
        ("replies late", t.delays_in_flight, stats.replies_delayed),
    ] {
        if ours != sim {
            findings.push(format!("{name}: per transaction {ours} vs sim {sim}"));
        }
    }
    // Frames the controllers received valid and addressed to them: one per transaction whose
    // command arrived (more only if corruption turned a frame into a valid one for another axis).
    let addressed: u64 =
        s.h.bus
            .controllers()
            .map(|c| c.stats().frames_addressed)
            .sum();
    if addressed < t.cmd_received {
        findings.push(format!(
            "frames addressed {addressed} < commands received {}",
            t.cmd_received
        ));
    }
    // Failures: each is explained by a fault (checked one by one); conversely every faulted
    // transaction failed unless a stale or altered frame answered it.
    let failures = t.timeouts + t.early_ends;
    if failures + t.faulted_but_accepted != t.faulted_txns {
        findings.push(format!(
            "failures {failures} + faulted-but-answered {} != faulted transactions {}",
            t.faulted_but_accepted, t.faulted_txns
        ));
    }
    // Σ time-outs (and corrupted-answer ends) >= replies dropped while their command was in
    // flight, less those answered by a stale frame.
    if failures + t.faulted_but_accepted < t.drops_in_flight {
        findings.push("fewer failures than dropped replies".into());
    }
    // Candidates: what the engine counted equals what the mirror saw, category by category.
    let rejected: u64 = t
        .candidates
        .iter()
        .filter(|(k, _)| !k.starts_with("unsolicited"))
        .map(|(_, v)| v)
        .sum();
    let unsolicited: u64 = t
        .candidates
        .iter()
        .filter(|(k, _)| k.starts_with("unsolicited"))
        .map(|(_, v)| v)
        .sum();
    if rejected != u64::from(sum.bcc_errors) + u64::from(sum.bad_replies)
        || unsolicited != u64::from(bus.unsolicited)
    {
        findings.push(format!(
            "candidates {rejected}/{unsolicited} vs engine bcc+bad {}/{} unsolicited {}",
            sum.bcc_errors, sum.bad_replies, bus.unsolicited
        ));
    }
    if u64::from(sum.retries) != t.retries_seen {
        findings.push(format!(
            "Σ retries {} vs resends seen {}",
            sum.retries, t.retries_seen
        ));
    }
    if bus.events_lost != 0 {
        findings.push(format!("{} events lost", bus.events_lost));
    }

    // Jobs.
    let mut by_kind: BTreeMap<&'static str, BTreeMap<String, u64>> = BTreeMap::new();
    let mut unfinished = 0;
    for job in &s.jobs {
        match &job.done {
            Some(result) => {
                *by_kind
                    .entry(kind_name(&job.kind))
                    .or_default()
                    .entry(result_name(result))
                    .or_default() += 1
            }
            None => {
                unfinished += 1;
                *by_kind
                    .entry(kind_name(&job.kind))
                    .or_default()
                    .entry("UNFINISHED".into())
                    .or_default() += 1;
                if unfinished <= 3 {
                    let st = s.h.engine.axis(job.axis);
                    println!(
                        "unfinished: {:?} {:?} submitted {} link {:?} report {:?}",
                        job.axis, job.kind, job.submitted, st.link, st.report
                    );
                }
            }
        }
    }
    let m_sent: u64 = s.jobs.iter().map(|j| u64::from(j.m_sends)).sum();
    let mut lost_stops: BTreeMap<u32, u64> = BTreeMap::new();
    for job in s
        .jobs
        .iter()
        .filter(|j| j.kind == JobKind::Stop && j.done.is_none())
    {
        *lost_stops.entry(job.d_sends).or_default() += 1;
    }

    println!(
        "soak: seed {:#x}, {:.1} s wall, {:.2} h virtual",
        seed(),
        elapsed.as_secs_f64(),
        s.now() as f64 / 3.6e9
    );
    println!(
        "transactions (frames sent): {} (Σ frames_sent {}), replies {}, time-outs {}, \
         attempts ended by a corrupted answer {}, retries {}",
        s.frames, sum.frames_sent, sum.replies, sum.timeouts, t.early_ends, sum.retries
    );
    println!(
        "injected: host bytes corrupted {} ({} frames), reply bytes corrupted {} ({} replies), \
         replies dropped {}, late {}, noise bursts {} ({} bytes), collisions {} ({} bytes)",
        stats.host_bytes_corrupted,
        stats.host_frames_corrupted,
        stats.reply_bytes_corrupted,
        stats.replies_corrupted,
        stats.replies_dropped,
        stats.replies_delayed,
        stats.noise_bursts,
        stats.noise_bytes,
        stats.collisions,
        stats.collided_bytes
    );
    println!(
        "engine: bcc errors {}, bad replies {}, unsolicited {}, rejections {}, offline events {}, \
         queue full {}",
        sum.bcc_errors,
        sum.bad_replies,
        bus.unsolicited,
        sum.rejections,
        t.offline_events,
        t.queue_full
    );
    println!(
        "replies on the wire {}, arrived altered {}; altered frames with a valid BCC on the wire {}; \
         corrupted commands the controller still took as valid {}",
        t.replies_on_wire, t.replies_altered, t.altered_valid_on_wire, t.corrupted_commands_taken
    );
    println!(
        "accepted: fresh {}, stale (late answer to an earlier command) {} [{} before the earliest \
         possible answer time; by command {:?}], altered-but-valid {}",
        t.accepted[0], t.accepted[1], t.accepted_early, t.stale_by_command, t.accepted[2]
    );
    println!(
        "commands received valid by their axis {} of {}, frames addressed at the controllers {}, \
         deframer resets {}",
        t.cmd_received, s.frames, addressed, t.deframer_resets
    );
    println!("failed transactions by cause: {:?}", t.causes);
    println!("rejected candidates by cause: {:?}", t.candidates);
    println!(
        "jobs: {} submitted, {} unfinished, m transmissions {m_sent}",
        s.jobs.len(),
        unfinished
    );
    for (kind, results) in &by_kind {
        println!("  {kind}: {results:?}");
    }
    if !lost_stops.is_empty() {
        println!(
            "unfinished stops by `d` transmissions on their axis while outstanding: {lost_stops:?}"
        );
    }
    for d in &s.details {
        println!("  {d}");
    }
    println!("violations: {:?}", s.violations);
    println!("findings: {findings:?}");

    assert!(
        unfinished == 0 && findings.is_empty() && s.violations.is_empty(),
        "{unfinished} jobs never finished (by kind above); counter findings {findings:#?}; \
         violations {:#?}",
        s.violations
    );
}

// ------------------------------------------------------------------------------ reproductions
//
// Minimal, fault-free reproductions of what the soak found, with a silent axis (it executes
// commands but never answers) standing in for a lost answer.

/// `n` quiet controllers already at 115.2 kbit/s and RTIM 3 ms, and an engine that knows it.
fn quiet(n: usize) -> Harness {
    let mut bus = Bus::new(BusConfig {
        host_baud: BAUD,
        ..BusConfig::default()
    });
    for k in 0..n {
        bus.add_controller(
            axis(k),
            ControllerConfig {
                stored_line: Some((BAUD, Rtim::MIN)),
                ..ControllerConfig::default()
            },
        );
    }
    let engine = Engine::new(Config {
        axes: AxisSet::first(u8::try_from(n).unwrap()),
        establish: false,
        ..Config::default()
    });
    let mut h = Harness::new(engine, bus);
    h.run_until(50 * MS);
    h
}

fn done(h: &Harness, id: protocol::engine::JobId) -> Option<Result<JobOutput, JobError>> {
    h.events.iter().find_map(|(_, e)| match e {
        Event::JobDone { id: i, result, .. } if *i == id => Some(*result),
        _ => None,
    })
}

fn run_until_sent(h: &mut Harness, found: impl Fn(&Request) -> bool) {
    let until = h.now + S;
    while h.now < until {
        let seen = h.sent.len();
        h.step(until);
        if h.sent[seen..].iter().any(|(_, r)| found(r)) {
            return;
        }
    }
    panic!("not sent");
}

/// The axis homed, silent while `command` reaches it (so that its answer is lost) and answering
/// again right after; then a stop while `command` waits for its answer. Returns
/// the index in `h.sent` and `h.events` from the stop on.
fn stop_while_unanswered(command: Command) -> (Harness, usize, usize) {
    let mut h = quiet(1);
    let home = h
        .engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::Home(HomeDirection::MotorEnd),
        })
        .unwrap();
    h.run_until(h.now + 5 * S);
    assert!(matches!(done(&h, home), Some(Ok(_))));
    let kind = match command {
        Command::MoveAbsolute(x) => JobKind::MoveAbsolute(x),
        Command::MoveRelative(d) => JobKind::MoveRelative(d),
        _ => unreachable!(),
    };
    h.engine
        .submit(Job {
            axis: axis(0),
            kind,
        })
        .unwrap();
    run_until_sent(&mut h, |r| r.command == command);
    // The controller takes the command 1.4 ms later and drops its answer.
    h.bus.set_silent(axis(0), true);
    h.run_until(h.now + 2 * MS);
    h.bus.set_silent(axis(0), false);
    let (sent, events) = (h.sent.len(), h.events.len());
    let stop = h
        .engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::Stop,
        })
        .unwrap();
    h.run_until(h.now + 2 * S);
    assert!(
        matches!(done(&h, stop), Some(Ok(_))),
        "{:?}",
        done(&h, stop)
    );
    (h, sent, events)
}

/// Engine bug: a job frame in flight when a stop cancels its job becomes a poll
/// (`cancel_jobs`: `origin = Origin::Poll`), and a poll that times out is resent: the `a` goes
/// out again after the `d`, and the axis drives on to the cancelled target.
#[test]
fn a_move_cancelled_while_its_answer_is_lost_is_not_resent_after_the_stop() {
    let target = Pulses(-8_000);
    let (h, sent, _) = stop_while_unanswered(Command::MoveAbsolute(target));
    let resent: Vec<_> = h.sent[sent..]
        .iter()
        .filter(|(_, r)| r.command == Command::MoveAbsolute(target))
        .collect();
    let c = h.bus.controller(axis(0)).unwrap();
    assert!(
        resent.is_empty(),
        "the cancelled move went out again after the stop: {resent:?}; the axis is at {} \
         (target {}), moving {}",
        c.position(),
        target.0,
        c.moving()
    );
    assert!(c.position() > -7_000, "stopped short of the target");
}

/// Engine bug, same cause: the lost answer of a cancelled `m` (not resendable) fails the
/// "poll" it became, and a failed poll takes the axis offline after one lost answer.
#[test]
fn a_lost_answer_to_a_cancelled_m_does_not_take_the_axis_offline() {
    let (h, _, events) = stop_while_unanswered(Command::MoveRelative(Pulses(-3_000)));
    let offline: Vec<_> = h.events[events..]
        .iter()
        .filter(|(_, e)| matches!(e, Event::Offline(_)))
        .collect();
    assert!(
        offline.is_empty(),
        "one lost answer took the axis offline: {offline:?}"
    );
}

/// Engine bug: stops go before the resend slot, and a stop that needs a resend takes the slot
/// (`self.retry = Some(..)`) even when another stop's resend is waiting in it: that stop is never
/// sent again and never finishes (no JobDone).
#[test]
fn a_stop_waiting_for_its_resend_is_not_lost_behind_another_axis_stop() {
    let mut h = quiet(2);
    for n in 0..2 {
        h.bus.set_silent(axis(n), true);
    }
    let first = h
        .engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::Stop,
        })
        .unwrap();
    run_until_sent(&mut h, |r| {
        r.axis == axis(0) && r.command == Command::CancelMotion
    });
    // While the first `d` waits for its (lost) answer, stop the other axis.
    let second = h
        .engine
        .submit(Job {
            axis: axis(1),
            kind: JobKind::Stop,
        })
        .unwrap();
    h.run_until(h.now + 2 * S);
    let d0 = h
        .sent
        .iter()
        .filter(|(_, r)| r.axis == axis(0) && r.command == Command::CancelMotion)
        .count();
    assert_eq!(done(&h, second), Some(Err(JobError::Timeout)));
    assert_eq!(
        done(&h, first),
        Some(Err(JobError::Timeout)),
        "the first stop never finished; its `d` went out {d0} time(s) (1 + Nrt = 3 expected)"
    );
}
