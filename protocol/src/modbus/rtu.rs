//! Where RTU frames end: silence on the line (Serial Line §2.5.1.1).
//!
//! A frame is the bytes between two silences of at least **t3.5** (3.5 character times). A
//! character is 11 bits in RTU mode (start, 8 data, parity or a second stop bit, stop; Serial
//! Line §2.5.1). Above 19200 baud the timers are fixed: t1.5 = 750 µs and t3.5 = 1750 µs.
//!
//! The [`Receiver`] never reads a clock: the caller stamps each byte with [`Receiver::push`] and
//! calls [`Receiver::poll`] at [`Receiver::next_deadline`] (or any later time) to collect the
//! frame once the line has been quiet for t3.5.
//!
//! A caller that reads a UART's buffer from a task cannot always stamp a byte with the time it
//! came: bytes that arrived while the task did something else (sent a bus frame, 16.7 ms at
//! 9.6 kbit/s) wait in the buffer and are read together afterwards. Stamped with the time they
//! are read, they look like a frame of their own after a silence that was never on the line, and
//! a request read half before and half after is cut in two (a CRC error and no reply, although
//! the PLC sent it whole). [`Receiver::push_between`] takes such a byte with the span it arrived
//! in: a silence ends a frame only as far as it is certain.
//!
//! Inside a frame, a silence longer than **t1.5** but shorter than t3.5 makes the frame
//! incomplete (Serial Line §2.5.1.1, "control and waiting" state): every byte up to the next
//! t3.5 silence is discarded and the burst is reported as [`FrameError::BadGap`]. This check
//! needs byte timestamps accurate to a few hundred µs (stamp bytes in the receive interrupt or
//! DMA half/idle event, not when a task gets round to reading them); if they are not, turn it off
//! with [`Receiver::without_gap_check`] — the CRC still rejects a garbled frame. Many masters and
//! slaves (FreeModbus, libmodbus) do not check t1.5 at all.
//!
//! A burst longer than 256 bytes is discarded as it arrives (nothing beyond 256 bytes is kept)
//! and reported once, as [`FrameError::TooLong`], when it ends. Frames are never lost to a
//! panic or an overflow; a complete frame not polled before the next byte arrives is dropped and
//! counted in [`ReceiverCounters::overruns`].

use super::adu::{Adu, FrameError, MAX_ADU_LEN};
use crate::time::{Duration, Instant};

/// Bits per character in RTU mode (Serial Line §2.5.1).
pub const BITS_PER_CHAR: u64 = 11;

/// Above this baud rate, t1.5 and t3.5 are fixed (Serial Line §2.5.1.1).
const FIXED_TIMERS_ABOVE: u32 = 19_200;

/// `chars` tenths of a character time at `baud_bps`, rounded up to a microsecond.
// In 32 bits, as `chars_time`: 35 x 11 x 10^6 < 2^32 (and 10 x 4.29 Gbit/s is no rate).
const fn tenths_of_char(tenths: u32, baud_bps: u32) -> Duration {
    let bps = if baud_bps == 0 {
        1
    } else {
        baud_bps.saturating_mul(10)
    };
    Duration::from_micros((tenths * BITS_PER_CHAR as u32 * 1_000_000).div_ceil(bps) as u64)
}

/// How long `len` characters take on the line at `baud_bps` (11 bits each), rounded up to a
/// microsecond; a frame is at most [`MAX_ADU_LEN`] characters (longer counts as that many).
///
/// ```
/// use protocol::modbus::chars_time;
/// assert_eq!(chars_time(255, 1_200).as_micros(), 2_337_500); // a 125-register reply
/// assert_eq!(chars_time(8, 115_200).as_micros(), 764);
/// ```
// In 32 bits: 256 x 11 x 10^6 < 2^32, and a 64-bit division would pull a kilobyte of
// compiler builtins into the F103's firmware.
pub const fn chars_time(len: usize, baud_bps: u32) -> Duration {
    let len = if len > MAX_ADU_LEN { MAX_ADU_LEN } else { len } as u32;
    let bps = if baud_bps == 0 { 1 } else { baud_bps };
    Duration::from_micros((len * BITS_PER_CHAR as u32 * 1_000_000).div_ceil(bps) as u64)
}

/// The end-of-frame silence t3.5 (Serial Line §2.5.1.1): 3.5 character times of 11 bits,
/// rounded up to a microsecond, or 1750 µs above 19200 baud.
///
/// ```
/// use protocol::modbus::t3_5;
/// assert_eq!(t3_5(9_600).as_micros(), 4_011); // 38.5 bits / 9600 bps = 4010.4 µs
/// assert_eq!(t3_5(19_200).as_micros(), 2_006);
/// assert_eq!(t3_5(38_400).as_micros(), 1_750);
/// ```
pub const fn t3_5(baud_bps: u32) -> Duration {
    if baud_bps > FIXED_TIMERS_ABOVE {
        Duration::from_micros(1_750)
    } else {
        tenths_of_char(35, baud_bps)
    }
}

/// The inter-character time-out t1.5 (Serial Line §2.5.1.1): 1.5 character times of 11 bits,
/// rounded up to a microsecond, or 750 µs above 19200 baud.
pub const fn t1_5(baud_bps: u32) -> Duration {
    if baud_bps > FIXED_TIMERS_ABOVE {
        Duration::from_micros(750)
    } else {
        tenths_of_char(15, baud_bps)
    }
}

/// What the receiver has seen (wrapping counters).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ReceiverCounters {
    /// Frames with a good length and CRC.
    pub frames: u32,
    /// Bursts of 1 to 3 bytes.
    pub too_short: u32,
    /// Bursts longer than 256 bytes.
    pub too_long: u32,
    /// Bursts with a bad CRC.
    pub crc_errors: u32,
    /// Bursts broken by a silence between t1.5 and t3.5.
    pub bad_gaps: u32,
    /// Bursts (good or bad) that ended but were not polled before the next byte came.
    pub overruns: u32,
}

/// The state of the current burst of bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Burst {
    /// The line has been quiet for t3.5 (or nothing was ever received).
    Idle,
    /// Collecting a frame.
    Receiving,
    /// More than 256 bytes: discarding until silence.
    TooLong,
    /// A t1.5 gap was seen: discarding until silence.
    BadGap,
}

/// Collects bytes into frames; see the [module documentation](self).
#[derive(Clone, Debug)]
pub struct Receiver {
    buf: [u8; MAX_ADU_LEN],
    len: usize,
    burst: Burst,
    last_byte: Instant,
    t1_5: Option<Duration>,
    t3_5: Duration,
    counters: ReceiverCounters,
}

impl Receiver {
    /// A receiver for `baud_bps`, with the t1.5 gap check on, assuming an idle line.
    pub const fn new(baud_bps: u32) -> Receiver {
        Receiver::with_timing(Some(t1_5(baud_bps)), t3_5(baud_bps))
    }

    /// A receiver with explicit timers; `t1_5: None` turns the gap check off.
    pub const fn with_timing(t1_5: Option<Duration>, t3_5: Duration) -> Receiver {
        Receiver {
            buf: [0; MAX_ADU_LEN],
            len: 0,
            burst: Burst::Idle,
            last_byte: Instant(0),
            t1_5,
            t3_5,
            counters: ReceiverCounters {
                frames: 0,
                too_short: 0,
                too_long: 0,
                crc_errors: 0,
                bad_gaps: 0,
                overruns: 0,
            },
        }
    }

    /// The same receiver without the t1.5 gap check (for byte timestamps with jitter).
    pub const fn without_gap_check(mut self) -> Receiver {
        self.t1_5 = None;
        self
    }

    /// A new end-of-frame silence (the line's rate has changed): the burst in progress, heard
    /// at the old rate, is dropped; the counters go on. (In place: a receiver is a 256-byte
    /// buffer, which a new one would copy.)
    pub fn set_frame_end(&mut self, t3_5: Duration) {
        self.t3_5 = t3_5;
        self.reset();
    }

    /// The end-of-frame silence in use.
    pub const fn t3_5(&self) -> Duration {
        self.t3_5
    }

    /// The inter-character time-out in use, if the gap check is on.
    pub const fn t1_5(&self) -> Option<Duration> {
        self.t1_5
    }

    /// A byte received at `now`.
    pub fn push(&mut self, now: Instant, byte: u8) {
        self.push_between(now, now, &[byte]);
    }

    /// Bytes that arrived after `since` and by `now` (`since`: when the caller last found the
    /// line without them; see the [module documentation](self)), one after the other. The
    /// silence before them counts from `since`, the frame's end from `now`.
    pub fn push_between(&mut self, since: Instant, now: Instant, bytes: &[u8]) {
        if bytes.is_empty() {
            return;
        }
        if self.burst != Burst::Idle {
            let gap = since.since(self.last_byte);
            if gap >= self.t3_5 {
                // The previous burst ended and the caller did not poll it: it is lost.
                let _ = self.finish();
                self.counters.overruns = self.counters.overruns.wrapping_add(1);
            } else if self.burst == Burst::Receiving && self.t1_5.is_some_and(|t1_5| gap > t1_5) {
                self.burst = Burst::BadGap;
                self.len = 0;
            }
        }
        if self.burst == Burst::Idle {
            self.burst = Burst::Receiving;
            self.len = 0;
        }
        self.last_byte = now;
        for &byte in bytes {
            if self.burst == Burst::Receiving {
                if let Some(slot) = self.buf.get_mut(self.len) {
                    *slot = byte;
                    self.len += 1;
                } else {
                    self.burst = Burst::TooLong;
                    self.len = 0;
                }
            }
        }
    }

    /// The frame that ended with a t3.5 silence before `now`, or why that burst is not one;
    /// `None` while the line is idle or the silence is shorter than t3.5.
    pub fn poll(&mut self, now: Instant) -> Option<Result<Adu<'_>, FrameError>> {
        if self.burst == Burst::Idle || now.since(self.last_byte) < self.t3_5 {
            return None;
        }
        Some(self.finish())
    }

    /// When [`poll`](Self::poll) will next have something: t3.5 after the last byte of a burst;
    /// `None` while idle.
    pub fn next_deadline(&self) -> Option<Instant> {
        match self.burst {
            Burst::Idle => None,
            _ => Some(self.last_byte + self.t3_5),
        }
    }

    /// Whether a burst is in progress (the line is not known to be quiet for t3.5).
    pub fn is_busy(&self) -> bool {
        self.burst != Burst::Idle
    }

    /// Drops the burst in progress, if any (e.g. bytes heard while the gateway transmitted).
    pub fn reset(&mut self) {
        self.burst = Burst::Idle;
        self.len = 0;
    }

    /// What has been counted since the receiver was made.
    pub fn counters(&self) -> ReceiverCounters {
        self.counters
    }

    /// Ends the current burst: the frame, or its error (counted either way).
    fn finish(&mut self) -> Result<Adu<'_>, FrameError> {
        let burst = self.burst;
        self.burst = Burst::Idle;
        let result = match burst {
            Burst::TooLong => Err(FrameError::TooLong),
            Burst::BadGap => Err(FrameError::BadGap),
            Burst::Idle | Burst::Receiving => {
                Adu::new_checked(self.buf.get(..self.len).unwrap_or(&[]))
            }
        };
        let counter = match result {
            Ok(_) => &mut self.counters.frames,
            Err(FrameError::TooShort) => &mut self.counters.too_short,
            Err(FrameError::TooLong) => &mut self.counters.too_long,
            Err(FrameError::Crc) => &mut self.counters.crc_errors,
            Err(FrameError::BadGap) => &mut self.counters.bad_gaps,
        };
        *counter = counter.wrapping_add(1);
        result
    }
}
