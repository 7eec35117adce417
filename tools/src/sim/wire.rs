//! Time on the wire: how long bytes take at a baud rate (complete edition §1: 8 data bits, no
//! parity, 1 stop bit, so 10 bit times per byte with the start bit; §2 defines a break as a
//! continual 0 for more than 10 bit times).
//!
//! Every time in the simulator is a `u64` count of microseconds of virtual time.
//!
//! # Rounding
//! A byte takes 10_000_000 / baud µs, which is not an integer (1041.67 µs at 9600 bit/s). The
//! simulator never adds rounded byte times up: byte `k` of a transmission that starts at `t0`
//! occupies `[t0 + offset(k), t0 + offset(k + 1))` with `offset(k) = ceil(k x 10_000_000 / baud)`,
//! so a 16-byte frame at 9600 bit/s takes exactly 16_667 µs (16.667 ms rounded up once) and the
//! error never exceeds 1 µs per transmission. A byte is received when its stop bit ends, at
//! `t0 + offset(k + 1)`.

use protocol::line::Baud;

/// Bit times per byte on the line: start bit, 8 data bits, stop bit.
pub const BITS_PER_BYTE: u64 = 10;

/// Microseconds in a millisecond.
pub const US_PER_MS: u64 = 1_000;

/// `ms` milliseconds in microseconds.
pub const fn ms(ms: u64) -> u64 {
    ms.saturating_mul(US_PER_MS)
}

/// Start of byte `k` of a transmission, relative to the start of the transmission (µs, rounded
/// up; see the [module documentation](self)).
pub fn byte_offset(k: usize, baud: Baud) -> u64 {
    let bits = u64::try_from(k)
        .unwrap_or(u64::MAX)
        .saturating_mul(BITS_PER_BYTE * 1_000_000);
    bits.div_ceil(u64::from(baud.bits_per_second()))
}

/// How long `len` bytes take on the wire (µs).
pub fn transmit_time(len: usize, baud: Baud) -> u64 {
    byte_offset(len, baud)
}

/// One bit time (µs, rounded up).
pub fn bit_time(baud: Baud) -> u64 {
    1_000_000u64.div_ceil(u64::from(baud.bits_per_second()))
}

/// The shortest low level a receiver at `baud` takes for a break: more than 10 bit times (§2).
pub fn break_threshold(baud: Baud) -> u64 {
    (BITS_PER_BYTE * 1_000_000).div_ceil(u64::from(baud.bits_per_second()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_times() {
        assert_eq!(transmit_time(16, Baud::B9600), 16_667);
        assert_eq!(transmit_time(16, Baud::B115200), 1_389);
        assert_eq!(byte_offset(1, Baud::B9600), 1_042);
        assert_eq!(byte_offset(3, Baud::B9600), 3_125);
    }
}
