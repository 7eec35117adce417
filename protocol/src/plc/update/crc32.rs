//! The CRC-32 an image is checked with, end to end: the tool computes it over the file, the
//! gateway over what it wrote.

/// CRC-32 (IEEE 802.3: polynomial 0x04C11DB7 reflected, initial value and final XOR all ones),
/// computed a byte at a time over a 16-entry table, as [`crc`](crate::modbus::crc) does CRC-16.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Crc32(u32);

/// The reflected polynomial.
const POLY32: u32 = 0xEDB8_8320;

const NIBBLE32: [u32; 16] = crate::modbus::crc::nibble_table(POLY32);

impl Crc32 {
    /// Nothing yet.
    pub const fn new() -> Crc32 {
        Crc32(0xFFFF_FFFF)
    }

    /// `bytes` next.
    pub fn update(&mut self, bytes: &[u8]) {
        let step = |crc: u32| {
            let i = usize::from((crc & 0xF) as u8);
            (crc >> 4) ^ NIBBLE32.get(i).copied().unwrap_or(0)
        };
        for &byte in bytes {
            self.0 = step(step(self.0 ^ u32::from(byte)));
        }
    }

    /// The CRC-32 of the bytes so far.
    pub fn finish(&self) -> u32 {
        !self.0
    }
}

impl Default for Crc32 {
    fn default() -> Self {
        Crc32::new()
    }
}

/// The CRC-32 of `bytes` (`crc32("123456789")` is 0xCBF43926).
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = Crc32::new();
    crc.update(bytes);
    crc.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32_is_the_common_one() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), 0);
        let mut split = Crc32::new();
        split.update(b"1234");
        split.update(b"56789");
        assert_eq!(split.finish(), 0xCBF4_3926);
    }
}
