//! A scripted host: sends requests on a [`Bus`] and waits for the answers the way the complete
//! edition's §5 says (time-out Trt = 20 + RTIM + 160/Kbr ms, 200 + ... for V5), in virtual
//! time. It is a test tool, not a bus master: no retries, no polling schedule.
//!
//! Frames are written with [`Request::emit`] and read with [`Deframer`] + [`Reply::parse`];
//! a reply counts when it [`answers`](Reply::answers) the request. Everything else the host
//! receives is kept in [`ScriptedHost::strays`].

use protocol::engine::point_jobs::{Step, StepError};
use protocol::frame::{Packet, COMM_CHANGE, FRAME_LEN};
use protocol::line::{Baud, HOST_GAP_MS};
use protocol::{Axis, Command, Deframer, Reply, Request, StatusReport};

use super::bus::Bus;
use super::wire::ms;

/// An answer and when it came.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Answer {
    /// The reply.
    pub reply: Reply,
    /// When the command's first byte went out (µs).
    pub sent_at: u64,
    /// When the command's last byte left (µs).
    pub sent_end: u64,
    /// When the reply's first byte was received (its stop bit, µs).
    pub first_byte_at: u64,
    /// When the reply's last byte was received (µs).
    pub last_byte_at: u64,
}

/// A job step that failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JobFailure {
    /// No answer within Trt at this step.
    Timeout(usize),
    /// The answer did not confirm the step.
    Step(usize, StepError),
}

/// A host in virtual time; see the [module documentation](self).
#[derive(Clone, Debug)]
pub struct ScriptedHost {
    bus: Bus,
    now: u64,
    deframer: Deframer,
    rtim_ms: u8,
    gap_us: u64,
    /// Arrival times of the last 16 bytes, to date a frame's first byte.
    recent: [u64; FRAME_LEN],
    received: usize,
    inbox: Vec<(u64, u64, Packet)>,
    strays: Vec<(u64, Packet)>,
    log: Vec<(u64, u8)>,
}

impl ScriptedHost {
    /// A host on `bus`, starting at the bus's time, assuming RTIM 255 ms.
    pub fn new(bus: Bus) -> ScriptedHost {
        ScriptedHost {
            now: bus.now(),
            bus,
            deframer: Deframer::new(),
            rtim_ms: 255,
            gap_us: ms(u64::from(HOST_GAP_MS)),
            recent: [0; FRAME_LEN],
            received: 0,
            inbox: Vec::new(),
            strays: Vec::new(),
            log: Vec::new(),
        }
    }

    /// The bus.
    pub fn bus(&self) -> &Bus {
        &self.bus
    }

    /// The bus, to inject faults or change controllers.
    pub fn bus_mut(&mut self) -> &mut Bus {
        &mut self.bus
    }

    /// The host's time (µs).
    pub fn now(&self) -> u64 {
        self.now
    }

    /// The RTIM the host assumes when it computes time-outs.
    pub fn set_rtim_belief(&mut self, rtim_ms: u8) {
        self.rtim_ms = rtim_ms;
    }

    /// The pause after a reply before the next command (default 1 ms, §2 (2)).
    pub fn set_gap_us(&mut self, gap_us: u64) {
        self.gap_us = gap_us;
    }

    /// Packets received that answered no request, with their arrival times.
    pub fn strays(&self) -> &[(u64, Packet)] {
        &self.strays
    }

    /// Every byte received, with its arrival time.
    pub fn log(&self) -> &[(u64, u8)] {
        &self.log
    }

    /// The host's deframer (its counters tell noise and broken frames).
    pub fn deframer(&self) -> &Deframer {
        &self.deframer
    }

    /// Switch the host's rate (forgets any partial frame).
    pub fn set_baud(&mut self, baud: Baud) {
        self.bus.set_host_baud(baud);
        self.deframer.reset();
    }

    /// Trt for `command` at the present rate and assumed RTIM (complete edition §5 (1)), µs.
    pub fn timeout_us(&self, command: &Command) -> u64 {
        let base_ms = if matches!(command, Command::StoreFromEdit(_)) {
            200
        } else {
            20
        };
        let bps = u64::from(self.bus.host_baud().bits_per_second());
        ms(base_ms + u64::from(self.rtim_ms)) + 160_000_000u64.div_ceil(bps)
    }

    /// Run to `t`, reading what arrives; packets received go to [`strays`](Self::strays).
    pub fn wait_until(&mut self, t: u64) {
        self.advance_to(t);
        self.flush();
    }

    fn advance_to(&mut self, t: u64) {
        let bytes = self.bus.advance(t);
        self.feed(&bytes);
        self.now = self.now.max(t);
    }

    /// Packets not claimed by a request become strays (a host empties its receive buffer
    /// before it sends, so that a late reply cannot answer a later request).
    fn flush(&mut self) {
        for (_, last, packet) in self.inbox.drain(..) {
            self.strays.push((last, packet));
        }
    }

    /// Run for `us` microseconds.
    pub fn wait(&mut self, us: u64) {
        self.wait_until(self.now.saturating_add(us));
    }

    fn feed(&mut self, bytes: &[(u64, u8)]) {
        for &(t, byte) in bytes {
            self.log.push((t, byte));
            self.recent[self.received % FRAME_LEN] = t;
            self.received += 1;
            if let Ok(packet) = self.deframer.push(byte) {
                // The frame's first byte arrived 15 bytes before this one.
                let first = self.recent[self.received % FRAME_LEN];
                self.inbox.push((first, t, packet));
            }
        }
    }

    /// Send raw bytes now (or after the host's previous transmission); returns (start, end).
    /// The host's time does not move, so a test can talk over a reply on purpose.
    pub fn send_bytes(&mut self, bytes: &[u8]) -> (u64, u64) {
        self.flush();
        let start = self.now.max(self.bus.host_busy_until());
        let end = self.bus.host_send(start, bytes);
        self.now = start;
        (start, end)
    }

    /// Send `request` and wait up to Trt after its last byte for the reply that answers it.
    /// On success the host's time is the reply's end plus the host gap; on time-out, the
    /// deadline.
    pub fn transact(&mut self, request: &Request) -> Option<Answer> {
        let (sent_at, sent_end) = self.send_bytes(&request.emit().to_bytes());
        let deadline = sent_end.saturating_add(self.timeout_us(&request.command));
        self.await_reply(request, sent_at, sent_end, deadline)
    }

    /// Wait until `deadline` for a reply answering `request` (sent at `sent_at`..`sent_end`).
    pub fn await_reply(
        &mut self,
        request: &Request,
        sent_at: u64,
        sent_end: u64,
        deadline: u64,
    ) -> Option<Answer> {
        loop {
            if let Some(answer) = self.take_answer(request, sent_at, sent_end) {
                self.wait_until(answer.last_byte_at.saturating_add(self.gap_us));
                return Some(answer);
            }
            match self.bus.next_event().filter(|&t| t <= deadline) {
                Some(t) => self.advance_to(t),
                None => {
                    self.advance_to(deadline);
                    if let Some(answer) = self.take_answer(request, sent_at, sent_end) {
                        self.wait_until(answer.last_byte_at.saturating_add(self.gap_us));
                        return Some(answer);
                    }
                    self.flush();
                    return None;
                }
            }
        }
    }

    fn take_answer(&mut self, request: &Request, sent_at: u64, sent_end: u64) -> Option<Answer> {
        let mut found = None;
        for (first, last, packet) in std::mem::take(&mut self.inbox) {
            let reply = match packet {
                Packet::Frame(frame) => Reply::parse(&frame).ok(),
                Packet::CommChange => None,
            };
            match reply {
                Some(reply) if found.is_none() && reply.answers(request).is_ok() => {
                    found = Some(Answer {
                        reply,
                        sent_at,
                        sent_end,
                        first_byte_at: first,
                        last_byte_at: last,
                    });
                }
                _ => self.strays.push((last, packet)),
            }
        }
        found
    }

    /// `n` to `axis`: the status, if it answers.
    pub fn status(&mut self, axis: Axis) -> Option<StatusReport> {
        let answer = self.transact(&Request::new(axis, Command::Status))?;
        answer.reply.report().copied()
    }

    /// Poll `n` until `done` holds or `timeout_us` passes; returns the answer that satisfied it
    /// (its `sent_end` is when the controller evaluated the status) and the status.
    pub fn poll_until(
        &mut self,
        axis: Axis,
        timeout_us: u64,
        mut done: impl FnMut(&StatusReport) -> bool,
    ) -> Option<(Answer, StatusReport)> {
        let deadline = self.now.saturating_add(timeout_us);
        while self.now <= deadline {
            if let Some(answer) = self.transact(&Request::new(axis, Command::Status)) {
                if let Some(report) = answer.reply.report().filter(|r| done(r)) {
                    return Some((answer, *report));
                }
            }
        }
        None
    }

    /// Run a job's frames in order, each confirmed by its answer; returns each step's value.
    pub fn run_job(&mut self, steps: &[Step]) -> Result<Vec<Option<u32>>, JobFailure> {
        let mut values = Vec::with_capacity(steps.len());
        for (index, step) in steps.iter().enumerate() {
            let answer = self
                .transact(&step.request)
                .ok_or(JobFailure::Timeout(index))?;
            let value = step
                .expect
                .check(&answer.reply)
                .map_err(|e| JobFailure::Step(index, e))?;
            values.push(value);
        }
        Ok(values)
    }

    /// A break of `duration_us`, then wait until it ends (and assume RTIM 255 ms again).
    pub fn break_line(&mut self, duration_us: u64) {
        let end = self.bus.host_break(self.now, duration_us);
        self.wait_until(end);
        self.deframer.reset();
        self.rtim_ms = 255;
    }

    /// Send the communication-change broadcast (STX + 14 ENQ + ETX, §6-1 step 8) and wait until
    /// it has left; nobody answers.
    pub fn comm_change(&mut self) {
        let (_, end) = self.send_bytes(&COMM_CHANGE);
        self.wait_until(end);
    }
}
