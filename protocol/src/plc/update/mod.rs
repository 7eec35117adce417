//! A new firmware image over the PLC link (feature `update`): the transfer into the board's
//! DFU partition, as a state machine that never touches flash. It asks the caller to erase,
//! write and finish ([`UpdateJob`], handed out by the node as
//! [`Action::Update`](crate::node::Action::Update)); the caller reports each job's result with
//! [`Node::update_done`](crate::node::Node::update_done). What boots the image (the bootloader,
//! its signature check, the swap) is not this module's.
//!
//! # The mechanism: a register window on the gateway unit
//!
//! Three blocks of holding registers on the gateway unit (63 by default), beside its other
//! registers ([`map`](super::map)):
//!
//! | Block | Address | Registers | Written with | What |
//! |---|---|---|---|---|
//! | UPDCTL | [`G_UPDATE`] | 6 or 1 | FC16 (6) or FC06 (1) | `1` BEGIN with the image's size (u32), CRC-32 (u32) and board id; `2` FINISH; `3` ABORT |
//! | UPDSTAT | [`G_UPDATE_STATUS`] | 16 | read with FC03 or FC04 | state, last error, bytes received (u32), next offset (u32), image size (u32), image CRC-32 (u32), board id, partition size (u32), refusals (u32), the largest chunk |
//! | UPDCHUNK | [`G_UPDATE_CHUNK`] | 4 + ⌈n/2⌉ | FC16 | offset (u32), length n (bytes, 1..=[`MAX_CHUNK`]), CRC-16/MODBUS of the n bytes, then the bytes, two per register, high byte first |
//!
//! u32 values are two registers, high word first, as everywhere on the gateway. The CRC-32 of
//! the image is the common one (IEEE 802.3, reflected, as zip and `crc32` compute it:
//! [`crc32`]).
//!
//! **A transfer**: BEGIN (the gateway asks the caller to erase the partition's first *size*
//! bytes; UPDSTAT shows state 1 until that is done, then 2); chunks in order, each starting at
//! the next offset UPDSTAT shows (state 3 while the caller writes one, then 2 again with the
//! next offset moved on); FINISH (once every byte is written and the CRC-32 of what was written
//! is the one BEGIN declared: the caller reads the image back, checks its CRC-32, its signed
//! trailer and its signature, and marks it for the bootloader; state 4, then 5 ready or 6
//! failed with the reason: `Flash`, `NotAnImage`, `Signature`, `OnTrial`). Each chunk is 8-byte aligned: its
//! length a multiple of 8 unless it is the image's last, so every write starts on a flash word
//! of every STM32 the gateway runs on.
//!
//! **A cut link resumes**: a tool that lost the link, or the reply to a chunk, reads UPDSTAT. In
//! state 2 with its image's size and CRC-32, it sends the chunk at the next offset shown; a
//! chunk that was taken is never taken twice (its offset is no longer the next one). A restart
//! of the gateway forgets the transfer (state 0): BEGIN again.
//!
//! **Refused** (each refusal counted in UPDSTAT's refusals but `Busy`, the flow control a fast
//! tool meets at nearly every chunk; its reason in the last error; the transfer stays where it
//! was, but for a failed FINISH check):
//!
//! | Reason ([`UpdateError`]) | Exception |
//! |---|---|
//! | an axis moves, has a job waiting, or a synchronized start runs (`Moving`); a SAVE is pending (`SavePending`); a flash job under way (`Busy`) | 04, ask again |
//! | no transfer under way (`NotStarted`: none begun, or the last one failed, finished or was forgotten by a restart; BEGIN again); a board id not this board's (`WrongBoard`); an image larger than the DFU partition or empty (`TooLarge`); a chunk not at the next offset (`OutOfOrder`); a chunk whose CRC-16 does not match its bytes (`ChunkCheck`); a block of the wrong shape, a length out of range or unaligned, a chunk past the image's end (`Malformed`); FINISH before the last byte (`Incomplete`) or with another CRC-32 than BEGIN's (`ImageCheck`: state 6, BEGIN again) | 03 |
//! | no DFU partition on this board (`NoPartition`) | 02 |
//! | after FINISH was taken, the caller's checks failed: the flash (`Flash`), the signed trailer (`NotAnImage`), the signature (`Signature`), the running firmware on trial (`OnTrial`) | none: FINISH was answered; UPDSTAT shows state 6 and the reason |
//!
//! # Why a register window, not FC 0x15
//!
//! The Modbus Application Protocol Specification V1.1b3 has a function for files, Write File
//! Record (FC 0x15, §6.15): up to 244 data bytes a request, and Read File Record (FC 0x14,
//! §6.14) to read them back. A window written with Write Multiple Registers (FC16, §6.12: at
//! most 123 registers, the RTU ADU at most 256 bytes) carries 232 bytes a request: 5 % less,
//! and it needs nothing new. Every master the gateway meets writes FC16 and reads FC03 (PLCs,
//! HMIs, libmodbus, mbpoll, pymodbus, `rcgw` itself); several have no FC 0x15 (libmodbus has no
//! call for it), and the slave would need a new function and its own checks. The window is the
//! gateway unit's usual way (the command channel, AXISCFG), answers over RTU and TCP alike and
//! gives the tool the status it needs to resume in one FC03.
//!
//! **Throughput** at 115.2 kbit/s (11 bits a character): a chunk's request is 249 bytes (1 unit,
//! 1 function, 4 address and count, 1 byte count, 240 data, 2 CRC), its reply 8: 257 characters,
//! 24.5 ms, plus two t3.5 (1.75 ms each) and the gateway's turn-around, about 29 ms for 232
//! bytes, 8 KB/s: a 256 KiB image in about 33 s, a 128 KiB one in about 17 s (computed, not yet
//! measured). Over TCP the chunk is one segment each way; the flash writes set the pace.
//!
//! # While the transfer runs
//!
//! The gateway keeps serving the bus and the PLC: a job is handed out only when the bus has
//! nothing to send at once and is quiet ([`Node::quiet_for_flash`](crate::node::Node::quiet_for_flash):
//! no axis moves or has a job waiting, no synchronized start runs, no stop is owed), and the
//! node does not wait for its result: the caller reports it when it is done, and until then a
//! chunk is refused with 04 (`Busy`). A move the PLC starts during a transfer is carried out at
//! once; the transfer waits until it ends. The caller takes the job's steps under the same rule,
//! so a stop never waits behind flash work. How long one step may stall the caller (an erase of
//! a 128 KiB sector takes seconds on an F4) is the firmware's to bound.

use super::map::{
    G_BOOT_STATUS, G_BOOT_STATUS_LEN, G_UPDATE, G_UPDATE_CHUNK, G_UPDATE_CHUNK_LEN, G_UPDATE_LEN,
    G_UPDATE_STATUS, G_UPDATE_STATUS_LEN,
};
use super::refused::Refused;
use super::registers::{join, split};
use crate::modbus::crc;

mod codes;
mod crc32;
mod tool;

pub use codes::{boot_status, status, BootState, UpdateError, UpdateState};
pub use crc32::{crc32, Crc32};
pub use tool::{begin_registers, chunk_registers, UpdateStatus};

/// The most bytes a chunk carries: 116 registers, with the 4 of its header 120 of FC16's 123,
/// and a multiple of 8 (the flash words of the STM32L4 and F4).
pub const MAX_CHUNK: usize = 232;

/// A chunk's header: offset (2 registers), length, CRC-16.
pub const CHUNK_HEADER: u16 = 4;

/// Every chunk but an image's last is a multiple of this many bytes.
pub const CHUNK_ALIGN: u32 = 8;

// The map's UPDCHUNK is a header and the largest chunk, in one FC16 (at most 123 registers);
// the largest chunk keeps the next offset on a flash word.
const _: () = assert!(
    G_UPDATE_CHUNK_LEN == CHUNK_HEADER + (MAX_CHUNK as u16).div_ceil(2)
        && G_UPDATE_CHUNK_LEN <= 123
        && (MAX_CHUNK as u32).is_multiple_of(CHUNK_ALIGN)
);

/// UPDCTL: BEGIN (with size, CRC-32 and board id in the same write).
pub const BEGIN: u16 = 1;
/// UPDCTL: FINISH.
pub const FINISH: u16 = 2;
/// UPDCTL: ABORT (forget the transfer; the partition keeps what was written).
pub const ABORT: u16 = 3;

/// Where an image goes: what the firmware tells the node about its board.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Target {
    /// The board's id, which an image must declare (BEGIN).
    pub board: u16,
    /// The DFU partition's size in bytes: the largest image.
    pub partition: u32,
}

/// What the caller does to the DFU partition, then reports with
/// [`Node::update_done`](crate::node::Node::update_done).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpdateJob<'a> {
    /// Erase the partition from its start over at least `len` bytes (whole pages or sectors),
    /// after unmarking the image marked for the bootloader before, if any: a mark must never
    /// point at a partition being rewritten.
    Erase {
        /// Bytes to erase, at most the partition's size.
        len: u32,
    },
    /// Write `bytes` at `offset` from the partition's start (`offset + bytes.len()` is at most
    /// the partition's size; `offset` a multiple of [`CHUNK_ALIGN`]).
    Write {
        /// From the partition's start.
        offset: u32,
        /// The chunk's bytes.
        bytes: &'a [u8],
    },
    /// Read the partition's first `len` bytes back, check that their CRC-32 ([`crc32`]) is
    /// `crc32` ([`UpdateError::Flash`] if not), check the image's signed trailer
    /// ([`UpdateError::NotAnImage`]) and signature ([`UpdateError::Signature`]), and mark the image
    /// for the bootloader ([`UpdateError::OnTrial`] if it takes none now); tell its version
    /// ([`Node::set_image_version`](crate::node::Node::set_image_version)).
    Finish {
        /// The image's size.
        len: u32,
        /// Its CRC-32.
        crc32: u32,
    },
}

/// What the gateway's state says about starting flash work (checked by the gateway).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Gate {
    /// An axis moves or has a job waiting, or a synchronized start runs.
    pub(super) moving: bool,
    /// A SAVE is pending.
    pub(super) saving: bool,
}

/// The transfer's state; see the [module documentation](self).
#[derive(Clone, Debug)]
pub struct Update {
    target: Option<Target>,
    state: UpdateState,
    error: UpdateError,
    /// BEGIN's size and CRC-32.
    size: u32,
    crc: u32,
    /// The end of the chunk taken last, and of the one written last.
    received: u32,
    written: u32,
    /// The CRC-32 register over the bytes written.
    running: Crc32,
    refusals: u32,
    /// The chunk being written.
    chunk: heapless::Vec<u8, MAX_CHUNK>,
    /// A job made and not yet handed out.
    due: bool,
    /// BOOTSTAT: what the bootloader did, the version of the image marked.
    boot: BootState,
    image: u32,
}

impl Default for Update {
    fn default() -> Self {
        Update::new()
    }
}

impl Update {
    /// No partition, no transfer.
    pub const fn new() -> Update {
        Update {
            target: None,
            state: UpdateState::Idle,
            error: UpdateError::None,
            size: 0,
            crc: 0,
            received: 0,
            written: 0,
            running: Crc32::new(),
            refusals: 0,
            chunk: heapless::Vec::new(),
            due: false,
            boot: BootState::Unknown,
            image: 0,
        }
    }

    /// What the bootloader did at this start (BOOTSTAT).
    pub fn set_boot(&mut self, boot: BootState) {
        self.boot = boot;
    }

    /// What the bootloader did at this start.
    pub fn boot(&self) -> BootState {
        self.boot
    }

    /// The version of the image FINISH checked and marked (BOOTSTAT), given by the caller with
    /// its report of the job: `major << 24 | minor << 16 | patch`.
    pub fn set_image_version(&mut self, version: u32) {
        self.image = version;
    }

    /// The board and its DFU partition; until then every transfer is refused (02).
    pub fn set_target(&mut self, target: Target) {
        self.target = Some(target);
    }

    /// A flash job under way (an erase, a chunk's write, the check and mark): the settings
    /// store's SAVE and factory reset wait for it (04).
    pub fn flash_busy(&self) -> bool {
        matches!(
            self.state,
            UpdateState::Erasing | UpdateState::Writing | UpdateState::Finishing
        )
    }

    /// The state.
    pub fn state(&self) -> UpdateState {
        self.state
    }

    /// The last refusal's or failure's reason.
    pub fn error(&self) -> UpdateError {
        self.error
    }

    /// The offset the next chunk must have: the bytes written so far.
    pub fn next_offset(&self) -> u32 {
        self.written
    }

    /// Requests refused so far.
    pub fn refusals(&self) -> u32 {
        self.refusals
    }

    /// A flash job under way (handed out or not): no new one until it is reported.
    fn working(&self) -> bool {
        matches!(
            self.state,
            UpdateState::Erasing | UpdateState::Writing | UpdateState::Finishing
        )
    }

    /// A register of the window, if `address` is one: UPDSTAT's values, 0 for the
    /// write-only blocks.
    pub(super) fn read(&self, address: u16) -> Option<u16> {
        if let Some(offset) = address
            .checked_sub(G_UPDATE_STATUS)
            .filter(|&o| o < G_UPDATE_STATUS_LEN)
        {
            let word = |value: u32, at: u16| {
                split(value)
                    .get(usize::from(offset.saturating_sub(at)))
                    .copied()
                    .unwrap_or(0)
            };
            let target = self.target.unwrap_or(Target {
                board: 0,
                partition: 0,
            });
            return Some(match offset {
                status::STATE => self.state as u16,
                status::ERROR => self.error as u16,
                o if o < status::NEXT => word(self.received, status::RECEIVED),
                o if o < status::SIZE => word(self.written, status::NEXT),
                o if o < status::CRC => word(self.size, status::SIZE),
                o if o < status::BOARD => word(self.crc, status::CRC),
                status::BOARD => target.board,
                o if o < status::REFUSALS => word(target.partition, status::PARTITION),
                o if o < status::MAX_CHUNK => word(self.refusals, status::REFUSALS),
                _ => MAX_CHUNK as u16,
            });
        }
        if let Some(offset) = address
            .checked_sub(G_BOOT_STATUS)
            .filter(|&o| o < G_BOOT_STATUS_LEN)
        {
            let image = split(self.image);
            return Some(match offset {
                boot_status::STATE => self.boot as u16,
                o => image
                    .get(usize::from(o.wrapping_sub(boot_status::IMAGE)))
                    .copied()
                    .unwrap_or(0),
            });
        }
        let in_block = |first: u16, len: u16| address.checked_sub(first).is_some_and(|o| o < len);
        (in_block(G_UPDATE, G_UPDATE_LEN) || in_block(G_UPDATE_CHUNK, G_UPDATE_CHUNK_LEN))
            .then_some(0)
    }

    /// A write to the gateway unit at `address`, if it is to the window: `None` when it is
    /// not. A refusal is counted and its reason kept.
    pub(super) fn write(
        &mut self,
        address: u16,
        values: &[u16],
        gate: Gate,
    ) -> Option<Result<(), Refused>> {
        let result = match address {
            G_UPDATE => self.control(values, gate),
            G_UPDATE_CHUNK => self.take_chunk(values, gate),
            _ => {
                // Inside the window but not at a block's start: the status is read-only, a
                // block is written whole.
                let inside =
                    |first: u16, len: u16| address.checked_sub(first).is_some_and(|o| o < len);
                if inside(G_UPDATE, G_UPDATE_LEN)
                    || inside(G_BOOT_STATUS, G_BOOT_STATUS_LEN)
                    || inside(G_UPDATE_STATUS, G_UPDATE_STATUS_LEN)
                    || inside(G_UPDATE_CHUNK, G_UPDATE_CHUNK_LEN)
                {
                    Err(UpdateError::Malformed)
                } else {
                    return None;
                }
            }
        };
        Some(result.map_err(|error| {
            // "The flash is still at work" is the tool's flow control, not a fault: a fast
            // tool meets it at nearly every chunk.
            if error != UpdateError::Busy {
                self.refusals = self.refusals.wrapping_add(1);
            }
            // A failed transfer keeps why it failed (the flash, the image's check) until a
            // BEGIN: the tool's next chunk, refused as no transfer is under way, would hide it.
            if self.state != UpdateState::Failed || address == G_UPDATE {
                self.error = error;
            }
            error.refused()
        }))
    }

    /// The flash work may start now.
    fn admit(&self, gate: Gate) -> Result<(), UpdateError> {
        if self.working() {
            Err(UpdateError::Busy)
        } else if gate.moving {
            Err(UpdateError::Moving)
        } else if gate.saving {
            Err(UpdateError::SavePending)
        } else {
            Ok(())
        }
    }

    /// UPDCTL: BEGIN, FINISH, ABORT.
    fn control(&mut self, values: &[u16], gate: Gate) -> Result<(), UpdateError> {
        let target = self.target.ok_or(UpdateError::NoPartition)?;
        match *values {
            [BEGIN, size_hi, size_lo, crc_hi, crc_lo, board] => {
                self.admit(gate)?;
                if board != target.board {
                    return Err(UpdateError::WrongBoard);
                }
                let size = join(size_hi, size_lo);
                if size == 0 || size > target.partition {
                    return Err(UpdateError::TooLarge);
                }
                *self = Update {
                    target: Some(target),
                    state: UpdateState::Erasing,
                    size,
                    crc: join(crc_hi, crc_lo),
                    refusals: self.refusals,
                    due: true,
                    // The image marked before, if any, is being erased: the caller unmarks it
                    // first (UpdateJob::Erase).
                    boot: self.boot,
                    ..Update::new()
                };
                Ok(())
            }
            [FINISH] => {
                self.admit(gate)?;
                if self.state != UpdateState::Receiving {
                    return Err(UpdateError::NotStarted);
                }
                if self.written != self.size {
                    return Err(UpdateError::Incomplete);
                }
                if self.running.finish() != self.crc {
                    self.state = UpdateState::Failed;
                    return Err(UpdateError::ImageCheck);
                }
                self.state = UpdateState::Finishing;
                self.error = UpdateError::None;
                self.due = true;
                Ok(())
            }
            [ABORT] => {
                if self.working() {
                    return Err(UpdateError::Busy);
                }
                *self = Update {
                    target: Some(target),
                    refusals: self.refusals,
                    // What is marked stays marked.
                    boot: self.boot,
                    image: self.image,
                    ..Update::new()
                };
                Ok(())
            }
            _ => Err(UpdateError::Malformed),
        }
    }

    /// UPDCHUNK: the chunk at the next offset, checked whole before it is taken. Not inlined:
    /// its frame is on the stack only while a chunk is taken, not under every register write.
    #[inline(never)]
    fn take_chunk(&mut self, values: &[u16], gate: Gate) -> Result<(), UpdateError> {
        self.target.ok_or(UpdateError::NoPartition)?;
        self.admit(gate)?;
        if self.state != UpdateState::Receiving {
            return Err(UpdateError::NotStarted);
        }
        let [offset_hi, offset_lo, len, check, ref data @ ..] = *values else {
            return Err(UpdateError::Malformed);
        };
        let len_bytes = usize::from(len);
        if len_bytes == 0 || len_bytes > MAX_CHUNK || data.len() != len_bytes.div_ceil(2) {
            return Err(UpdateError::Malformed);
        }
        let offset = join(offset_hi, offset_lo);
        if offset != self.written {
            return Err(UpdateError::OutOfOrder);
        }
        let end = offset
            .checked_add(u32::from(len))
            .filter(|&end| end <= self.size)
            .ok_or(UpdateError::Malformed)?;
        if u32::from(len) % CHUNK_ALIGN != 0 && end != self.size {
            return Err(UpdateError::Malformed);
        }
        // Straight into the chunk buffer, not through a copy on the stack: this runs under the
        // gateway unit's register write, the deepest stack of a PLC write (232 bytes more of it
        // put the emulator build's stack high-water mark 512 B up). The buffer is read only in
        // state Writing, which a chunk refused below does not reach.
        self.chunk.clear();
        for byte in data
            .iter()
            .flat_map(|word| word.to_be_bytes())
            .take(len_bytes)
        {
            self.chunk.push(byte).map_err(|_| UpdateError::Malformed)?;
        }
        if crc::checksum(&self.chunk) != check {
            return Err(UpdateError::ChunkCheck);
        }
        self.received = end;
        self.state = UpdateState::Writing;
        self.error = UpdateError::None;
        self.due = true;
        Ok(())
    }

    /// Whether a job is due, without taking it.
    pub(super) fn is_due(&self) -> bool {
        self.due
    }

    /// Whether a job is due: taken by this call (the node hands it out once).
    pub(super) fn take_due(&mut self) -> bool {
        core::mem::take(&mut self.due)
    }

    /// The job of the state (after [`take_due`](Self::take_due) said there is one).
    pub(super) fn job(&self) -> Option<UpdateJob<'_>> {
        match self.state {
            UpdateState::Erasing => Some(UpdateJob::Erase { len: self.size }),
            UpdateState::Writing => Some(UpdateJob::Write {
                offset: self.written,
                bytes: &self.chunk,
            }),
            UpdateState::Finishing => Some(UpdateJob::Finish {
                len: self.size,
                crc32: self.crc,
            }),
            _ => None,
        }
    }

    /// The caller's report of the job handed out; ignored when none is under way.
    pub(super) fn done(&mut self, result: Result<(), UpdateError>) {
        // Not a report of a job not yet handed out.
        if !self.working() || self.due {
            return;
        }
        self.due = false;
        if let Err(error) = result {
            self.state = UpdateState::Failed;
            self.error = error;
            return;
        }
        self.state = match self.state {
            UpdateState::Writing => {
                self.running.update(&self.chunk);
                self.written = self.received;
                UpdateState::Receiving
            }
            UpdateState::Finishing => UpdateState::Ready,
            _ => UpdateState::Receiving,
        };
    }
}
