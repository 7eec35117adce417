//! The board's flash and bootloader on a PC: what `rc-gateway-host --dfu PATH` runs, so a firmware
//! update over the PLC link goes through the same steps as on the board (issue 37).
//!
//! **The board** is `--board-id`'s, and its layout `rc_boot::layout_of(board)` (one home; an id
//! without one is refused): the L475 (`rc_boot::layout::L475`) or the NUCLEO-F429ZI
//! (`rc_boot::layout::F429`).
//!
//! **The flash** is one file of the board's whole flash (the L475's 1 MiB, the F429's 2 MiB;
//! offset 0 is `0x0800_0000`), held in memory and written through to the file at every erase and
//! write: erased `0xFF`, a write ANDed into what is there (NOR flash), on the layout's write unit
//! (the L475: 8-byte words; the F429: 4-byte words). An erase lies in one region, on that
//! region's unit: the layout's page in ACTIVE and DFU (the L475: 2 KiB; the F429: 128 KiB
//! sectors), its small page in STATE and the settings (the L475: 2 KiB; the F429: 16 KiB
//! sectors); the bootloader's and the spare regions are never erased. Only ACTIVE, DFU and
//! STATE are used; the bootloader's and the settings' pages stay erased. A new file starts
//! erased: ACTIVE empty, STATE without a mark.
//!
//! **The partitions** embassy-boot works on are [`Part`]s, each with its erase unit as its
//! `NorFlash::ERASE_SIZE`, as the board's bootloader builds them: embassy-boot's page is ACTIVE's
//! and DFU's unit (the F429: 128 KiB), its state word STATE's write unit, and STATE is erased in
//! its own unit (the F429: one 16 KiB sector).
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
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use protocol::plc::update::{crc32, BootState, Target, UpdateError, UpdateJob};
use rc_boot::image::{Trailer, Version, MAGIC, TRAILER_LEN};
use rc_boot::layout::{Layout, Region, ERASED, F429, L475};
use rc_boot::update::verify_and_mark;

/// The board, its flash file and the key its firmware verifies images with.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DfuOptions {
    /// The flash file (the board's whole flash: the L475's 1 MiB, the F429's 2 MiB; created
    /// erased).
    pub path: PathBuf,
    /// The board id (BEGIN and the image's trailer must name it); its layout is
    /// `rc_boot::layout_of(board)`, and an id without one is refused.
    pub board: u16,
    /// The Ed25519 public key the "firmware" verifies images with (`None`: the TEST key).
    pub public_key: Option<[u8; 32]>,
}

/// Why a flash operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlashError {
    /// Outside the flash, outside the partition, or an erase outside the regions the board
    /// erases (the bootloader's and the spare ones).
    OutOfBounds,
    /// Not on the region's erase unit, or not on a write unit.
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

/// The whole flash of a layout, in memory and written through to its file. Offsets count from
/// the flash's first address (offset 0 is `0x0800_0000`).
pub struct FileFlash {
    mem: Vec<u8>,
    file: File,
    layout: &'static Layout,
}

impl FileFlash {
    /// Opens the file (created erased if missing or empty); it must be the layout's size.
    pub fn open(path: &std::path::Path, layout: &'static Layout) -> io::Result<FileFlash> {
        let len = layout.flash.len();
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
        Ok(FileFlash { mem, file, layout })
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

    /// The region holding offset `at` and its erase unit: ACTIVE and DFU erase in the
    /// layout's pages (the F429: 128 KiB sectors), STATE and the settings in its small pages
    /// (the F429: 16 KiB sectors). `None` elsewhere: the bootloader's region and the spare
    /// ones, which the board never erases.
    pub fn erase_unit(&self, at: u32) -> Option<(Region, u32)> {
        let l = self.layout;
        let address = l.flash.start.checked_add(at)?;
        [
            (l.active, l.page),
            (l.dfu, l.page),
            (l.state, l.small_page),
            (l.settings, l.small_page),
        ]
        .into_iter()
        .find(|(r, _)| (r.start..r.end).contains(&address))
    }

    /// Reads `bytes.len()` bytes at `at`.
    pub fn read(&self, at: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        let range = self.range(at, bytes.len())?;
        bytes.copy_from_slice(self.mem.get(range).ok_or(FlashError::OutOfBounds)?);
        Ok(())
    }

    /// Erases `from..to`: inside one region, on that region's erase unit.
    pub fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        if from > to {
            return Err(FlashError::OutOfBounds);
        }
        let range = self.range(from, (to - from) as usize)?;
        if from == to {
            return Ok(());
        }
        let (region, unit) = self.erase_unit(from).ok_or(FlashError::OutOfBounds)?;
        if to > region.end - self.layout.flash.start {
            return Err(FlashError::OutOfBounds);
        }
        if !from.is_multiple_of(unit) || !to.is_multiple_of(unit) {
            return Err(FlashError::NotAligned);
        }
        self.mem
            .get_mut(range.clone())
            .ok_or(FlashError::OutOfBounds)?
            .fill(ERASED);
        self.persist(range)
    }

    /// Writes `bytes` at `at`, on whole write units (NOR flash: a write only clears bits).
    pub fn write(&mut self, at: u32, bytes: &[u8]) -> Result<(), FlashError> {
        let word = self.layout.word;
        if !at.is_multiple_of(word) || !bytes.len().is_multiple_of(word as usize) {
            return Err(FlashError::NotAligned);
        }
        let range = self.range(at, bytes.len())?;
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

/// One partition of the flash with its own erase unit `ERASE` and the flash's write unit
/// `WRITE`, as the board's bootloader builds them (bootloader/src/main.rs): embassy-boot takes
/// its page from ACTIVE's and DFU's `ERASE_SIZE` and its state word from STATE's `WRITE_SIZE`,
/// and embassy-embedded-hal's `BlockingPartition` has the flash's one unit for all, which the
/// F429's 16 KiB STATE sector beside its 128 KiB ACTIVE and DFU sectors cannot have. Offsets
/// count from the partition's start; nothing outside it is reached.
pub struct Part<'a, const ERASE: usize, const WRITE: usize> {
    flash: &'a Shared,
    /// The partition's first offset in the flash.
    start: u32,
    len: u32,
}

impl<'a, const ERASE: usize, const WRITE: usize> Part<'a, ERASE, WRITE> {
    fn new(flash: &'a Shared, layout: &Layout, region: Region) -> Self {
        Part {
            flash,
            start: region.offset_from(layout.flash.start),
            len: region.len(),
        }
    }

    /// The flash's offset of `offset..offset + len`, if it lies inside the partition.
    fn at(&self, offset: u32, len: usize) -> Result<u32, FlashError> {
        let len = u32::try_from(len).map_err(|_| FlashError::OutOfBounds)?;
        match offset.checked_add(len) {
            Some(end) if end <= self.len => Ok(self.start + offset),
            _ => Err(FlashError::OutOfBounds),
        }
    }
}

impl<const ERASE: usize, const WRITE: usize> ErrorType for Part<'_, ERASE, WRITE> {
    type Error = FlashError;
}

impl<const ERASE: usize, const WRITE: usize> ReadNorFlash for Part<'_, ERASE, WRITE> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        let at = self.at(offset, bytes.len())?;
        self.flash.lock(|f| f.borrow().read(at, bytes))
    }

    fn capacity(&self) -> usize {
        self.len as usize
    }
}

impl<const ERASE: usize, const WRITE: usize> NorFlash for Part<'_, ERASE, WRITE> {
    const WRITE_SIZE: usize = WRITE;
    const ERASE_SIZE: usize = ERASE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        let at = self.at(from, to.saturating_sub(from) as usize)?;
        if from > to || !from.is_multiple_of(ERASE as u32) || !to.is_multiple_of(ERASE as u32) {
            return Err(FlashError::NotAligned);
        }
        self.flash
            .lock(|f| f.borrow_mut().erase(at, at + (to - from)))
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        let at = self.at(offset, bytes.len())?;
        if !offset.is_multiple_of(WRITE as u32) || !bytes.len().is_multiple_of(WRITE) {
            return Err(FlashError::NotAligned);
        }
        self.flash.lock(|f| f.borrow_mut().write(at, bytes))
    }
}

/// The erase and write units of the layouts the host models, as (ACTIVE and DFU's erase unit,
/// STATE's erase unit, the write unit): each a partition type's constants, so each its own
/// instance of the generic steps below.
const L475_UNITS: (u32, u32, u32) = (L475.page, L475.small_page, L475.word);
const F429_UNITS: (u32, u32, u32) = (F429.page, F429.small_page, F429.word);

/// Which partition types a layout takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Units {
    /// 2 KiB pages everywhere, 8-byte words.
    L475,
    /// 128 KiB sectors for ACTIVE and DFU, a 16 KiB one for STATE, 4-byte words.
    F429,
}

impl Units {
    fn of(layout: &Layout) -> Option<Units> {
        match (layout.page, layout.small_page, layout.word) {
            L475_UNITS => Some(Units::L475),
            F429_UNITS => Some(Units::F429),
            _ => None,
        }
    }
}

/// Calls a generic step of [`Board`] with the partition types of its layout:
/// `units!(self.step(args))` is `self.step::<PAGE, SMALL, WORD>(args)`.
macro_rules! units {
    ($board:ident . $step:ident ( $($arg:expr),* )) => {
        match $board.units {
            Units::L475 => $board.$step::<
                { L475_UNITS.0 as usize },
                { L475_UNITS.1 as usize },
                { L475_UNITS.2 as usize },
            >($($arg),*),
            Units::F429 => $board.$step::<
                { F429_UNITS.0 as usize },
                { F429_UNITS.1 as usize },
                { F429_UNITS.2 as usize },
            >($($arg),*),
        }
    };
}

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
    layout: &'static Layout,
    units: Units,
    board: u16,
    key: [u8; 32],
    /// The state told to the node at the last start.
    boot: BootState,
    /// The trial (or the rollback) is still to be confirmed with `mark_booted`.
    unconfirmed: bool,
}

/// The flash error of a step, as the node's `UpdateError`.
fn flash<T, E>(r: Result<T, E>) -> Result<T, UpdateError> {
    r.map_err(|_| UpdateError::Flash)
}

impl Board {
    /// Opens the flash file of the board's layout (`rc_boot::layout_of`); nothing is booted yet
    /// ([`Board::boot`]). A board id without a layout is refused (`InvalidInput`).
    pub fn open(options: &DfuOptions) -> io::Result<Board> {
        let unknown = |why: &str| {
            io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "--board-id 0x{:04X}: {why} (--dfu models l475 = 0x{:04X} and f429 = 0x{:04X})",
                    options.board,
                    rc_boot::BOARD_L475,
                    rc_boot::BOARD_F429
                ),
            )
        };
        let layout = rc_boot::layout_of(options.board)
            .ok_or_else(|| unknown("no board with a bootloader has this id"))?;
        let units =
            Units::of(layout).ok_or_else(|| unknown("its flash's units are not modelled"))?;
        let flash = FileFlash::open(&options.path, layout)
            .map_err(|e| io::Error::new(e.kind(), format!("{}: {e}", options.path.display())))?;
        Ok(Board {
            flash: Mutex::new(RefCell::new(flash)),
            layout,
            units,
            board: options.board,
            key: options.public_key.unwrap_or(rc_boot::TEST_PUBLIC_KEY),
            boot: BootState::Unknown,
            unconfirmed: false,
        })
    }

    /// ACTIVE or DFU: erased in the layout's pages.
    fn big<const PAGE: usize, const WORD: usize>(&self, r: Region) -> Part<'_, PAGE, WORD> {
        Part::new(&self.flash, self.layout, r)
    }

    /// STATE: erased in the layout's small pages.
    fn state<const SMALL: usize, const WORD: usize>(&self) -> Part<'_, SMALL, WORD> {
        Part::new(&self.flash, self.layout, self.layout.state)
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

    /// embassy-boot's `prepare_boot`, then its `read_state`.
    fn prepare<const PAGE: usize, const SMALL: usize, const WORD: usize>(
        &self,
    ) -> io::Result<(State, State)> {
        let mut bl = BootLoader::new(BootLoaderConfig {
            active: self.big::<PAGE, WORD>(self.layout.active),
            dfu: self.big::<PAGE, WORD>(self.layout.dfu),
            state: self.state::<SMALL, WORD>(),
        });
        let mut buf = vec![0u8; rc_boot::BOOT_BUF_LEN];
        let prepared = bl
            .prepare_boot(&mut buf)
            .map_err(|e| io::Error::other(format!("prepare_boot: {e:?}")))?;
        let after = bl
            .read_state(&mut buf)
            .map_err(|e| io::Error::other(format!("read_state: {e:?}")))?;
        Ok((prepared, after))
    }

    /// A reset: embassy-boot's `prepare_boot` on the flash, then what ACTIVE runs.
    pub fn boot(&mut self) -> io::Result<Started> {
        let (prepared, after) = units!(self.prepare())?;
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
            at += self.layout.word as usize;
        }
        None
    }

    /// Whether the running firmware waits for its confirmation.
    pub fn unconfirmed(&self) -> bool {
        self.unconfirmed
    }

    /// embassy-boot's `mark_booted` in STATE.
    fn mark_booted<const PAGE: usize, const SMALL: usize, const WORD: usize>(
        &self,
    ) -> io::Result<()> {
        let mut aligned = [0u8; WORD];
        BlockingFirmwareState::new(self.state::<SMALL, WORD>(), &mut aligned)
            .mark_booted()
            .map_err(|e| io::Error::other(format!("mark_booted: {e:?}")))
    }

    /// The trial passed: embassy-boot's `mark_booted`. The new state to tell the node.
    pub fn confirm(&mut self) -> io::Result<BootState> {
        units!(self.mark_booted())?;
        self.unconfirmed = false;
        if self.boot == BootState::Trial {
            self.boot = BootState::Confirmed;
        }
        Ok(self.boot)
    }

    /// An erase of DFU for an image of `len` bytes (whole pages), a mark taken back first:
    /// `Some(0)` if there was one.
    fn erase_dfu<const PAGE: usize, const SMALL: usize, const WORD: usize>(
        &self,
        len: u32,
    ) -> Result<Option<u32>, UpdateError> {
        let mut unmarked = None;
        {
            let mut aligned = [0u8; WORD];
            let mut state = BlockingFirmwareState::new(self.state::<SMALL, WORD>(), &mut aligned);
            if flash(state.get_state())? == State::Swap {
                flash(state.mark_booted())?;
                unmarked = Some(0);
            }
        }
        let end = len
            .div_ceil(self.layout.page)
            .saturating_mul(self.layout.page)
            .min(self.layout.dfu.len());
        flash(self.big::<PAGE, WORD>(self.layout.dfu).erase(0, end))?;
        Ok(unmarked)
    }

    /// A chunk into DFU, padded with erased bytes to whole words.
    fn write_dfu<const PAGE: usize, const SMALL: usize, const WORD: usize>(
        &self,
        offset: u32,
        bytes: &[u8],
    ) -> Result<Option<u32>, UpdateError> {
        let mut padded = bytes.to_vec();
        padded.resize(bytes.len().next_multiple_of(WORD), ERASED);
        flash(
            self.big::<PAGE, WORD>(self.layout.dfu)
                .write(offset, &padded),
        )?;
        Ok(None)
    }

    /// FINISH: the image's CRC-32, then its trailer and signature, and the swap mark.
    fn finish<const PAGE: usize, const SMALL: usize, const WORD: usize>(
        &self,
        len: u32,
        crc: u32,
    ) -> Result<Option<u32>, UpdateError> {
        let mut image = vec![0u8; len as usize];
        flash(self.big::<PAGE, WORD>(self.layout.dfu).read(0, &mut image))?;
        if crc32(&image) != crc {
            return Err(UpdateError::Flash);
        }
        let mut aligned = [0u8; WORD];
        let mut updater = BlockingFirmwareUpdater::new(
            FirmwareUpdaterConfig {
                dfu: self.big::<PAGE, WORD>(self.layout.dfu),
                state: self.state::<SMALL, WORD>(),
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

    /// Carries out `job`: `Ok(Some(v))` when FINISH marked an image of version `v`
    /// (`major << 24 | minor << 16 | patch`), `Ok(Some(0))` when an erase took a mark back.
    pub fn carry_out(&mut self, job: &UpdateJob<'_>) -> Result<Option<u32>, UpdateError> {
        match *job {
            UpdateJob::Erase { len } => {
                // DFU holds the previous firmware during a trial: the rollback's copy.
                if self.boot == BootState::Trial && self.unconfirmed {
                    return Err(UpdateError::OnTrial);
                }
                units!(self.erase_dfu(len))
            }
            UpdateJob::Write { offset, bytes } => units!(self.write_dfu(offset, bytes)),
            UpdateJob::Finish { len, crc32 } => units!(self.finish(len, crc32)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flash(name: &str, layout: &'static Layout) -> (FileFlash, PathBuf) {
        let path = std::env::temp_dir().join(format!("board-{name}-{}", std::process::id()));
        let _ = std::fs::remove_file(&path);
        (FileFlash::open(&path, layout).expect("open"), path)
    }

    /// An offset of the flash file.
    fn at(layout: &Layout, address: u32) -> u32 {
        address - layout.flash.start
    }

    #[test]
    fn the_f429_erases_in_its_regions_units_and_writes_words() {
        let (mut f, path) = flash("f429-units", &F429);
        assert_eq!(f.mem.len(), 2 * 1024 * 1024);
        let dfu = at(&F429, F429.dfu.start);
        let state = at(&F429, F429.state.start);
        // DFU: 128 KiB sectors only.
        assert_eq!(f.erase(dfu, dfu + 16 * 1024), Err(FlashError::NotAligned));
        assert_eq!(f.erase(dfu, dfu + 2048), Err(FlashError::NotAligned));
        assert_eq!(f.erase(dfu, dfu + 128 * 1024), Ok(()));
        // STATE: its 16 KiB sector, not beyond it (sector 15 is spare), not half of it.
        assert_eq!(f.erase(state, state + 16 * 1024), Ok(()));
        assert_eq!(
            f.erase(state, state + 8 * 1024),
            Err(FlashError::NotAligned)
        );
        assert_eq!(
            f.erase(state, state + 32 * 1024),
            Err(FlashError::OutOfBounds)
        );
        // The bootloader's region and the spare sector 11: never erased.
        assert_eq!(f.erase(0, 128 * 1024), Err(FlashError::OutOfBounds));
        assert_eq!(
            f.erase(at(&F429, 0x080E_0000), at(&F429, 0x0810_0000)),
            Err(FlashError::OutOfBounds)
        );
        // 4-byte words; a write only clears bits.
        assert_eq!(f.write(dfu + 4, &[0x0F; 4]), Ok(()));
        assert_eq!(f.write(dfu + 4, &[0xF0, 0xFF, 0xFF, 0xFF]), Ok(()));
        assert_eq!(f.bytes(dfu + 4, 4), &[0x00, 0x0F, 0x0F, 0x0F]);
        assert_eq!(f.write(dfu + 2, &[0; 4]), Err(FlashError::NotAligned));
        assert_eq!(f.write(dfu, &[0; 2]), Err(FlashError::NotAligned));
        // Written through to the file.
        let file = std::fs::read(&path).expect("file");
        assert_eq!(
            &file[dfu as usize + 4..dfu as usize + 8],
            &[0x00, 0x0F, 0x0F, 0x0F]
        );
        let _ = std::fs::remove_file(&path);
    }

    #[test]
    fn the_l475_erases_pages_and_writes_double_words() {
        let (mut f, path) = flash("l475-units", &L475);
        assert_eq!(f.mem.len(), 1024 * 1024);
        let dfu = at(&L475, L475.dfu.start);
        let state = at(&L475, L475.state.start);
        assert_eq!(f.erase(dfu + 2048, dfu + 4096), Ok(()));
        assert_eq!(f.erase(state, state + 2048), Ok(()));
        assert_eq!(f.erase(dfu, dfu + 1024), Err(FlashError::NotAligned));
        assert_eq!(f.write(dfu + 8, &[0; 8]), Ok(()));
        assert_eq!(f.write(dfu + 4, &[0; 8]), Err(FlashError::NotAligned));
        assert_eq!(f.write(dfu, &[0; 4]), Err(FlashError::NotAligned));
        let _ = std::fs::remove_file(&path);
    }

    #[test]
    fn a_partition_has_its_own_erase_unit_and_stays_inside() {
        let (f, path) = flash("f429-parts", &F429);
        let shared: Shared = Mutex::new(RefCell::new(f));
        let mut dfu = Part::<{ 128 * 1024 }, 4>::new(&shared, &F429, F429.dfu);
        let mut state = Part::<{ 16 * 1024 }, 4>::new(&shared, &F429, F429.state);
        assert_eq!(dfu.capacity(), 896 * 1024);
        assert_eq!(state.capacity(), 16 * 1024);
        assert_eq!(state.erase(0, 16 * 1024), Ok(()));
        assert_eq!(dfu.erase(0, 16 * 1024), Err(FlashError::NotAligned));
        assert_eq!(state.erase(0, 32 * 1024), Err(FlashError::OutOfBounds));
        assert_eq!(state.write(16 * 1024 - 4, &[0; 4]), Ok(()));
        assert_eq!(
            state.write(16 * 1024, &[0; 4]),
            Err(FlashError::OutOfBounds)
        );
        let mut word = [0xAA; 4];
        state.read(16 * 1024 - 4, &mut word).expect("read");
        assert_eq!(word, [0; 4]);
        let _ = std::fs::remove_file(&path);
    }

    #[test]
    fn an_id_without_a_layout_is_refused() {
        let path = std::env::temp_dir().join(format!("board-unknown-{}", std::process::id()));
        let options = DfuOptions {
            path: path.clone(),
            board: 0x1234,
            public_key: None,
        };
        let e = Board::open(&options).err().expect("refused");
        assert_eq!(e.kind(), io::ErrorKind::InvalidInput);
        assert!(e.to_string().contains("0x1234"), "{e}");
        assert!(!path.exists());
        let f429 = Board::open(&DfuOptions {
            board: rc_boot::BOARD_F429,
            ..options
        })
        .expect("f429");
        assert_eq!(
            f429.target(),
            Target {
                board: 0x0429,
                partition: 768 * 1024
            }
        );
        assert_eq!(f429.units, Units::F429);
        let _ = std::fs::remove_file(&path);
    }
}
