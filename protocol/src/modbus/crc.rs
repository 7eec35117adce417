//! CRC-16/MODBUS (Serial Line §2.5.1.2 and Appendix B §6.2.2): polynomial 0xA001 (reflected
//! 0x8005), initial value 0xFFFF, no final XOR. The CRC is the last field of an RTU frame,
//! **low byte first** (the only little-endian field in Modbus).
//!
//! ```
//! use protocol::modbus::crc;
//!
//! assert_eq!(crc::checksum(b"123456789"), 0x4B37);
//! assert_eq!(crc::to_wire(crc::checksum(&[0x01, 0x03, 0x00, 0x00, 0x00, 0x0A])), [0xC5, 0xCD]);
//! ```

/// The reflected polynomial.
const POLY: u16 = 0xA001;

/// The 16-entry table of a reflected CRC with polynomial `poly` (reflected): entry `i` is `i`
/// shifted through 4 bits. CRC-16/MODBUS here and the update's CRC-32 both take theirs from it.
// Evaluated at compile time: an index out of range would be a build error, not a panic.
#[allow(clippy::indexing_slicing)]
pub(crate) const fn nibble_table(poly: u32) -> [u32; 16] {
    let mut table = [0u32; 16];
    let mut i = 0;
    while i < 16 {
        let mut crc = i as u32;
        let mut bit = 0;
        while bit < 4 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ poly
            } else {
                crc >> 1
            };
            bit += 1;
        }
        table[i] = crc;
        i += 1;
    }
    table
}

/// The CRC step of each 4-bit value: half a byte at a time, a 32-byte table instead of the
/// usual 256-entry one, at two look-ups per byte. Modbus frames are short and come at the
/// PLC's pace, so the extra look-up is not measurable.
// The usual table is 512 bytes: 1 % of the F103's flash.
// Evaluated at compile time, narrowed to 16 bits (a 16-bit polynomial keeps every entry there).
#[allow(clippy::indexing_slicing)]
const NIBBLE: [u16; 16] = {
    let wide = nibble_table(POLY as u32);
    let mut table = [0u16; 16];
    let mut i = 0;
    while i < 16 {
        table[i] = wide[i] as u16;
        i += 1;
    }
    table
};

/// `crc` shifted by the 4 bits entering it.
// The index is masked to 0-15 and the table has 16 entries: the look-up cannot miss (and the
// compiler sees that too: no bounds check is emitted).
#[allow(clippy::indexing_slicing)]
const fn nibble(crc: u16) -> u16 {
    (crc >> 4) ^ NIBBLE[(crc & 0x0F) as usize]
}

/// The CRC of `bytes`.
pub const fn checksum(bytes: &[u8]) -> u16 {
    let mut crc = 0xFFFF;
    let mut rest = bytes;
    while let [byte, tail @ ..] = rest {
        crc = nibble(nibble(crc ^ *byte as u16));
        rest = tail;
    }
    crc
}

/// The two CRC bytes as sent: low byte first.
pub const fn to_wire(crc: u16) -> [u8; 2] {
    crc.to_le_bytes()
}

/// Whether `frame` ends with the CRC of what precedes it (false if it is shorter than 2 bytes).
pub fn is_valid(frame: &[u8]) -> bool {
    match frame.len().checked_sub(2).map(|at| frame.split_at(at)) {
        Some((body, crc)) => crc == to_wire(checksum(body)),
        None => false,
    }
}

#[cfg(test)]
mod tests {
    use super::checksum;

    /// Against the `crc` crate's table-driven CRC-16/MODBUS, on every length up to 300 bytes of
    /// a pseudo-random sequence (and the empty input).
    #[test]
    fn checksum_is_crc16_modbus() {
        let reference = ::crc::Crc::<u16>::new(&::crc::CRC_16_MODBUS);
        let mut x = 0x2545_F491_u32;
        let bytes: [u8; 300] = core::array::from_fn(|_| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x as u8
        });
        for n in 0..=bytes.len() {
            assert_eq!(
                checksum(&bytes[..n]),
                reference.checksum(&bytes[..n]),
                "{n} bytes"
            );
        }
    }
}
