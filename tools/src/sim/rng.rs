//! A small deterministic pseudo-random generator for fault injection: SplitMix64 (Steele, Lea
//! and Flood, "Fast splittable pseudorandom number generators", OOPSLA 2014).
//!
//! Every fault kind draws from its own generator, seeded from the bus seed and a per-kind
//! constant, so that enabling one fault does not change when another one fires: a run is a pure
//! function of the seed, the configuration and the host's actions.

/// SplitMix64: 64 bits of state, full period, passes BigCrush. Not for cryptography.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Rng {
    state: u64,
}

/// The golden-ratio increment of SplitMix64.
const GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;

impl Rng {
    /// A generator seeded with `seed`.
    pub const fn new(seed: u64) -> Rng {
        Rng { state: seed }
    }

    /// An independent generator for one purpose: `seed` mixed with `stream`.
    pub fn derive(seed: u64, stream: u64) -> Rng {
        let mut mixer = Rng::new(seed ^ stream.wrapping_mul(GAMMA).rotate_left(17));
        Rng::new(mixer.next_u64())
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(GAMMA);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// A uniform number in [0, 1) with 53 bits of precision.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// True with probability `p` (clamped to [0, 1]). Always draws, so the stream advances the
    /// same way whatever `p` is.
    pub fn chance(&mut self, p: f64) -> bool {
        let draw = self.unit();
        draw < p
    }

    /// A uniform number in `0..n` (0 when `n` is 0). The modulo bias is below 2^-32 for the
    /// small `n` used here.
    pub fn below(&mut self, n: u64) -> u64 {
        if n == 0 {
            0
        } else {
            self.next_u64() % n
        }
    }

    /// A random byte.
    pub fn byte(&mut self) -> u8 {
        self.next_u64().to_le_bytes()[0]
    }

    /// A random non-zero byte: a bit-flip mask that always changes the byte it is applied to.
    pub fn nonzero_byte(&mut self) -> u8 {
        // 255 non-zero values; `below(255)` is 0..=254.
        let value = self.below(255) + 1;
        u8::try_from(value).unwrap_or(u8::MAX)
    }
}

#[cfg(test)]
mod tests {
    use super::Rng;

    #[test]
    fn splitmix64_reference_values() {
        // First outputs of SplitMix64 seeded with 1234567 (reference implementation by Vigna).
        let mut rng = Rng::new(1_234_567);
        assert_eq!(rng.next_u64(), 6_457_827_717_110_365_317);
        assert_eq!(rng.next_u64(), 3_203_168_211_198_807_973);
    }

    #[test]
    fn masks_are_never_zero() {
        let mut rng = Rng::new(7);
        assert!((0..10_000).all(|_| rng.nonzero_byte() != 0));
    }
}
