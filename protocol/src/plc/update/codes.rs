//! UPDSTAT's and BOOTSTAT's registers and codes: what a tool decodes (`rcgw update --status`)
//! and the gateway writes. The transfer that sets them is the [parent module](super)'s.

use crate::plc::refused::Refused;

/// UPDSTAT's registers, as offsets from [`G_UPDATE_STATUS`](crate::plc::map::G_UPDATE_STATUS).
pub mod status {
    /// [`UpdateState`](super::UpdateState).
    pub const STATE: u16 = 0;
    /// [`UpdateError`](super::UpdateError) of the last refusal or failure.
    pub const ERROR: u16 = 1;
    /// Bytes taken (u32): with a chunk being written, its end.
    pub const RECEIVED: u16 = 2;
    /// The offset the next chunk must have (u32): the bytes written.
    pub const NEXT: u16 = 4;
    /// The image's size BEGIN declared (u32).
    pub const SIZE: u16 = 6;
    /// The image's CRC-32 BEGIN declared (u32).
    pub const CRC: u16 = 8;
    /// This board's id (0: no DFU partition).
    pub const BOARD: u16 = 10;
    /// The DFU partition's size in bytes (u32).
    pub const PARTITION: u16 = 11;
    /// Refused requests but those refused as `Busy` (u32, wrapping).
    pub const REFUSALS: u16 = 13;
    /// The largest chunk, in bytes ([`MAX_CHUNK`](crate::plc::update::MAX_CHUNK)).
    pub const MAX_CHUNK: u16 = 15;
}

/// UPDSTAT's state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u16)]
pub enum UpdateState {
    /// No transfer.
    #[default]
    Idle = 0,
    /// The partition is being erased.
    Erasing = 1,
    /// Waiting for the chunk at the next offset.
    Receiving = 2,
    /// A chunk is being written.
    Writing = 3,
    /// The image is being read back, checked and marked for the bootloader.
    Finishing = 4,
    /// The image is in the partition, checked and marked.
    Ready = 5,
    /// A flash job failed, or the image's CRC-32 did not match: BEGIN again.
    Failed = 6,
}

/// Why a request was refused or a transfer failed (UPDSTAT's last error).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u16)]
pub enum UpdateError {
    /// Nothing refused, nothing failed.
    #[default]
    None = 0,
    /// An axis moves or has a job waiting, or a synchronized start runs (04).
    Moving = 1,
    /// A SAVE is pending (04).
    SavePending = 2,
    /// The caller is still erasing or writing (04).
    Busy = 3,
    /// No transfer under way (04).
    NotStarted = 4,
    /// BEGIN's board id is not this board's (03).
    WrongBoard = 5,
    /// The image is larger than the DFU partition, or empty (03).
    TooLarge = 6,
    /// A chunk not at the next offset (03).
    OutOfOrder = 7,
    /// A chunk whose CRC-16 does not match its bytes (03).
    ChunkCheck = 8,
    /// A block of the wrong shape, a length out of range or unaligned, a chunk past the end
    /// (03).
    Malformed = 9,
    /// FINISH before every byte was written (03).
    Incomplete = 10,
    /// FINISH with another CRC-32 than BEGIN's: state [`Failed`](UpdateState::Failed) (03).
    ImageCheck = 11,
    /// The caller could not erase, write, check or mark: state
    /// [`Failed`](UpdateState::Failed).
    Flash = 12,
    /// This board has no DFU partition (02).
    NoPartition = 13,
    /// FINISH: the image carries no valid trailer, or one for another board, or it is larger
    /// than the application's partition (the caller's check, before the signature's): state
    /// [`Failed`](UpdateState::Failed).
    NotAnImage = 14,
    /// FINISH: the image's signature is not one of this firmware's key (unsigned, signed with
    /// another key, or altered after signing): state [`Failed`](UpdateState::Failed).
    Signature = 15,
    /// FINISH: the firmware that runs is itself on trial (a new image not yet confirmed, or
    /// just rolled back): the bootloader takes no second image until it is confirmed. State
    /// [`Failed`](UpdateState::Failed); restart or wait for the confirmation, then BEGIN again.
    OnTrial = 16,
}

impl UpdateState {
    /// Every state, in the order of its code (0 to 6): for tools that decode UPDSTAT.
    pub const ALL: [UpdateState; 7] = [
        UpdateState::Idle,
        UpdateState::Erasing,
        UpdateState::Receiving,
        UpdateState::Writing,
        UpdateState::Finishing,
        UpdateState::Ready,
        UpdateState::Failed,
    ];

    /// The state of UPDSTAT's STATE register, if it is one.
    pub fn from_code(code: u16) -> Option<UpdateState> {
        UpdateState::ALL.get(usize::from(code)).copied()
    }

    /// Its name, one word, as a tool shows it.
    pub const fn name(self) -> &'static str {
        match self {
            UpdateState::Idle => "idle",
            UpdateState::Erasing => "erasing",
            UpdateState::Receiving => "receiving",
            UpdateState::Writing => "writing",
            UpdateState::Finishing => "finishing",
            UpdateState::Ready => "ready",
            UpdateState::Failed => "failed",
        }
    }
}

impl UpdateError {
    /// Every error, in the order of its code (0 to 16): for tools that decode UPDSTAT.
    pub const ALL: [UpdateError; 17] = [
        UpdateError::None,
        UpdateError::Moving,
        UpdateError::SavePending,
        UpdateError::Busy,
        UpdateError::NotStarted,
        UpdateError::WrongBoard,
        UpdateError::TooLarge,
        UpdateError::OutOfOrder,
        UpdateError::ChunkCheck,
        UpdateError::Malformed,
        UpdateError::Incomplete,
        UpdateError::ImageCheck,
        UpdateError::Flash,
        UpdateError::NoPartition,
        UpdateError::NotAnImage,
        UpdateError::Signature,
        UpdateError::OnTrial,
    ];

    /// The error of UPDSTAT's ERROR register, if it is one.
    pub fn from_code(code: u16) -> Option<UpdateError> {
        UpdateError::ALL.get(usize::from(code)).copied()
    }

    /// What it means, in a few words, for a tool's message.
    pub const fn text(self) -> &'static str {
        match self {
            UpdateError::None => "none",
            UpdateError::Moving => "an axis moves or has a job waiting",
            UpdateError::SavePending => "a SAVE is pending",
            UpdateError::Busy => "the gateway is still erasing or writing",
            UpdateError::NotStarted => "no transfer under way",
            UpdateError::WrongBoard => "the image is for another board",
            UpdateError::TooLarge => "the image is larger than the DFU partition",
            UpdateError::OutOfOrder => "a chunk not at the next offset",
            UpdateError::ChunkCheck => "a chunk's CRC-16 did not match",
            UpdateError::Malformed => "a malformed request",
            UpdateError::Incomplete => "FINISH before the last byte",
            UpdateError::ImageCheck => "the image's CRC-32 is not the one BEGIN declared",
            UpdateError::Flash => "the flash could not be erased, written or checked",
            UpdateError::NoPartition => "this gateway has no DFU partition",
            UpdateError::NotAnImage => {
                "not a signed image for this board (no valid trailer, another board, or too large)"
            }
            UpdateError::Signature => "the image's signature does not match this firmware's key",
            UpdateError::OnTrial => {
                "the running firmware is on trial: restart or wait for its confirmation"
            }
        }
    }

    /// How a Modbus master sees the refusal.
    pub(super) fn refused(self) -> Refused {
        match self {
            // What passes by itself: ask again. (No transfer under way does not: 03.)
            UpdateError::Moving | UpdateError::SavePending | UpdateError::Busy => Refused::Busy,
            UpdateError::NoPartition => Refused::NoSuchAddress,
            _ => Refused::OutOfRange,
        }
    }
}

/// What the bootloader did at the last start (BOOTSTAT's first register): the firmware's to
/// tell ([`Node::set_boot_state`](crate::node::Node::set_boot_state)).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u16)]
pub enum BootState {
    /// Not told: no bootloader (the board has none, or the firmware was flashed alone).
    #[default]
    Unknown = 0,
    /// The running firmware is confirmed: it stays at the next start.
    Confirmed = 1,
    /// The running firmware is a new image on trial: it is confirmed once it has started, found
    /// its bus and answered the PLC link; a start without that confirmation swaps the old one
    /// back.
    Trial = 2,
    /// The last new image never confirmed and was swapped back: the old firmware runs (and is
    /// confirmed again once it has started). Until the next start.
    RolledBack = 3,
}

impl BootState {
    /// Every state, in the order of its code.
    pub const ALL: [BootState; 4] = [
        BootState::Unknown,
        BootState::Confirmed,
        BootState::Trial,
        BootState::RolledBack,
    ];

    /// The state of BOOTSTAT's first register, if it is one.
    pub fn from_code(code: u16) -> Option<BootState> {
        BootState::ALL.get(usize::from(code)).copied()
    }

    /// Its name, as a tool shows it.
    pub const fn name(self) -> &'static str {
        match self {
            BootState::Unknown => "no bootloader",
            BootState::Confirmed => "confirmed",
            BootState::Trial => "on trial",
            BootState::RolledBack => "rolled back",
        }
    }
}

/// BOOTSTAT's registers, as offsets from [`G_BOOT_STATUS`](crate::plc::map::G_BOOT_STATUS).
pub mod boot_status {
    /// [`BootState`](super::BootState).
    pub const STATE: u16 = 0;
    /// The version of the signed image checked into DFU since the start and marked for the
    /// next one (u32, `major << 24 | minor << 16 | patch`; 0: none).
    pub const IMAGE: u16 = 1;
}
