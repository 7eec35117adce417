//! Cursor over the 12 data characters: every command and response layout is written and read
//! through these two types, so that position bookkeeping lives in one place and an error always
//! names the index of the offending byte in the 16-byte frame.

use crate::error::Error;
use crate::frame::DATA_LEN;
use crate::hex;

/// Index in the frame of data character 0 (STX comes first).
const FRAME_OFFSET: usize = 1;

/// Reads fields left to right.
pub(crate) struct Reader<'a> {
    data: &'a [u8; DATA_LEN],
    pos: usize,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(data: &'a [u8; DATA_LEN]) -> Self {
        Reader { data, pos: 0 }
    }

    fn frame_index(&self) -> u8 {
        // pos <= DATA_LEN, so this always fits.
        u8::try_from(self.pos + FRAME_OFFSET).unwrap_or(u8::MAX)
    }

    /// The next character.
    pub(crate) fn byte(&mut self) -> Result<u8, Error> {
        let byte = self
            .data
            .get(self.pos)
            .copied()
            .ok_or(Error::WrongLength { len: DATA_LEN })?;
        self.pos += 1;
        Ok(byte)
    }

    /// The next character, without consuming it.
    pub(crate) fn peek(&self) -> Result<u8, Error> {
        self.data
            .get(self.pos)
            .copied()
            .ok_or(Error::WrongLength { len: DATA_LEN })
    }

    /// The next character, which must be `expected`.
    pub(crate) fn literal(&mut self, expected: &[u8]) -> Result<(), Error> {
        for &want in expected {
            let index = self.frame_index();
            let found = self.byte()?;
            if found != want {
                return Err(Error::UnexpectedChar { index, found });
            }
        }
        Ok(())
    }

    /// `n` filler zeros.
    pub(crate) fn zeros(&mut self, n: usize) -> Result<(), Error> {
        for _ in 0..n {
            self.literal(b"0")?;
        }
        Ok(())
    }

    /// A big-endian hex number of `digits` characters (at most 8).
    pub(crate) fn hex(&mut self, digits: usize) -> Result<u32, Error> {
        let mut value = 0u32;
        for _ in 0..digits {
            let index = self.frame_index();
            let found = self.byte()?;
            let nibble = hex::value(found).ok_or(Error::NonHexDigit { index, found })?;
            value = value << 4 | u32::from(nibble);
        }
        Ok(value)
    }

    /// A 2-digit hex byte.
    pub(crate) fn hex_u8(&mut self) -> Result<u8, Error> {
        // Two digits never exceed 0xFF.
        self.hex(2).map(|v| (v & 0xFF) as u8)
    }

    /// A 4-digit hex number.
    pub(crate) fn hex_u16(&mut self) -> Result<u16, Error> {
        self.hex(4).map(|v| (v & 0xFFFF) as u16)
    }
}

/// Writes fields left to right; unwritten characters stay `'0'` (the documents' filler).
///
/// Written in place (`&mut self`): a writer passed by value was copied whole (16 bytes) at
/// every field.
pub(crate) struct Writer {
    data: [u8; DATA_LEN],
    pos: usize,
}

impl Writer {
    pub(crate) fn new() -> Self {
        Writer {
            data: [b'0'; DATA_LEN],
            pos: 0,
        }
    }

    /// One character. Layouts are fixed and tested to fit; a write past the end is ignored.
    // Not inlined: its bounds check at each of its ten uses took 48 B more of the F103's flash.
    #[inline(never)]
    pub(crate) fn byte(&mut self, byte: u8) -> &mut Self {
        if let Some(slot) = self.data.get_mut(self.pos) {
            *slot = byte;
        }
        self.pos += 1;
        self
    }

    /// Several characters.
    pub(crate) fn bytes(&mut self, bytes: &[u8]) -> &mut Self {
        for &b in bytes {
            self.byte(b);
        }
        self
    }

    /// A big-endian hex number of `digits` characters.
    pub(crate) fn hex(&mut self, digits: u32, value: u32) -> &mut Self {
        for i in (0..digits).rev() {
            self.byte(hex::digit(value >> (4 * i)));
        }
        self
    }

    /// The 12 data characters; the rest of the frame is filler.
    pub(crate) fn finish(&self) -> [u8; DATA_LEN] {
        self.data
    }
}
