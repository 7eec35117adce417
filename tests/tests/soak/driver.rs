//! The soak's state, its set-up, and the loop that drives the engine and the bus byte by byte.

use std::collections::{BTreeMap, VecDeque};

use protocol::engine::{timing, Config, Engine, Output};
use protocol::time::{Duration, Instant};
use protocol::AxisSet;
use protocol::{Axis, Command, Deframer, Frame, Request, Rtim};
use rc_host::harness::Harness;
use rc_tools::sim::rng::Rng;
use rc_tools::sim::wire::byte_offset;
use rc_tools::sim::{Bus, BusConfig, ControllerConfig, Faults};

use crate::job_records::JobRec;
use crate::plc::Plc;
use crate::transactions::{snap, End, Snap, Txn};
use crate::wire::{Pending, Rx, SentReply};
use crate::{axis, seed, BAUD, FRAME_LEN, MS, RETRIES, S, STX, TRANSACTIONS};

#[derive(Default)]
pub(crate) struct Tally {
    pub(crate) accepted: [u64; 3],
    pub(crate) accepted_early: u64,
    pub(crate) stale_by_command: BTreeMap<&'static str, u64>,
    pub(crate) timeouts: u64,
    pub(crate) early_ends: u64,
    pub(crate) causes: BTreeMap<&'static str, u64>,
    /// Transactions that met a fault but were answered anyway (stale or altered frame).
    pub(crate) faulted_but_accepted: u64,
    pub(crate) faulted_txns: u64,
    pub(crate) drops_in_flight: u64,
    pub(crate) delays_in_flight: u64,
    pub(crate) host_corrupted_txns: u64,
    /// Corrupted commands that still reached the addressed controller as a valid frame.
    pub(crate) corrupted_commands_taken: u64,
    pub(crate) cmd_received: u64,
    pub(crate) candidates: BTreeMap<&'static str, u64>,
    pub(crate) replies_on_wire: u64,
    pub(crate) replies_altered: u64,
    pub(crate) altered_valid_on_wire: u64,
    pub(crate) offline_events: u64,
    pub(crate) retries_seen: u64,
    pub(crate) queue_full: u64,
    pub(crate) deframer_resets: u64,
}

pub(crate) struct Soak {
    pub(crate) h: Harness,
    pub(crate) rng: Rng,
    // wire
    pub(crate) pending: [Option<Pending>; 16],
    pub(crate) sched_seen: [u64; 16],
    scan_marks: (u64, u64, u64),
    pub(crate) sent_seen: [u64; 16],
    pub(crate) replies: VecDeque<SentReply>,
    /// Index of the first reply not yet complete (replies complete in order).
    pub(crate) open_from: usize,
    pub(crate) next_reply_id: u64,
    /// Arrival of byte k after the start of a transmission.
    pub(crate) offsets: [u64; FRAME_LEN],
    pub(crate) ring: [Rx; FRAME_LEN],
    pub(crate) ring_pos: usize,
    pub(crate) mirror: Deframer,
    // engine
    pub(crate) snaps: [Snap; 16],
    pub(crate) unsolicited: u32,
    pub(crate) cur: Option<Txn>,
    next_seq: u64,
    pub(crate) frames: u64,
    pub(crate) per_axis: [[u64; 3]; 16], // accepted, timeouts, early ends
    pub(crate) history: [VecDeque<(Request, bool)>; 16],
    pub(crate) offline_checks: Vec<Axis>,
    // jobs
    pub(crate) jobs: Vec<JobRec>,
    pub(crate) fifo: [VecDeque<u32>; 16],
    pub(crate) stops: [Vec<u32>; 16],
    /// The last jobs a stop cancelled, per axis.
    pub(crate) cancelled: [VecDeque<u32>; 16],
    pub(crate) plc: [Plc; 16],
    pub(crate) stop_at: Vec<(u64, Axis)>,
    pub(crate) submitting: bool,
    pub(crate) plc_check_at: u64,
    // results
    pub(crate) tally: Tally,
    pub(crate) violations: BTreeMap<&'static str, u64>,
    pub(crate) details: Vec<String>,
}

impl Soak {
    pub(crate) fn new() -> Soak {
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
            wire_time: true,
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

    pub(crate) fn violation(&mut self, kind: &'static str, detail: String) {
        let count = self.violations.entry(kind).or_default();
        *count += 1;
        if *count <= 3 {
            self.details
                .push(format!("t={} µs {kind}: {detail}", self.h.now));
        }
    }

    pub(crate) fn now(&self) -> u64 {
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
    pub(crate) fn finish_replies(&mut self, t: u64, inclusive: bool) {
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
    pub(crate) fn check_all_axes(&mut self, at: &'static str) {
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
        // A `d` to an axis owed a stop (its own got no answer) stands in for whatever the
        // engine would have sent it: no job's frame.
        let owed = self.h.engine.stop_owed(a);
        self.attribute(now, request, owed);

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

    fn outstanding(&self) -> usize {
        self.fifo.iter().map(VecDeque::len).sum::<usize>()
            + self.stops.iter().map(Vec::len).sum::<usize>()
    }

    pub(crate) fn run(&mut self) {
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
