//! A stand-in for `protocol::node::Node` while it is being written: the same [`Node`] contract,
//! with a behaviour simple enough to check the hardware layer from outside (the emulator harness
//! in `tests/emu/`, or a person with two RS485 adapters). It is replaced, not extended.
//!
//! - Bus and PLC lines form a transparent bridge: every 16 bytes from the PLC go to the bus as one
//!   frame (a partial frame is dropped after [`PARTIAL_FRAME_TIMEOUT`]); bytes from the bus go
//!   to the PLC as they arrive.
//! - A 16-byte PLC frame that starts with ESC (0x1B) is a command for the bridge itself, answered
//!   on the PLC line once carried out: `ESC B <rate in decimal>` sets the bus rate (answer
//!   `ESC b`), `ESC K` holds a break for [`BREAK_MS`] (answers `ESC K` when it starts and `ESC k`
//!   when it ends), `ESC C` sends the communication-change frame (answer `ESC c`); in the emulator
//!   build `ESC P` panics, so that the harness can check the fail-safe.
//! - Outputs mirror the inputs bit for bit (INn drives OUTn, where OUTn exists), and all go OFF
//!   while the stop input is active. Link LED: a bus byte within the last second; alarm LED: stop.

use crate::node::{Action, Baud, Instant, LineAction, Node, PioInputs, PioOutputs};
use protocol::engine::Duration;
use protocol::line::BREAK_MS;

/// A partial PLC frame older than this is dropped.
pub const PARTIAL_FRAME_TIMEOUT: Duration = Duration::from_millis(100);
/// The link LED stays on this long after a bus byte.
const LINK_HOLD: Duration = Duration::from_millis(1000);
const ESC: u8 = 0x1B;

/// The bring-up bridge's state (see the module documentation).
pub struct BringUp {
    frame: [u8; 16],
    frame_len: usize,
    frame_started: Instant,
    /// Bytes from the bus not yet sent to the PLC.
    to_plc: [u8; 64],
    to_plc_len: usize,
    /// Frames for the bus, sent in order.
    to_bus: Option<[u8; 16]>,
    line: Option<LineAction>,
    /// The answer to a bridge command, sent after the command's action.
    answer: Option<[u8; 2]>,
    answer_buf: [u8; 2],
    break_ends: Option<Instant>,
    inputs: PioInputs,
    stop: bool,
    last_bus_byte: Option<Instant>,
    now: Instant,
}

impl BringUp {
    /// Nothing received, outputs OFF, the stop considered active until the first sample says
    /// otherwise.
    pub const fn new() -> BringUp {
        BringUp {
            frame: [0; 16],
            frame_len: 0,
            frame_started: Instant(0),
            to_plc: [0; 64],
            to_plc_len: 0,
            to_bus: None,
            line: None,
            answer: None,
            answer_buf: [0; 2],
            break_ends: None,
            inputs: PioInputs::NONE,
            stop: true,
            last_bus_byte: None,
            now: Instant(0),
        }
    }

    fn plc_frame(&mut self, now: Instant) {
        let frame = self.frame;
        self.frame_len = 0;
        if frame[0] != ESC {
            self.to_bus = Some(frame);
            return;
        }
        match frame[1] {
            b'B' => {
                let rate = frame[2..]
                    .iter()
                    .take_while(|b| b.is_ascii_digit())
                    .fold(0u32, |n, b| {
                        n.saturating_mul(10).saturating_add(u32::from(b - b'0'))
                    });
                match Baud::from_bits_per_second(rate) {
                    Some(baud) => self.command(LineAction::SetBaud(baud), b'b'),
                    None => self.answer = Some([ESC, b'?']),
                }
            }
            b'K' => {
                self.command(LineAction::BreakStart, b'K');
                self.break_ends = Some(now + Duration::from_millis(u64::from(BREAK_MS)));
            }
            b'C' => self.command(LineAction::CommChange, b'c'),
            #[cfg(feature = "emulator")]
            b'P' => panic!("panic requested over the PLC line"),
            _ => self.answer = Some([ESC, b'?']),
        }
    }

    fn partial_expired(&self, now: Instant) -> bool {
        self.frame_len > 0 && now.since(self.frame_started) >= PARTIAL_FRAME_TIMEOUT
    }

    fn command(&mut self, action: LineAction, answer: u8) {
        self.line = Some(action);
        self.answer = Some([ESC, answer]);
    }
}

impl Default for BringUp {
    fn default() -> Self {
        BringUp::new()
    }
}

impl Node for BringUp {
    fn bus_received(&mut self, now: Instant, bytes: &[u8]) {
        self.last_bus_byte = Some(now);
        let room = self.to_plc.len() - self.to_plc_len;
        let n = bytes.len().min(room);
        if let (Some(dst), Some(src)) = (
            self.to_plc.get_mut(self.to_plc_len..self.to_plc_len + n),
            bytes.get(..n),
        ) {
            dst.copy_from_slice(src);
            self.to_plc_len += n;
        }
    }

    fn plc_received(&mut self, now: Instant, bytes: &[u8]) {
        for &byte in bytes {
            if self.partial_expired(now) {
                self.frame_len = 0;
            }
            if self.frame_len == 0 {
                self.frame_started = now;
            }
            if let Some(slot) = self.frame.get_mut(self.frame_len) {
                *slot = byte;
                self.frame_len += 1;
            }
            if self.frame_len == self.frame.len() {
                self.plc_frame(now);
            }
        }
    }

    fn sample_inputs(&mut self, _now: Instant, inputs: PioInputs) {
        self.inputs = inputs;
    }

    fn set_stop_input(&mut self, _now: Instant, active: bool) {
        self.stop = active;
    }

    fn poll(&mut self, now: Instant) -> Option<Action<'_>> {
        self.now = now;
        if self.partial_expired(now) {
            self.frame_len = 0;
        }
        if let Some(line) = self.line.take() {
            return Some(Action::Line(line));
        }
        if self.break_ends.is_some_and(|end| now >= end) {
            self.break_ends = None;
            self.answer = Some([ESC, b'k']);
            return Some(Action::Line(LineAction::BreakEnd));
        }
        if let Some(frame) = self.to_bus.take() {
            return Some(Action::Bus(frame));
        }
        if let Some(answer) = self.answer.take() {
            self.answer_buf = answer;
            return Some(Action::Reply(&self.answer_buf));
        }
        if self.to_plc_len > 0 {
            let n = core::mem::take(&mut self.to_plc_len);
            return self.to_plc.get(..n).map(Action::Reply);
        }
        None
    }

    fn poll_at(&self) -> Option<Instant> {
        let partial = (self.frame_len > 0).then(|| self.frame_started + PARTIAL_FRAME_TIMEOUT);
        match (self.break_ends, partial) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    fn outputs(&self) -> PioOutputs {
        if self.stop {
            PioOutputs::SAFE
        } else {
            PioOutputs::from_bits(self.inputs.bits())
        }
    }

    fn indicators(&self) -> (bool, bool) {
        let link = self
            .last_bus_byte
            .is_some_and(|t| self.now.since(t) < LINK_HOLD);
        (link, self.stop)
    }
}
