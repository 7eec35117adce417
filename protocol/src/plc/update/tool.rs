//! What a tool writes and reads to send an image ([`super`] says how): the BEGIN block, a
//! chunk's block, UPDSTAT parsed. `rcgw update` uses them, and the tests do.

use super::{status, BEGIN, MAX_CHUNK};
use crate::modbus::crc;
use crate::plc::map::G_UPDATE_STATUS_LEN;
use crate::plc::registers::{join, split};

/// UPDCTL's BEGIN block for an image of `size` bytes with CRC-32 `crc32`, for board `board`:
/// what a tool writes with FC16 at [`G_UPDATE`](crate::plc::map::G_UPDATE).
pub fn begin_registers(size: u32, crc32: u32, board: u16) -> [u16; 6] {
    let [size_hi, size_lo] = split(size);
    let [crc_hi, crc_lo] = split(crc32);
    [BEGIN, size_hi, size_lo, crc_hi, crc_lo, board]
}

/// UPDCHUNK's block for `bytes` at `offset` (at most [`MAX_CHUNK`] of them; more are cut):
/// what a tool writes with FC16 at [`G_UPDATE_CHUNK`](crate::plc::map::G_UPDATE_CHUNK).
pub fn chunk_registers(offset: u32, bytes: &[u8]) -> heapless::Vec<u16, 120> {
    let bytes = bytes.get(..MAX_CHUNK).unwrap_or(bytes);
    let [offset_hi, offset_lo] = split(offset);
    let mut out = heapless::Vec::new();
    let len = u16::try_from(bytes.len()).unwrap_or(0);
    for word in [offset_hi, offset_lo, len, crc::checksum(bytes)] {
        let _ = out.push(word);
    }
    for pair in bytes.chunks(2) {
        let hi = pair.first().copied().unwrap_or(0);
        let lo = pair.get(1).copied().unwrap_or(0);
        let _ = out.push(u16::from_be_bytes([hi, lo]));
    }
    out
}

/// UPDSTAT as a tool reads it (16 registers from [`G_UPDATE_STATUS`](crate::plc::map::G_UPDATE_STATUS)).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UpdateStatus {
    /// [`UpdateState`](super::UpdateState) as its number (an unknown one kept as read).
    pub state: u16,
    /// [`UpdateError`](super::UpdateError) as its number.
    pub error: u16,
    /// Bytes taken.
    pub received: u32,
    /// The offset the next chunk must have.
    pub next: u32,
    /// The image's size BEGIN declared.
    pub size: u32,
    /// The image's CRC-32 BEGIN declared.
    pub crc32: u32,
    /// The board's id.
    pub board: u16,
    /// The DFU partition's size.
    pub partition: u32,
    /// Refusals so far.
    pub refusals: u32,
    /// The largest chunk the gateway takes.
    pub max_chunk: u16,
}

impl UpdateStatus {
    /// UPDSTAT from its registers; `None` unless there are 16.
    pub fn parse(registers: &[u16]) -> Option<UpdateStatus> {
        let r = |i: u16| registers.get(usize::from(i)).copied();
        let u32_at = |i: u16| Some(join(r(i)?, r(i + 1)?));
        if registers.len() != usize::from(G_UPDATE_STATUS_LEN) {
            return None;
        }
        Some(UpdateStatus {
            state: r(status::STATE)?,
            error: r(status::ERROR)?,
            received: u32_at(status::RECEIVED)?,
            next: u32_at(status::NEXT)?,
            size: u32_at(status::SIZE)?,
            crc32: u32_at(status::CRC)?,
            board: r(status::BOARD)?,
            partition: u32_at(status::PARTITION)?,
            refusals: u32_at(status::REFUSALS)?,
            max_chunk: r(status::MAX_CHUNK)?,
        })
    }
}
