//! A controller's serial line (complete edition §2, §3, §4-3, §6-1, §7-2-1): what it does with
//! each byte it hears, when it answers, breaks, the communication-change broadcast, power.
//!
//! See [`super::controller`] for the model; this module holds its line half.

use protocol::alarm::AlarmCode;
use protocol::frame::{Frame, Packet, FRAME_LEN};
use protocol::line::{Baud, BAUD_AFTER_BREAK};
use protocol::memory::common;
use protocol::reply::RESPONSE_ID;
use protocol::{Axis, Code, Command, Error, Reply, Request, Rtim, StatusReport, RTIM_AFTER_BREAK};

use super::controller::{
    BadBccPolicy, Body, Controller, PendingReply, W_ADDRESS, W_BCC, W_OPERAND1, W_OPERAND2,
    W_OPERAND3,
};
use super::memory::{ci, Memory, NonVolatile};
use super::wire::{break_threshold, ms};

fn line_state(nv: &NonVolatile) -> (Baud, u8) {
    match Baud::from_brsl(nv.common[ci(common::BRSL)]) {
        Some(baud) => (baud, clamp_rtim(nv.common[ci(common::RTIM)])),
        None => (BAUD_AFTER_BREAK, RTIM_AFTER_BREAK.get()),
    }
}

/// An RTIM word as the controller uses it: 3-255 ms.
pub(super) fn clamp_rtim(value: u32) -> u8 {
    u8::try_from(value.clamp(u32::from(Rtim::MIN.get()), u32::from(Rtim::MAX.get())))
        .unwrap_or(u8::MAX)
}

fn hex_pair(byte: u8) -> [u8; 2] {
    const DIGITS: &[u8; 16] = b"0123456789ABCDEF";
    [
        DIGITS[usize::from(byte >> 4)],
        DIGITS[usize::from(byte & 0x0F)],
    ]
}

/// A direct-format response for any command character, including ones the codec does not know
/// (the controller echoes what it received).
fn status_frame(axis: Axis, code: u8, report: &StatusReport) -> Frame {
    if let Some(code) = Code::from_char(code) {
        return Reply::Status {
            axis,
            code,
            report: *report,
        }
        .emit();
    }
    let mut data = [b'0'; 12];
    data[0] = RESPONSE_ID;
    data[1] = axis.to_char();
    data[2] = code;
    let fields = [
        report.status.bits(),
        report.alarm.0,
        report.inputs.bits(),
        report.outputs.bits(),
    ];
    for (i, value) in fields.into_iter().enumerate() {
        let [hi, lo] = hex_pair(value);
        data[3 + 2 * i] = hi;
        data[4 + 2 * i] = lo;
    }
    Frame::from_data(data)
}

/// The warning a controller answers a frame it cannot parse with (§8-1-5): operand errors by
/// the operand's place, anything else an illegal character.
fn warning_for(error: &Error) -> u8 {
    use protocol::Field;
    match error {
        Error::FieldOutOfRange { field, .. } => match field {
            Field::PositionNo | Field::Velocity => W_OPERAND2,
            Field::Acceleration => W_OPERAND3,
            _ => W_OPERAND1,
        },
        _ => W_ADDRESS,
    }
}

impl Controller {
    // ----- power and line -----

    /// Lose power: nothing is received or sent until [`power_on`](Self::power_on).
    pub fn power_off(&mut self, now: u64) {
        self.update(now);
        let (x, _) = self.kinematics(now);
        self.x = x;
        self.motion = None;
        self.homing = None;
        if self.reply.take().is_some() {
            self.stats.replies_cancelled += 1;
        }
        self.powered = false;
    }

    /// Power up at `now` from non-volatile memory (§7-3-1, §7-3-2): line settings stored by V5
    /// (or the default state), servo on (§4-4-15), not homed, the slider where it physically is
    /// with coordinate 0 there, PFIN on once motor initialization is over.
    pub fn power_on(&mut self, now: u64) {
        let physical = self.physical_position_f64();
        self.now = now.max(self.now);
        let nv = self.memory.nv.clone();
        let (baud, rtim) = line_state(&nv);
        self.memory = Memory::power_up(nv);
        self.baud = baud;
        self.rtim = rtim;
        self.comm_change = None;
        self.deframer.reset();
        self.servo = true;
        self.alarm = AlarmCode::NONE;
        self.zfin = false;
        self.pm = 0;
        self.x = 0.0;
        self.mech_max = physical.round() as i64;
        self.motion = None;
        self.homing = None;
        self.buffered = None;
        self.reply = None;
        self.init_until = self.now.saturating_add(self.config.init_time_us);
        self.initializing = self.config.init_time_us > 0;
        self.pfin = !self.initializing;
        self.powered = true;
        self.stats.power_ups += 1;
    }

    /// The line has been held low, and will be for `duration` µs in all; the controller notices
    /// at `now`. A break (more than 10 bit times at this controller's rate) restores 9.6 kbit/s
    /// and RTIM 255 ms; anything shorter reads as a framing error. Either way a partial frame
    /// and a prepared reply are dropped. Returns whether a prepared reply was dropped.
    pub fn line_low(&mut self, now: u64, duration: u64) -> bool {
        self.update(now);
        if !self.powered {
            return false;
        }
        if duration >= break_threshold(self.baud) {
            self.baud = BAUD_AFTER_BREAK;
            self.rtim = RTIM_AFTER_BREAK.get();
            self.comm_change = None;
            self.stats.breaks += 1;
        }
        self.deframer.reset();
        self.cancel_reply()
    }

    /// A byte arrives at `now`, sent at `sender` (`None`: a glitch, read at any rate).
    /// Returns the time of the reply when this byte completes a command that is answered.
    pub fn receive(&mut self, now: u64, byte: u8, sender: Option<Baud>) -> Option<u64> {
        self.update(now);
        if !self.powered {
            return None;
        }
        if sender.is_some_and(|baud| baud != self.baud) {
            self.stats.wrong_baud_bytes += 1;
            self.deframer.reset();
            return None;
        }
        self.stats.bytes_received += 1;
        match self.deframer.push(byte) {
            Ok(Packet::CommChange) => {
                self.stats.comm_change_frames += 1;
                if self.comm_change.is_none() {
                    let (baud, rtim) = self.edit_line_settings();
                    let at = now.saturating_add(self.config.comm_change_delay_us);
                    self.comm_change = Some((at, baud, rtim));
                }
                None
            }
            Ok(Packet::Frame(frame)) => self.on_frame(now, &frame),
            Err(protocol::nb::Error::Other(error)) => self.on_bad_candidate(now, error),
            Err(protocol::nb::Error::WouldBlock) => None,
        }
    }

    fn edit_line_settings(&self) -> (Baud, u8) {
        let edit = &self.memory.edit.common;
        match Baud::from_brsl(edit[ci(common::BRSL)]) {
            Some(baud) => (baud, clamp_rtim(edit[ci(common::RTIM)])),
            None => (BAUD_AFTER_BREAK, RTIM_AFTER_BREAK.get()),
        }
    }

    fn on_bad_candidate(&mut self, now: u64, error: Error) -> Option<u64> {
        let bytes = self.deframer.rejected();
        if !matches!(error, Error::BadBcc { .. }) {
            self.stats.bad_frames += 1;
            return None;
        }
        self.stats.bad_bcc += 1;
        let (axis_char, code) = (bytes.get(1).copied(), bytes.get(2).copied());
        let addressed = axis_char.and_then(|c| Axis::from_char(c).ok()) == Some(self.axis);
        match (self.config.bad_bcc, addressed, code) {
            (BadBccPolicy::RejectIfAddressed, true, Some(code)) => {
                Some(self.schedule(now, code, Err(W_BCC), false))
            }
            _ => None,
        }
    }

    fn on_frame(&mut self, now: u64, frame: &Frame) -> Option<u64> {
        let data = frame.data();
        if data[0] == RESPONSE_ID {
            self.stats.foreign_replies += 1;
            return None;
        }
        let addressed = Axis::from_char(data[0]).ok() == Some(self.axis);
        match Request::parse(frame) {
            Ok(request) if addressed => {
                self.stats.frames_addressed += 1;
                let store = matches!(request.command, Command::StoreFromEdit(_));
                let outcome = self.execute(now, request.command);
                Some(self.schedule(now, data[1], outcome, store))
            }
            Ok(request) if request.command == Command::ExecuteBuffered => {
                self.stats.broadcasts += 1;
                let _ = self.run_buffered(now);
                None
            }
            Err(error) if addressed => {
                self.stats.frames_addressed += 1;
                Some(self.schedule(now, data[1], Err(warning_for(&error)), false))
            }
            _ => {
                self.stats.frames_for_others += 1;
                None
            }
        }
    }

    /// Prepare the response to a command received at `now`: RTIM later (plus the store time
    /// for V5). A reply still waiting is replaced.
    fn schedule(&mut self, now: u64, code: u8, outcome: Result<Body, u8>, store: bool) -> u64 {
        let frame = match outcome {
            Ok(Body::Memory(code, value)) => Reply::Memory {
                axis: self.axis,
                code,
                value,
            }
            .emit(),
            Ok(Body::Status) => status_frame(self.axis, code, &self.report(None)),
            Err(warning) => {
                *self.stats.rejections.entry(warning).or_default() += 1;
                status_frame(self.axis, code, &self.report(Some(warning)))
            }
        };
        let extra = if store { self.config.store_time_us } else { 0 };
        let at = now
            .saturating_add(ms(u64::from(self.rtim)))
            .saturating_add(extra);
        if self.reply.is_some() {
            self.stats.replies_superseded += 1;
        }
        self.reply = Some(PendingReply {
            at,
            bytes: frame.to_bytes(),
        });
        self.stats.replies_scheduled += 1;
        at
    }

    /// When the prepared reply goes out, if there is one.
    pub fn reply_due(&self) -> Option<u64> {
        self.reply.map(|reply| reply.at)
    }

    /// Take the prepared reply if it is due at `now`: its bytes and the rate to send them at.
    pub fn take_reply(&mut self, now: u64) -> Option<([u8; FRAME_LEN], Baud)> {
        self.update(now);
        let reply = self.reply.filter(|reply| reply.at <= now)?;
        self.reply = None;
        if !self.powered {
            return None;
        }
        self.stats.replies_sent += 1;
        Some((reply.bytes, self.baud))
    }

    /// Drop the prepared reply (returns whether there was one).
    pub fn cancel_reply(&mut self) -> bool {
        let cancelled = self.reply.take().is_some();
        if cancelled {
            self.stats.replies_cancelled += 1;
        }
        cancelled
    }

    /// Send the prepared reply `extra` µs later.
    pub fn delay_reply(&mut self, extra: u64) {
        if let Some(reply) = self.reply.as_mut() {
            reply.at = reply.at.saturating_add(extra);
        }
    }
}
