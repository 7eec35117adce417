//! Upper-case hexadecimal ASCII, the encoding of every numeric field (brief edition §4-1).
//!
//! Decoding accepts only `0`-`9` and `A`-`F`: the documents define upper case, and a lower-case
//! letter in a hex field is more likely a corrupted byte than a host that chose lower case.

/// The ASCII digit of the low nibble of `value`.
pub(crate) const fn digit(value: u32) -> u8 {
    let nibble = (value & 0xF) as u8;
    if nibble < 10 {
        b'0' + nibble
    } else {
        b'A' + nibble - 10
    }
}

/// The value of an upper-case hex digit.
pub(crate) const fn value(digit: u8) -> Option<u8> {
    match digit {
        b'0'..=b'9' => Some(digit - b'0'),
        b'A'..=b'F' => Some(digit - b'A' + 10),
        _ => None,
    }
}

/// Two digits for one byte, high nibble first.
pub(crate) const fn encode_pair(byte: u8) -> [u8; 2] {
    [digit((byte >> 4) as u32), digit(byte as u32)]
}

/// One byte from two digits; on error, the offset (0 or 1) and the offending byte.
pub(crate) const fn decode_pair(hi: u8, lo: u8) -> Result<u8, (u8, u8)> {
    match (value(hi), value(lo)) {
        (Some(h), Some(l)) => Ok(h << 4 | l),
        (None, _) => Err((0, hi)),
        (Some(_), None) => Err((1, lo)),
    }
}
