//! Bytes in, frames out: the receive side of the line.
//!
//! Every frame starts with STX (0x02), and STX never occurs inside a valid frame (data and BCC
//! are printable ASCII). So an STX always starts a new candidate: whatever was collected is
//! abandoned (reported as [`Error::Truncated`]), and the frame that follows a half frame, a
//! glitch or noise is never lost. Bytes outside a candidate are counted as noise. The 16th byte
//! of a candidate closes it: it is a [`Packet`] if it passes [`Frame::new_checked`] (or is the
//! communication-change broadcast), else an error. Memory is one frame.
//!
//! With a transceiver whose receiver is always on, the gateway hears its own transmission.
//! [`Deframer::expect_echo`] makes the deframer swallow exactly that echo; if the line carries
//! something else (the echo was lost, or collided with another talker), the echo is abandoned,
//! counted, and the bytes are deframed normally so that a real reply is not lost.

use crate::error::Error;
use crate::frame::{Frame, Packet, COMM_CHANGE, FRAME_LEN, STX};

/// What the deframer has counted since it was made (wrapping counters).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DeframerCounters {
    /// Packets delivered.
    pub packets: u32,
    /// Candidates rejected (bad BCC, missing ETX, truncated, ...).
    pub errors: u32,
    /// Bytes outside any candidate (line noise, garbage before STX).
    pub noise_bytes: u32,
    /// Own transmissions swallowed whole.
    pub echoes: u32,
    /// Own transmissions that did not come back as sent (lost echo or a collision).
    pub echo_mismatches: u32,
}

#[derive(Clone, Copy, Debug)]
struct Echo {
    bytes: [u8; FRAME_LEN],
    matched: usize,
}

/// Turns received bytes into packets; see the [module documentation](self).
#[derive(Clone, Debug)]
pub struct Deframer {
    buf: [u8; FRAME_LEN],
    len: usize,
    rejected: [u8; FRAME_LEN],
    rejected_len: usize,
    echo: Option<Echo>,
    counters: DeframerCounters,
}

impl Default for Deframer {
    fn default() -> Self {
        Deframer::new()
    }
}

impl Deframer {
    /// An idle deframer.
    pub const fn new() -> Deframer {
        Deframer {
            buf: [0; FRAME_LEN],
            len: 0,
            rejected: [0; FRAME_LEN],
            rejected_len: 0,
            echo: None,
            counters: DeframerCounters {
                packets: 0,
                errors: 0,
                noise_bytes: 0,
                echoes: 0,
                echo_mismatches: 0,
            },
        }
    }

    /// Feed one received byte.
    ///
    /// `Ok` when it completes a packet; `Err(WouldBlock)` while more bytes are needed;
    /// `Err(Other(e))` when it ends a candidate that is not a valid packet (the bytes are then in
    /// [`rejected`](Self::rejected)). Never panics, whatever the bytes.
    pub fn push(&mut self, byte: u8) -> nb::Result<Packet, Error> {
        if let Some(echo) = self.echo.as_mut() {
            if echo.bytes.get(echo.matched) == Some(&byte) {
                echo.matched += 1;
                if echo.matched == FRAME_LEN {
                    self.echo = None;
                    self.counters.echoes = self.counters.echoes.wrapping_add(1);
                }
                return Err(nb::Error::WouldBlock);
            }
            if echo.matched == 0 && byte != STX {
                // Noise before the echo started: keep waiting for it.
                self.counters.noise_bytes = self.counters.noise_bytes.wrapping_add(1);
                return Err(nb::Error::WouldBlock);
            }
            let echo = *echo;
            self.echo = None;
            self.counters.echo_mismatches = self.counters.echo_mismatches.wrapping_add(1);
            if byte != STX {
                // What matched so far may have been the start of a real frame: keep it.
                self.buf = echo.bytes;
                self.len = echo.matched;
            }
        }
        self.receive(byte)
    }

    fn receive(&mut self, byte: u8) -> nb::Result<Packet, Error> {
        if byte == STX {
            let abandoned = self.len;
            if abandoned > 0 {
                self.reject(abandoned);
            }
            // Only the first `len` bytes count: what the last candidate left after them is
            // overwritten before it is read.
            self.buf[0] = STX;
            self.len = 1;
            return match u8::try_from(abandoned) {
                Ok(0) => Err(nb::Error::WouldBlock),
                Ok(len) => Err(nb::Error::Other(Error::Truncated { len })),
                Err(_) => Err(nb::Error::Other(Error::Truncated { len: u8::MAX })),
            };
        }
        let Some(slot) = self.buf.get_mut(self.len).filter(|_| self.len > 0) else {
            self.counters.noise_bytes = self.counters.noise_bytes.wrapping_add(1);
            return Err(nb::Error::WouldBlock);
        };
        *slot = byte;
        self.len += 1;
        if self.len < FRAME_LEN {
            return Err(nb::Error::WouldBlock);
        }
        self.len = 0;
        if self.buf == COMM_CHANGE {
            self.counters.packets = self.counters.packets.wrapping_add(1);
            return Ok(Packet::CommChange);
        }
        match Frame::new_checked(&self.buf) {
            Ok(frame) => {
                self.counters.packets = self.counters.packets.wrapping_add(1);
                Ok(Packet::Frame(frame))
            }
            Err(e) => {
                self.reject(FRAME_LEN);
                Err(nb::Error::Other(e))
            }
        }
    }

    fn reject(&mut self, len: usize) {
        self.rejected = self.buf;
        self.rejected_len = len.min(FRAME_LEN);
        self.counters.errors = self.counters.errors.wrapping_add(1);
    }

    /// The bytes of the last rejected candidate, for diagnostics (a bus analyser prints them).
    pub fn rejected(&self) -> &[u8] {
        self.rejected.get(..self.rejected_len).unwrap_or(&[])
    }

    /// The bytes of the candidate being collected (empty between frames): what a capture that
    /// ends mid-frame leaves behind.
    pub fn pending(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }

    /// Swallow the echo of `sent`, which the gateway is about to transmit (see the
    /// [module documentation](self)). Any partial candidate is dropped as noise.
    pub fn expect_echo(&mut self, sent: &[u8; FRAME_LEN]) {
        self.drop_partial();
        self.echo = Some(Echo {
            bytes: *sent,
            matched: 0,
        });
    }

    /// How many more bytes complete what has started: the echo being swallowed, or the
    /// candidate being collected; 0 between frames. A receiver may leave that many character
    /// times' worth of bytes in its UART buffer and take them in one go
    /// ([`Engine::frame_due`](crate::engine::Engine::frame_due)).
    pub fn missing(&self) -> usize {
        match self.echo {
            Some(echo) if echo.matched > 0 => FRAME_LEN.saturating_sub(echo.matched),
            _ if self.len > 0 => FRAME_LEN.saturating_sub(self.len),
            _ => 0,
        }
    }

    /// Whether an expected echo has not come back whole yet.
    pub fn echo_pending(&self) -> bool {
        self.echo.is_some()
    }

    /// Forget any partial candidate and pending echo (e.g. after a break or a baud change).
    ///
    /// Not inlined: the engine resets at five places, none of them per byte or per frame.
    #[inline(never)]
    pub fn reset(&mut self) {
        self.drop_partial();
        self.echo = None;
    }

    fn drop_partial(&mut self) {
        let dropped = u32::try_from(self.len).unwrap_or(u32::MAX);
        self.counters.noise_bytes = self.counters.noise_bytes.wrapping_add(dropped);
        self.len = 0;
    }

    /// What has been counted so far.
    pub fn counters(&self) -> DeframerCounters {
        self.counters
    }
}
