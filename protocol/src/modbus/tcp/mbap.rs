//! What a Modbus TCP frame is: the MBAP header and a PDU (Messaging on TCP/IP Implementation
//! Guide V1.0b, *TCP Guide* below, §3.1.3), and where frames end in a connection's byte stream.
//!
//! | Bytes | Field |
//! |---|---|
//! | 0-1 | transaction id: echoed in the reply |
//! | 2-3 | protocol id: 0 for Modbus |
//! | 4-5 | length: the bytes that follow (unit id and PDU), 2 to 254 |
//! | 6 | unit id |
//! | 7.. | PDU: function code and data, at most 253 bytes (Application Protocol §4.1) |
//!
//! TCP is a stream: a request may arrive in several segments, or several requests in one. A
//! [`Stream`] collects a connection's bytes and hands out whole frames, one at a time. A frame
//! whose protocol id is not 0 is skipped whole (its length still says where it ends: TCP Guide
//! §4.4.1.2, "the indication is discarded"); a length out of 2..=254 leaves nothing to find the
//! next frame by, so the connection has to be closed.

use crate::modbus::MAX_PDU_LEN;

/// Bytes of the MBAP header, unit id included.
pub const MBAP_LEN: usize = 7;

/// The longest frame: the header and the longest PDU (260 bytes).
pub const MAX_TCP_ADU_LEN: usize = MBAP_LEN + MAX_PDU_LEN;

/// The bytes of a frame the length field does not count (transaction, protocol, length).
const UNCOUNTED: usize = 6;

/// The length field's range: the unit id and a PDU of 1 to 253 bytes.
const LENGTHS: core::ops::RangeInclusive<usize> = 2..=(1 + MAX_PDU_LEN);

/// Why bytes at the front of a stream are not a frame. Every one is counted; none is answered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MbapError {
    /// The protocol id is not 0 (not Modbus): the frame was skipped, the stream goes on.
    Protocol,
    /// The length field is out of 2..=254: where the next frame starts is lost, the
    /// connection must be closed.
    Length,
}

impl core::fmt::Display for MbapError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            MbapError::Protocol => "MBAP protocol id is not 0 (frame skipped)",
            MbapError::Length => "MBAP length out of 2..=254 (connection closed)",
        })
    }
}

/// A whole frame with a Modbus protocol id and a valid length; a view of its bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TcpAdu<'a> {
    bytes: &'a [u8],
}

impl<'a> TcpAdu<'a> {
    /// Checks a whole frame: the protocol id, and a length that counts exactly the bytes after
    /// it (2 to 254 of them).
    pub fn new_checked(bytes: &'a [u8]) -> Result<TcpAdu<'a>, MbapError> {
        let length = frame_len(bytes).ok_or(MbapError::Length)?;
        if length != Ok(bytes.len()) {
            return Err(MbapError::Length);
        }
        if bytes.get(2..4) != Some(&[0, 0]) {
            return Err(MbapError::Protocol);
        }
        Ok(TcpAdu { bytes })
    }

    /// The transaction id.
    pub fn transaction(&self) -> u16 {
        be16(self.bytes, 0)
    }

    /// The unit id: on TCP, 0xFF (or 0) for the device at the IP address itself (TCP Guide
    /// §4.4.2), other values for a unit behind it.
    pub fn unit(&self) -> u8 {
        self.bytes.get(UNCOUNTED).copied().unwrap_or(0)
    }

    /// The PDU: function code and data.
    pub fn pdu(&self) -> &'a [u8] {
        self.bytes.get(MBAP_LEN..).unwrap_or(&[])
    }

    /// The function code (the PDU's first byte).
    pub fn function(&self) -> u8 {
        self.pdu().first().copied().unwrap_or(0)
    }

    /// The whole frame.
    pub fn as_bytes(&self) -> &'a [u8] {
        self.bytes
    }
}

/// A big-endian u16 at `at`, 0 past the end.
fn be16(bytes: &[u8], at: usize) -> u16 {
    match bytes.get(at..at + 2) {
        Some(&[high, low]) => u16::from_be_bytes([high, low]),
        _ => 0,
    }
}

/// The length of the frame at the front of `bytes`: `None` if the header's length field is
/// out of range, `Some(Err(()))` while the header is not all there.
fn frame_len(bytes: &[u8]) -> Option<Result<usize, ()>> {
    if bytes.len() < UNCOUNTED {
        return Some(Err(()));
    }
    let counted = usize::from(be16(bytes, 4));
    LENGTHS
        .contains(&counted)
        .then_some(Ok(UNCOUNTED + counted))
}

/// One connection's receive side: bytes in as they come, whole frames out in order.
///
/// It holds at most one frame ([`MAX_TCP_ADU_LEN`] bytes): [`push`](Stream::push) takes only
/// what fits, and the rest stays with the caller (in the TCP socket, whose window then holds
/// the client back) until the frame in front has been taken with [`take`](Stream::take).
#[derive(Clone, Debug)]
pub struct Stream {
    buf: [u8; MAX_TCP_ADU_LEN],
    len: usize,
    /// Bytes at the front already handed out (dropped at the next call).
    taken: usize,
}

impl Default for Stream {
    fn default() -> Self {
        Stream::new()
    }
}

impl Stream {
    /// An empty stream.
    pub const fn new() -> Stream {
        Stream {
            buf: [0; MAX_TCP_ADU_LEN],
            len: 0,
            taken: 0,
        }
    }

    /// Drops the frame handed out last.
    fn drop_taken(&mut self) {
        if self.taken > 0 {
            self.buf.copy_within(self.taken.min(self.len)..self.len, 0);
            self.len = self.len.saturating_sub(self.taken);
            self.taken = 0;
        }
    }

    /// Appends as many of `bytes` as fit and returns how many that was.
    pub fn push(&mut self, bytes: &[u8]) -> usize {
        self.drop_taken();
        let room = self.buf.get_mut(self.len..).unwrap_or(&mut []);
        let n = room.len().min(bytes.len());
        if let (Some(to), Some(from)) = (room.get_mut(..n), bytes.get(..n)) {
            to.copy_from_slice(from);
        }
        self.len += n;
        n
    }

    /// How many bytes [`push`](Stream::push) would take now.
    pub fn room(&self) -> usize {
        MAX_TCP_ADU_LEN - (self.len - self.taken)
    }

    /// The bytes the front item spans once it is whole: a frame, or everything there for a
    /// length out of range (nothing to find the next frame by); `None` while it is not whole.
    fn front_len(&self) -> Option<usize> {
        let front = self.buf.get(self.taken..self.len)?;
        match frame_len(front) {
            None => Some(front.len()),
            Some(Err(())) => None,
            Some(Ok(len)) => (front.len() >= len).then_some(len),
        }
    }

    /// Whether a whole frame (or bytes [`take`](Stream::take) refuses) waits at the front.
    pub fn is_ready(&self) -> bool {
        self.front_len().is_some()
    }

    /// Whether a frame has started and is not whole yet.
    pub fn is_partial(&self) -> bool {
        self.len > self.taken && !self.is_ready()
    }

    /// The frame at the front, without taking it.
    pub fn peek(&self) -> Option<Result<TcpAdu<'_>, MbapError>> {
        let len = self.front_len()?;
        let front = self.buf.get(self.taken..self.taken + len)?;
        Some(TcpAdu::new_checked(front))
    }

    /// The frame at the front, once it is whole (it is dropped at the next call to `take` or
    /// `push`); `None` while it is not. After [`MbapError::Length`] the stream is of no more
    /// use: [`clear`](Stream::clear) it with its connection.
    pub fn take(&mut self) -> Option<Result<TcpAdu<'_>, MbapError>> {
        self.drop_taken();
        let len = self.front_len()?;
        self.taken = len;
        Some(TcpAdu::new_checked(self.buf.get(..len)?))
    }

    /// Forgets everything (a connection closed, or a new one on the same socket).
    pub fn clear(&mut self) {
        self.len = 0;
        self.taken = 0;
    }
}
