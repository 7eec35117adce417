//! The 16-byte frame: STX, 12 data characters, 2 BCC hex digits, ETX.
//!
//! Brief edition §4-1 and complete edition §3. The BCC is the low byte of the two's complement of
//! the sum of the 12 data characters, written as two upper-case hex digits.
//!
//! The complete edition (§3) calls this the "one's complement", but its own worked example
//! (`1a1234567800` -> `6A`, sum 0x296) is the two's complement, as is the brief edition's rule and
//! every other worked example of both editions. The brief edition's rule is followed here; the
//! tests name the complete edition's wording.

use crate::error::Error;
use crate::hex;

/// Start of a frame.
pub const STX: u8 = 0x02;
/// End of a frame.
pub const ETX: u8 = 0x03;
/// The filler of the communication-change broadcast.
pub const ENQ: u8 = 0x05;
/// Bytes in every frame, commands and responses alike.
pub const FRAME_LEN: usize = 16;
/// Data characters between STX and the BCC.
pub const DATA_LEN: usize = 12;

/// The communication-change broadcast: STX, 14 ENQ, ETX (complete edition §6-1 step 8).
///
/// Every axis takes the BRSL/RTIM values written to its edit area when it receives this; none
/// replies. It carries no BCC and is therefore not a [`Frame`].
pub const COMM_CHANGE: [u8; FRAME_LEN] = [
    STX, ENQ, ENQ, ENQ, ENQ, ENQ, ENQ, ENQ, ENQ, ENQ, ENQ, ENQ, ENQ, ENQ, ENQ, ETX,
];

/// The block check character of 12 data characters.
pub fn bcc(data: &[u8; DATA_LEN]) -> u8 {
    data.iter()
        .fold(0u8, |sum, &byte| sum.wrapping_add(byte))
        .wrapping_neg()
}

/// A frame whose BCC is right: the 12 data characters, with STX, BCC and ETX implied.
///
/// It says nothing yet about whether the data is a valid command or response; see
/// [`Request::parse`](crate::Request::parse) and [`Reply::parse`](crate::Reply::parse).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Frame {
    data: [u8; DATA_LEN],
}

impl Frame {
    /// The frame carrying these 12 data characters; the BCC is computed.
    pub const fn from_data(data: [u8; DATA_LEN]) -> Frame {
        Frame { data }
    }

    /// Check `bytes` as a complete frame: length, STX, ETX, BCC digits, then the BCC itself.
    pub fn new_checked(bytes: &[u8]) -> Result<Frame, Error> {
        let bytes: &[u8; FRAME_LEN] = bytes
            .try_into()
            .map_err(|_| Error::WrongLength { len: bytes.len() })?;
        let [stx, data @ .., hi, lo, etx] = *bytes;
        if stx != STX {
            return Err(Error::MissingStx { found: stx });
        }
        if etx != ETX {
            return Err(Error::MissingEtx { found: etx });
        }
        let received = hex::decode_pair(hi, lo).map_err(|(offset, found)| Error::NonHexDigit {
            index: 13 + offset,
            found,
        })?;
        let expected = bcc(&data);
        if received != expected {
            return Err(Error::BadBcc { expected, received });
        }
        Ok(Frame { data })
    }

    /// The 12 data characters.
    pub const fn data(&self) -> &[u8; DATA_LEN] {
        &self.data
    }

    /// The BCC of this frame.
    pub fn bcc(&self) -> u8 {
        bcc(&self.data)
    }

    /// The 16 bytes to put on the wire.
    pub fn to_bytes(&self) -> [u8; FRAME_LEN] {
        let [d0, d1, d2, d3, d4, d5, d6, d7, d8, d9, d10, d11] = self.data;
        let [hi, lo] = hex::encode_pair(self.bcc());
        [
            STX, d0, d1, d2, d3, d4, d5, d6, d7, d8, d9, d10, d11, hi, lo, ETX,
        ]
    }

    /// The 14 printable characters between STX and ETX (data and BCC), as the vendor documents
    /// write frames (`Chr$(02) + 0n000000000082 + Chr$(03)`).
    pub fn to_text(&self) -> [u8; DATA_LEN + 2] {
        let [d0, d1, d2, d3, d4, d5, d6, d7, d8, d9, d10, d11] = self.data;
        let [hi, lo] = hex::encode_pair(self.bcc());
        [d0, d1, d2, d3, d4, d5, d6, d7, d8, d9, d10, d11, hi, lo]
    }

    /// Parse the 14 characters between STX and ETX, as the documents print frames.
    pub fn from_text(text: &[u8]) -> Result<Frame, Error> {
        let text: &[u8; DATA_LEN + 2] = text.try_into().map_err(|_| Error::WrongLength {
            len: text.len().saturating_add(2),
        })?;
        let [d0, d1, d2, d3, d4, d5, d6, d7, d8, d9, d10, d11, hi, lo] = *text;
        Frame::new_checked(&[
            STX, d0, d1, d2, d3, d4, d5, d6, d7, d8, d9, d10, d11, hi, lo, ETX,
        ])
    }
}

impl core::fmt::Debug for Frame {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let text = self.to_text();
        match core::str::from_utf8(&text) {
            Ok(s) => write!(f, "Frame({s})"),
            Err(_) => write!(f, "Frame({text:02X?})"),
        }
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for Frame {
    fn format(&self, f: defmt::Formatter) {
        defmt::write!(f, "Frame({=[u8]:a})", &self.to_text()[..])
    }
}

/// What arrives on the bus: a frame, or the communication-change broadcast.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Packet {
    /// A frame with a correct BCC.
    Frame(Frame),
    /// STX + 14 ENQ + ETX ([`COMM_CHANGE`]).
    CommChange,
}
