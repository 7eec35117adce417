//! The bus timing rules of the complete edition §2 and §5, as formulas in one place.

use crate::frame::FRAME_LEN;
use crate::line::Baud;
use crate::time::Duration;
use crate::Rtim;

/// Bits on the wire per character: start, 8 data, stop (8N1, complete edition §1).
pub const BITS_PER_CHAR: u64 = 10;

/// Time to send one character at `baud`, rounded up to a whole microsecond.
pub const fn char_time(baud: Baud) -> Duration {
    let bps = baud.bits_per_second() as u64;
    Duration((BITS_PER_CHAR * 1_000_000).div_ceil(bps))
}

/// Time to send one 16-character frame at `baud`, rounded up.
pub const fn frame_time(baud: Baud) -> Duration {
    let bps = baud.bits_per_second() as u64;
    Duration((FRAME_LEN as u64 * BITS_PER_CHAR * 1_000_000).div_ceil(bps))
}

/// The response time-out Trt, from the end of the command to the end of the response
/// (complete edition §5 (1)): 20 + alpha + 160/Kbr ms, or 200 + alpha + 160/Kbr ms for V5,
/// where alpha is the axis' RTIM and 160/Kbr is the response's own transmission time.
pub const fn response_timeout(baud: Baud, rtim: Rtim, is_v5: bool) -> Duration {
    let base_ms: u64 = if is_v5 { 200 } else { 20 };
    Duration::from_millis(base_ms + rtim.get() as u64).plus(frame_time(baud))
}

/// The host's minimum gap after a response before its next command (§2 (2)).
pub const HOST_GAP: Duration = Duration::from_millis(crate::line::HOST_GAP_MS as u64);

/// The shortest possible transaction on a healthy bus: command, RTIM, response, host gap.
/// Sixteen of these are the wire limit of a 16-axis status cycle.
pub const fn transaction_time(baud: Baud, rtim: Rtim) -> Duration {
    frame_time(baud)
        .plus(frame_time(baud))
        .plus(Duration::from_millis(rtim.get() as u64))
        .plus(HOST_GAP)
}
