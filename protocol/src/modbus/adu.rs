//! The RTU frame, or ADU (Serial Line §2.1, §2.5.1): unit id (1 byte), PDU (function code +
//! data, at most 253 bytes, Application Protocol §4.1), CRC (2 bytes, low byte first). So a frame
//! is 4 to 256 bytes.

use core::fmt;

use super::crc;

/// The longest RTU frame (Serial Line §2.5.1: 1 + 253 + 2 bytes).
pub const MAX_ADU_LEN: usize = 256;

/// The longest PDU (Application Protocol §4.1).
pub const MAX_PDU_LEN: usize = 253;

/// The shortest frame: unit id, function code, CRC.
const MIN_ADU_LEN: usize = 4;

/// Why a burst of bytes is not a frame. Such bursts are discarded and never answered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// Fewer than 4 bytes.
    TooShort,
    /// More than [`MAX_ADU_LEN`] bytes before a t3.5 silence.
    TooLong,
    /// The CRC does not match.
    Crc,
    /// A silence longer than t1.5 but shorter than t3.5 between two characters
    /// (Serial Line §2.5.1.1: the frame is incomplete and discarded).
    BadGap,
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            FrameError::TooShort => "Modbus frame shorter than 4 bytes",
            FrameError::TooLong => "Modbus frame longer than 256 bytes",
            FrameError::Crc => "Modbus frame with a bad CRC",
            FrameError::BadGap => "Modbus frame broken by a silence longer than t1.5",
        })
    }
}

/// A received frame whose length and CRC are valid; a view of the bytes (smoltcp style).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Adu<'a> {
    bytes: &'a [u8],
}

impl<'a> Adu<'a> {
    /// Checks the length (4..=256) and the CRC of a whole frame.
    pub fn new_checked(bytes: &'a [u8]) -> Result<Adu<'a>, FrameError> {
        if bytes.len() < MIN_ADU_LEN {
            Err(FrameError::TooShort)
        } else if bytes.len() > MAX_ADU_LEN {
            Err(FrameError::TooLong)
        } else if !crc::is_valid(bytes) {
            Err(FrameError::Crc)
        } else {
            Ok(Adu { bytes })
        }
    }

    /// The unit id (slave address): 0 broadcast, 1..=247 slaves, 248..=255 reserved
    /// (Serial Line §2.2).
    pub fn unit(&self) -> u8 {
        self.bytes.first().copied().unwrap_or(0)
    }

    /// The function code (first PDU byte).
    pub fn function(&self) -> u8 {
        self.pdu().first().copied().unwrap_or(0)
    }

    /// The PDU: function code and data, without unit id and CRC (1..=253 bytes).
    pub fn pdu(&self) -> &'a [u8] {
        let end = self.bytes.len().saturating_sub(2);
        self.bytes.get(1..end).unwrap_or(&[])
    }

    /// The whole frame, CRC included.
    pub fn as_bytes(&self) -> &'a [u8] {
        self.bytes
    }
}

/// How a frame wraps its PDU: the serial line's unit id and CRC, or TCP's MBAP header
/// (Messaging on TCP/IP Implementation Guide V1.0b, §3.1.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Framing {
    /// Unit id, PDU, CRC (Serial Line §2.5.1).
    Rtu,
    /// MBAP header (transaction id, protocol id 0, length, unit id), PDU. A reply echoes the
    /// request's transaction id and unit id byte for byte (feature `tcp`).
    #[cfg(feature = "tcp")]
    Tcp {
        /// The request's transaction id.
        transaction: u16,
        /// The request's unit id, as it came (0xFF and 0 included).
        unit: u8,
    },
}

/// Writes a frame into a byte slice, never past its end. A field that does not fit spoils the
/// frame (nothing more is written) and [`finish`](Writer::finish) says `None`: one check at the
/// end.
// Rather than one after every field, which took flash at each of the many fields written.
pub(crate) struct Writer<'a> {
    buf: &'a mut [u8],
    /// Bytes written; past `buf`'s end once the frame is spoilt.
    len: usize,
    framing: Framing,
}

/// Where an MBAP header's length field is, and the bytes before the unit id it counts from.
#[cfg(feature = "tcp")]
pub(crate) const MBAP_LENGTH_AT: usize = 4;
/// See [`MBAP_LENGTH_AT`].
#[cfg(feature = "tcp")]
pub(crate) const MBAP_UNCOUNTED: usize = 6;

impl<'a> Writer<'a> {
    /// An empty serial-line frame in `buf` (the caller writes the unit id).
    pub(crate) fn new(buf: &'a mut [u8]) -> Writer<'a> {
        Writer {
            buf,
            len: 0,
            framing: Framing::Rtu,
        }
    }

    /// A frame in `buf` for `unit`, its header written: the unit id (RTU), or the MBAP header
    /// with the request's own unit id (TCP).
    pub(crate) fn frame(buf: &'a mut [u8], framing: Framing, unit: u8) -> Writer<'a> {
        let mut w = Writer {
            buf,
            len: 0,
            framing,
        };
        match framing {
            Framing::Rtu => w.byte(unit),
            #[cfg(feature = "tcp")]
            Framing::Tcp { transaction, unit } => {
                w.u16(transaction);
                w.u16(0);
                w.u16(0); // the length, known at `finish`
                w.byte(unit);
            }
        }
        w
    }

    /// Appends one byte.
    pub(crate) fn byte(&mut self, byte: u8) {
        self.bytes(&[byte]);
    }

    /// Appends a big-endian 16-bit value (Application Protocol §4.2).
    pub(crate) fn u16(&mut self, value: u16) {
        self.bytes(&value.to_be_bytes());
    }

    /// Appends a length or count as one byte; one above 255 spoils the frame.
    pub(crate) fn len8(&mut self, len: usize) {
        match u8::try_from(len) {
            Ok(byte) => self.byte(byte),
            Err(_) => self.spoil(),
        }
    }

    /// Appends a length or count as a big-endian 16-bit value; one above 65535 spoils the frame.
    pub(crate) fn len16(&mut self, len: usize) {
        match u16::try_from(len) {
            Ok(value) => self.u16(value),
            Err(_) => self.spoil(),
        }
    }

    /// Appends bytes, or spoils the frame if they do not fit.
    pub(crate) fn bytes(&mut self, bytes: &[u8]) {
        let end = self.len.saturating_add(bytes.len());
        match self.buf.get_mut(self.len..end) {
            Some(slot) => {
                slot.copy_from_slice(bytes);
                self.len = end;
            }
            None => self.spoil(),
        }
    }

    /// Nothing more is written, and [`finish`](Writer::finish) says `None`.
    fn spoil(&mut self) {
        self.len = usize::MAX;
    }

    /// Ends the frame (RTU: appends the CRC of everything written; TCP: fills in the MBAP
    /// length) and returns its length; `None` if the frame is spoilt or does not fit.
    pub(crate) fn finish(mut self) -> Option<usize> {
        match self.framing {
            Framing::Rtu => {
                let crc = crc::checksum(self.buf.get(..self.len)?);
                self.bytes(&crc::to_wire(crc));
            }
            #[cfg(feature = "tcp")]
            Framing::Tcp { .. } => {
                let counted = u16::try_from(self.len.checked_sub(MBAP_UNCOUNTED)?).ok()?;
                self.buf
                    .get_mut(MBAP_LENGTH_AT..MBAP_UNCOUNTED)?
                    .copy_from_slice(&counted.to_be_bytes());
            }
        }
        (self.len != usize::MAX).then_some(self.len)
    }
}
