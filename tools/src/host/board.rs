//! The board's flash and bootloader on a PC: what `rc-gateway-host --dfu PATH` runs, so a firmware
//! update over the PLC link goes through the same steps as on the L475 (issue 37).
//!
//! **The flash** is one file of the L475's 1 MiB (`rc_boot::layout::L475`: offset 0 is
//! `0x0800_0000`), held in memory and written through to the file at every erase and write: 2
//! KiB pages, 8-byte words, erased `0xFF`, a write ANDed into what is there (NOR flash). Only
//! ACTIVE, DFU and STATE are used; the bootloader's and the settings' pages stay erased. A new
//! file starts erased: ACTIVE empty, STATE without a mark.
//!
//! **The update** ([`Board::carry_out`]): an erase and the chunks go into DFU; FINISH reads the
//! image back, checks its CRC-32, then `rc_boot::update::verify_and_mark` (the trailer, the
//! board, the size, and embassy-boot's `verify_and_mark_updated` with the host's public key,
//! which writes embassy-boot's swap mark into STATE). Its refusals are the node's
//! `UpdateError`s: `NotAnImage`, `Signature`, `OnTrial` (embassy-boot's `BadState`), `Flash`.
//! During a trial nothing is erased either (DFU holds the previous firmware, the rollback's
//! copy): the erase is refused with `OnTrial`. A mark left by an earlier FINISH of the same run
//! is taken back before the erase (embassy-boot's `mark_booted`): a mark must never point at a
//! partition being rewritten.
//!
//! **The start** ([`Board::boot`]): embassy-boot's own `BootLoader::prepare_boot` on the file,
//! as the bootloader does at every reset: it swaps a marked image in (a trial), reverts a trial
//! that was never confirmed, or does nothing. The "running firmware" is then whatever ACTIVE
//! holds: the version of the signed image found there (its trailer), or, with none (a new
//! file, or an image rolled back to the erased ACTIVE it replaced), the host's built-in one.
//! The state told to the node (BOOTSTAT): `prepare_boot` answered `Swap` and left the swap mark
//! → `Trial`; answered `Swap` and left the revert mark (it just rolled back) or answered
//! `Revert` → `RolledBack`; else `Confirmed`. Once the node says the trial passed
//! (`Node::trial_passed`), the host confirms with embassy-boot's `mark_booted`.

use std::cell::RefCell;
use std::fs::{File, OpenOptions};
use std::io;
use std::os::unix::fs::FileExt;
use std::path::PathBuf;

use embassy_boot::{
    BlockingFirmwareState, BlockingFirmwareUpdater, BootLoader, BootLoaderConfig,
    FirmwareUpdaterConfig, FirmwareUpdaterError, State,
};
use embassy_embedded_hal::flash::partition::BlockingPartition;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use protocol::plc::update::{crc32, BootState, Target, UpdateError, UpdateJob};
use rc_boot::image::{Trailer, Version, MAGIC, TRAILER_LEN};
use rc_boot::layout::{Layout, Region, ERASED, L475, PAGE, WORD};
use rc_boot::update::verify_and_mark;

/// The board, its flash file and the key its firmware verifies images with.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DfuOptions {
    /// The flash file (the L475's 1 MiB; created erased).
    pub path: PathBuf,
    /// The board id (BEGIN and the image's trailer must name it).
    pub board: u16,
    /// The Ed25519 public key the "firmware" verifies images with (`None`: the TEST key).
    pub public_key: Option<[u8; 32]>,
}

/// Why a flash operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlashError {
    /// Outside the flash.
    OutOfBounds,
    /// Not on a page or a word.
    NotAligned,
    /// The file could not be written.
    Io,
}

impl NorFlashError for FlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            FlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            FlashError::NotAligned => NorFlashErrorKind::NotAligned,
            FlashError::Io => NorFlashErrorKind::Other,
        }
    }
}

/// The whole flash, in memory and written through to its file.
pub struct FileFlash {
    mem: Vec<u8>,
    file: File,
}

impl FileFlash {
    /// Opens the file (created erased if missing or empty); it must be the layout's size.
    pub fn open(path: &std::path::Path, len: u32) -> io::Result<FileFlash> {
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)?;
        let have = file.metadata()?.len();
        let mem = if have == 0 {
            let mem = vec![ERASED; len as usize];
            file.write_all_at(&mem, 0)?;
            mem
        } else if have == u64::from(len) {
            let mut mem = vec![0; len as usize];
            file.read_exact_at(&mut mem, 0)?;
            mem
        } else {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("{have} bytes: the flash file is {len} bytes (or empty, or missing)"),
            ));
        };
        Ok(FileFlash { mem, file })
    }

    /// `len` bytes at `at`.
    pub fn bytes(&self, at: u32, len: u32) -> &[u8] {
        self.mem
            .get(at as usize..(at as usize).saturating_add(len as usize))
            .unwrap_or_default()
    }

    fn range(&self, at: u32, len: usize) -> Result<std::ops::Range<usize>, FlashError> {
        let start = at as usize;
        let end = start.checked_add(len).ok_or(FlashError::OutOfBounds)?;
        if end > self.mem.len() {
            return Err(FlashError::OutOfBounds);
        }
        Ok(start..end)
    }

    fn persist(&self, range: std::ops::Range<usize>) -> Result<(), FlashError> {
        let bytes = self.mem.get(range.clone()).ok_or(FlashError::OutOfBounds)?;
        self.file
            .write_all_at(bytes, range.start as u64)
            .map_err(|_| FlashError::Io)
    }
}

impl ErrorType for FileFlash {
    type Error = FlashError;
}

impl ReadNorFlash for FileFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        let range = self.range(offset, bytes.len())?;
        bytes.copy_from_slice(self.mem.get(range).ok_or(FlashError::OutOfBounds)?);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.mem.len()
    }
}

impl NorFlash for FileFlash {
    const WRITE_SIZE: usize = WORD as usize;
    const ERASE_SIZE: usize = PAGE as usize;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        if from > to {
            return Err(FlashError::OutOfBounds);
        }
        if !from.is_multiple_of(PAGE) || !to.is_multiple_of(PAGE) {
            return Err(FlashError::NotAligned);
        }
        let range = self.range(from, (to - from) as usize)?;
        self.mem
            .get_mut(range.clone())
            .ok_or(FlashError::OutOfBounds)?
            .fill(ERASED);
        self.persist(range)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        if !offset.is_multiple_of(WORD) || !bytes.len().is_multiple_of(WORD as usize) {
            return Err(FlashError::NotAligned);
        }
        let range = self.range(offset, bytes.len())?;
        // NOR flash: a write only clears bits.
        for (m, b) in self
            .mem
            .get_mut(range.clone())
            .ok_or(FlashError::OutOfBounds)?
            .iter_mut()
            .zip(bytes)
        {
            *m &= *b;
        }
        self.persist(range)
    }
}

type Shared = Mutex<NoopRawMutex, RefCell<FileFlash>>;
type Part<'a> = BlockingPartition<'a, NoopRawMutex, FileFlash>;

/// What a start found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Started {
    /// What the node is told (BOOTSTAT).
    pub boot: BootState,
    /// The version of the signed image in ACTIVE, if there is one.
    pub version: Option<Version>,
}

/// The board: its flash, its layout and its key.
pub struct Board {
    flash: Shared,
    layout: Layout,
    board: u16,
    key: [u8; 32],
    /// The state told to the node at the last start.
    boot: BootState,
    /// The trial (or the rollback) is still to be confirmed with `mark_booted`.
    unconfirmed: bool,
}

impl Board {
    /// Opens the flash file; nothing is booted yet ([`Board::boot`]).
    pub fn open(options: &DfuOptions) -> io::Result<Board> {
        let layout = L475;
        let flash = FileFlash::open(&options.path, layout.flash.len())
            .map_err(|e| io::Error::new(e.kind(), format!("{}: {e}", options.path.display())))?;
        Ok(Board {
            flash: Mutex::new(RefCell::new(flash)),
            layout,
            board: options.board,
            key: options.public_key.unwrap_or(rc_boot::TEST_PUBLIC_KEY),
            boot: BootState::Unknown,
            unconfirmed: false,
        })
    }

    fn part(&self, r: Region) -> Part<'_> {
        BlockingPartition::new(&self.flash, r.offset_from(self.layout.flash.start), r.len())
    }

    /// What the node is told about the board: its id and the largest image, as the firmware
    /// tells it (src/dfu/): DFU's size, but no larger than ACTIVE, where the swap puts it.
    pub fn target(&self) -> Target {
        Target {
            board: self.board,
            partition: self.layout.max_image(),
        }
    }

    /// The state told at the last start.
    pub fn boot_state(&self) -> BootState {
        self.boot
    }

    /// A reset: embassy-boot's `prepare_boot` on the flash, then what ACTIVE runs.
    pub fn boot(&mut self) -> io::Result<Started> {
        let (prepared, after) = {
            let mut bl = BootLoader::new(BootLoaderConfig {
                active: self.part(self.layout.active),
                dfu: self.part(self.layout.dfu),
                state: self.part(self.layout.state),
            });
            let mut buf = vec![0u8; rc_boot::BOOT_BUF_LEN];
            let prepared = bl
                .prepare_boot(&mut buf)
                .map_err(|e| io::Error::other(format!("prepare_boot: {e:?}")))?;
            let after = bl
                .read_state(&mut buf)
                .map_err(|e| io::Error::other(format!("read_state: {e:?}")))?;
            (prepared, after)
        };
        self.boot = match (&prepared, &after) {
            (State::Swap, State::Swap) => BootState::Trial,
            (State::Swap, State::Revert) | (State::Revert, _) => BootState::RolledBack,
            _ => BootState::Confirmed,
        };
        self.unconfirmed = after != State::Boot;
        Ok(Started {
            boot: self.boot,
            version: self.active_version(),
        })
    }

    /// The version in the trailer of the signed image at ACTIVE's start: the first trailer
    /// that parses where its own length says it is.
    pub fn active_version(&self) -> Option<Version> {
        let flash = self.flash.lock(|f| {
            let f = f.borrow();
            f.bytes(
                self.layout.active.offset_from(self.layout.flash.start),
                self.layout.active.len(),
            )
            .to_vec()
        });
        let mut at = 0usize;
        while at + TRAILER_LEN <= flash.len() {
            if flash.get(at..at + MAGIC.len()) == Some(&MAGIC[..]) {
                if let Ok(t) = Trailer::parse(flash.get(at..at + TRAILER_LEN).unwrap_or_default()) {
                    if t.offset() == Some(at as u32) && t.board == self.board {
                        return Some(t.version);
                    }
                }
            }
            at += WORD as usize;
        }
        None
    }

    /// Whether the running firmware waits for its confirmation.
    pub fn unconfirmed(&self) -> bool {
        self.unconfirmed
    }

    /// The trial passed: embassy-boot's `mark_booted`. The new state to tell the node.
    pub fn confirm(&mut self) -> io::Result<BootState> {
        let mut aligned = [0u8; WORD as usize];
        let mut state = BlockingFirmwareState::new(self.part(self.layout.state), &mut aligned);
        state
            .mark_booted()
            .map_err(|e| io::Error::other(format!("mark_booted: {e:?}")))?;
        self.unconfirmed = false;
        if self.boot == BootState::Trial {
            self.boot = BootState::Confirmed;
        }
        Ok(self.boot)
    }

    /// Carries out `job`: `Ok(Some(v))` when FINISH marked an image of version `v`
    /// (`major << 24 | minor << 16 | patch`), `Ok(Some(0))` when an erase took a mark back.
    pub fn carry_out(&mut self, job: &UpdateJob<'_>) -> Result<Option<u32>, UpdateError> {
        match *job {
            UpdateJob::Erase { len } => {
                // DFU holds the previous firmware during a trial: the rollback's copy.
                if self.boot == BootState::Trial && self.unconfirmed {
                    return Err(UpdateError::OnTrial);
                }
                let mut unmarked = None;
                {
                    let mut aligned = [0u8; WORD as usize];
                    let mut state =
                        BlockingFirmwareState::new(self.part(self.layout.state), &mut aligned);
                    if state.get_state().map_err(|_| UpdateError::Flash)? == State::Swap {
                        state.mark_booted().map_err(|_| UpdateError::Flash)?;
                        unmarked = Some(0);
                    }
                }
                let end = len
                    .div_ceil(PAGE)
                    .saturating_mul(PAGE)
                    .min(self.layout.dfu.len());
                self.part(self.layout.dfu)
                    .erase(0, end)
                    .map_err(|_| UpdateError::Flash)?;
                Ok(unmarked)
            }
            UpdateJob::Write { offset, bytes } => {
                let mut padded = bytes.to_vec();
                padded.resize(bytes.len().next_multiple_of(WORD as usize), ERASED);
                self.part(self.layout.dfu)
                    .write(offset, &padded)
                    .map_err(|_| UpdateError::Flash)?;
                Ok(None)
            }
            UpdateJob::Finish { len, crc32: crc } => {
                let mut image = vec![0u8; len as usize];
                self.part(self.layout.dfu)
                    .read(0, &mut image)
                    .map_err(|_| UpdateError::Flash)?;
                if crc32(&image) != crc {
                    return Err(UpdateError::Flash);
                }
                let mut aligned = [0u8; WORD as usize];
                let mut updater = BlockingFirmwareUpdater::new(
                    FirmwareUpdaterConfig {
                        dfu: self.part(self.layout.dfu),
                        state: self.part(self.layout.state),
                    },
                    &mut aligned,
                );
                match verify_and_mark(
                    &mut updater,
                    len,
                    self.board,
                    self.layout.max_image(),
                    &self.key,
                ) {
                    Ok(trailer) => Ok(Some(trailer.version.to_u32())),
                    Err(rc_boot::update::UpdateError::Image(_)) => Err(UpdateError::NotAnImage),
                    Err(rc_boot::update::UpdateError::Updater(e)) => Err(match e {
                        FirmwareUpdaterError::Signature(_) => UpdateError::Signature,
                        FirmwareUpdaterError::BadState => UpdateError::OnTrial,
                        FirmwareUpdaterError::Flash(_) => UpdateError::Flash,
                    }),
                }
            }
        }
    }
}
