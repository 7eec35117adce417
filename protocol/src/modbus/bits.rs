//! Coils and discrete inputs as Modbus packs them on the wire: eight to a byte, the first bit
//! in bit 0 of the first byte (Application Protocol §6.1, §6.11). A request's bits are handed
//! to the [`DataModel`](super::DataModel) as they arrived, and a read fills the reply's bytes,
//! so no bit ever takes a byte of its own.

/// Bits to read from (a write request's values).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Bits<'a> {
    bytes: &'a [u8],
    len: usize,
}

impl<'a> Bits<'a> {
    /// The first `len` bits of `bytes`, if there are that many.
    pub fn new(bytes: &'a [u8], len: usize) -> Option<Bits<'a>> {
        (len <= bytes.len().saturating_mul(8)).then_some(Bits { bytes, len })
    }

    /// How many bits.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bit `i`, if there is one.
    pub fn get(&self, i: usize) -> Option<bool> {
        if i >= self.len {
            return None;
        }
        self.bytes.get(i / 8).map(|byte| byte >> (i % 8) & 1 != 0)
    }

    /// The bits, first first.
    pub fn iter(&self) -> impl Iterator<Item = bool> + Clone + 'a {
        let bits = *self;
        (0..bits.len).map(move |i| bits.get(i).unwrap_or(false))
    }
}

/// Bits to fill (a read request's answer), all 0 to begin with.
#[derive(Debug, PartialEq, Eq)]
pub struct BitsMut<'a> {
    bytes: &'a mut [u8],
    len: usize,
}

impl<'a> BitsMut<'a> {
    /// The first `len` bits of `bytes`, cleared (the bytes' unused high bits too), if there
    /// are that many.
    pub fn new(bytes: &'a mut [u8], len: usize) -> Option<BitsMut<'a>> {
        let bytes = bytes.get_mut(..len.div_ceil(8))?;
        bytes.fill(0);
        Some(BitsMut { bytes, len })
    }

    /// How many bits.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Set bit `i` (ignored past the end).
    pub fn set(&mut self, i: usize, on: bool) {
        if i >= self.len {
            return;
        }
        if let Some(byte) = self.bytes.get_mut(i / 8) {
            let mask = 1 << (i % 8);
            if on {
                *byte |= mask;
            } else {
                *byte &= !mask;
            }
        }
    }

    /// The bits read back.
    pub fn as_bits(&self) -> Bits<'_> {
        Bits {
            bytes: self.bytes,
            len: self.len,
        }
    }
}
