//! 64-bit division by a 32-bit divisor, without the compiler's 64-bit division routine.
//!
//! The Cortex-M3/M4's divide instruction (UDIV) takes 32 bits. A `u64` division in Rust calls
//! compiler-builtins' `__aeabi_uldivmod`, whose code is about 1 KB of the F103's flash
//! (`scripts/size-report.sh`), for the gateway's few 64-bit divisions: the unit conversions
//! ([`units`](crate::units)), whose products of a position and a lead pass 32 bits only for
//! positions beyond about 40 m; the engine's arrival estimate and position-read period; and the
//! uptime and watchdog registers, counted in µs. So they come here: one UDIV when the dividend
//! fits in 32 bits, a bit-at-a-time long division (at most 64 short steps) when it does not.

use core::num::NonZeroU32;

/// `n / d` and `n % d`. No panic path: `d` is not zero, and the remainder is below `d`.
pub(crate) fn div_rem(n: u64, d: NonZeroU32) -> (u64, u32) {
    if let Ok(small) = u32::try_from(n) {
        return (u64::from(small / d), small % d);
    }
    let divisor = u64::from(d.get());
    let (mut quotient, mut remainder) = (0u64, 0u64);
    // From the highest set bit of `n` down: the remainder stays below the divisor, so below 2^32,
    // and its shift never overflows.
    for bit in (0..u64::BITS - n.leading_zeros()).rev() {
        remainder = remainder << 1 | (n >> bit) & 1;
        quotient <<= 1;
        if remainder >= divisor {
            remainder -= divisor;
            quotient |= 1;
        }
    }
    (quotient, u32::try_from(remainder).unwrap_or(0))
}

/// A divisor from a number: a zero becomes 1 (never a panic), as a setting of 0 "per cycle"
/// means once.
pub(crate) const fn divisor(d: u32) -> NonZeroU32 {
    match NonZeroU32::new(d) {
        Some(d) => d,
        None => NonZeroU32::MIN,
    }
}

/// `n / d`; see [`div_rem`].
pub(crate) fn div(n: u64, d: NonZeroU32) -> u64 {
    div_rem(n, d).0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(n: u64, d: u32) {
        let Some(nz) = NonZeroU32::new(d) else { return };
        assert_eq!(
            div_rem(n, nz),
            (n / u64::from(d), (n % u64::from(d)) as u32),
            "{n} / {d}"
        );
    }

    #[test]
    fn matches_the_native_division_at_the_edges() {
        let ns = [
            0,
            1,
            u64::from(u32::MAX) - 1,
            u64::from(u32::MAX),
            u64::from(u32::MAX) + 1,
            1 << 40,
            (1 << 46) - 1,
            u64::MAX - 1,
            u64::MAX,
        ];
        let ds = [
            1,
            2,
            3,
            300,
            800,
            65_535,
            65_536,
            588_399,
            1_000_000,
            u32::MAX - 1,
            u32::MAX,
        ];
        for n in ns {
            for d in ds {
                check(n, d);
            }
        }
    }

    #[test]
    fn matches_the_native_division_on_random_operands() {
        let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
        for _ in 0..200_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            // Dividends of every length, divisors of every length.
            let n = x >> (x % 64);
            let d = (x.rotate_left(29) as u32) >> ((x >> 8) % 32);
            check(n, d);
        }
    }
}
