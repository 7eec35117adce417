//! The firmware update on the board (feature `update`): the DFU partition an image sent over the
//! PLC link goes into, its check, and the marks for the bootloader (the transfer itself is
//! `protocol::plc::update`'s; the layout, the image's signed trailer and the swap are
//! `rc_boot`'s and embassy-boot's). The gateway task carries out the node's
//! [`Action::Update`](crate::node::Action::Update) jobs here and reports each with
//! [`report`] once it is whole.
//!
//! **The jobs.** *Erase*: first, if an image is marked from earlier in this run, the mark is
//! taken back (embassy-boot's `mark_booted`: a mark must never point at a partition being
//! rewritten), then the pages the image needs, one per step. *Write*: a chunk, at once.
//! *Finish*: the image's trailer read and checked (`rc_boot::image::Trailer`: magic, CRC, this
//! board, the length the transfer declared, no larger than ACTIVE: else `NotAnImage`), then the
//! image read back 2 KiB a step into its CRC-32 (the transfer's, else `Flash`) and into the
//! SHA-512 of its signed part (`rc_boot::update::Verifier`, embassy-boot's scheme in steps), the
//! Ed25519 signature checked with the key built in (else `Signature`), and the image marked for
//! a swap at the next start (embassy-boot's `mark_updated`). Its version goes to BOOTSTAT.
//!
//! **A trial.** At the start the state partition tells what the bootloader did
//! ([`Dfu::start_up`]): a new image swapped in runs on trial, until [`Dfu::confirm`] sees the
//! node's `trial_passed` (the bus established, the PLC link answered) and confirms it
//! (`mark_booted`); a start before that, a hang (the IWDG) or a power cut brings the old one
//! back. While a trial runs, DFU holds the old firmware the bootloader would swap back: no
//! transfer may erase it (`OnTrial`), nor may another image be marked.
//!
//! **In bounded steps.** A chunk is written as its job is handed out (at most 232 bytes, 29
//! double words of 90 µs at most, 2.6 ms); an erase or a check is done one step per pass of the
//! gateway task's loop ([`Dfu::step`]), between the node's other actions: the lines are read,
//! the stop input served and the watchdog fed between two steps. A step is one 2 KiB page erased
//! (the L475's page erase: 25 ms at most, datasheet), [`VERIFY_STEP`] bytes read back into the
//! CRC-32 and the SHA-512, the signature checked, or a mark written (embassy-boot erases the four
//! STATE pages and writes a word: 100 ms at most). DFU and STATE are in bank 2 and the program
//! runs from bank 1, so the CPU is not stalled while the flash works (read-while-write), and
//! embassy-stm32's blocking erase and write leave the interrupts on (the UARTs keep filling
//! their buffers), but the driver waits for the flash: the gateway task does nothing else
//! meanwhile. So a job is handed out, a step taken and a trial confirmed only while the bus is
//! quiet (`Node::quiet_for_flash`: no axis moves or waits for a job, no stop is owed): a move
//! started during a transfer pauses it, and a stop that falls due during a step is for an axis
//! that stands.
//!
//! **The key.** The board build verifies with the public key named at build time
//! (`RC_GATEWAY_UPDATE_KEY`, build.rs); built without one, it refuses every image
//! (`Signature`). The emulator build verifies with rc-boot's public TEST key.
//!
//! **The board** (`hw`): DFU and STATE are windows on the settings store's flash driver
//! (embassy-stm32's blocking one, with the data cache off around it: `l475::DcacheOff`), which
//! never reads outside its own pages.
//!
//! **The emulator** (`emulator`): QEMU's `b-l475e-iot01a` models no flash interface (its flash
//! cannot be written), so DFU is [`EMU_PARTITION`](parts::EMU_PARTITION) bytes of RAM and STATE four pages of RAM: the
//! transfer, the steps, the signature check and embassy-boot's marks run on the real ELF; the
//! flash driver does not, and no swap follows (the bootloader reads the real, unwritten flash).

use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};
use protocol::plc::update::{BootState, Crc32, Target, UpdateError, UpdateJob};
use rc_boot::image::{trailer_offset, Trailer, TRAILER_LEN};
use rc_boot::update::{BlockingFirmwareState, State, Verifier};

use crate::node::Node;

mod parts;
use parts::{Home, Parts, UPDATE_KEY};

/// The board id an image must declare (BEGIN and its trailer): this board's (the emulator's is
/// the L475's: the same firmware).
pub const BOARD_ID: u16 = parts::BOARD_ID;

/// DFU's erase unit, one step of an Erase: a 2 KiB page of the L475 (the emulator erases its RAM
/// in the same steps), a 128 KiB sector of the F429 (erased without waiting: its steps look
/// whether it is done).
const PAGE: u32 = parts::LAYOUT.page;

/// How often a sector erase under way is looked at (the F429's 128 KiB sector: about 1 s).
const ERASE_LOOK: protocol::time::Duration = protocol::time::Duration::from_millis(10);

/// Bytes read back into the CRC-32 and the SHA-512 per step (a few ms on the board).
const VERIFY_STEP: u32 = 2048;

/// The flash's write unit (the L475: a double word; the F429: a word): every write is whole
/// units.
const WORD: usize = parts::LAYOUT.word as usize;

/// How a job went, for [`report`].
pub struct Outcome {
    result: Result<(), UpdateError>,
    /// The version of the image marked, with a Finish that marked one.
    marked: Option<u32>,
}

impl Outcome {
    fn failed(error: UpdateError) -> Outcome {
        Outcome {
            result: Err(error),
            marked: None,
        }
    }
}

impl From<Result<(), UpdateError>> for Outcome {
    fn from(result: Result<(), UpdateError>) -> Outcome {
        Outcome {
            result,
            marked: None,
        }
    }
}

/// Tells the node how a job went.
pub fn report(node: &mut Node, outcome: Outcome) {
    if let Some(version) = outcome.marked {
        node.set_image_version(version);
    }
    node.update_done(outcome.result);
}

/// The job under way.
// One job, held once in the gateway task's Dfu (no heap to box the verifier's 200-byte hash
// into): the size of the largest variant is the size of the one value there is.
#[allow(clippy::large_enum_variant)]
enum Job {
    None,
    /// Erasing from `next` (an offset in DFU) up to `end`.
    Erase {
        next: u32,
        end: u32,
    },
    /// Reading back from `next` up to `len` into `crc` (`want`: the transfer's CRC-32) and
    /// `signed`; then the signature, then the mark.
    Verify {
        next: u32,
        len: u32,
        crc: Crc32,
        want: u32,
        signed: Verifier,
        version: u32,
    },
}

/// DFU, STATE and the job under way.
pub struct Dfu {
    job: Job,
    /// What the bootloader did at this start.
    boot: BootState,
    /// A trial (or the old firmware after a rollback) not yet confirmed.
    unconfirmed: bool,
    /// Where DFU and STATE are.
    home: Home,
    /// The last step found the flash still erasing a sector.
    erasing: bool,
}

impl Dfu {
    /// No job; the emulator's RAM partitions taken (once: the gateway task's).
    pub fn new() -> Dfu {
        Dfu {
            job: Job::None,
            boot: BootState::Unknown,
            unconfirmed: false,
            home: Home::new(),
            erasing: false,
        }
    }

    /// What the node is told: this board, and the largest image (DFU's size, but no larger than
    /// ACTIVE, where the bootloader swaps it).
    pub fn target() -> Target {
        Target {
            board: BOARD_ID,
            partition: Home::LARGEST_IMAGE,
        }
    }

    /// Reads what the bootloader did at this start from the state partition: a swap (the new
    /// firmware on trial), a rollback, or nothing (confirmed). For BOOTSTAT.
    // Not inlined, as `confirm`: their frames (embassy-boot's state, a flash window) would sit
    // in the gateway loop's under every request the node serves.
    #[inline(never)]
    pub fn start_up(&mut self, settings: &mut crate::settings::SavedSettings) -> BootState {
        let state = self.home.parts(settings).state().and_then(|mut state| {
            let mut word = [0; WORD];
            BlockingFirmwareState::new(&mut state, &mut word)
                .get_state()
                .map_err(|_| ())
        });
        (self.boot, self.unconfirmed) = match state {
            Ok(State::Swap) => (BootState::Trial, true),
            Ok(State::Revert) => (BootState::RolledBack, true),
            Ok(_) => (BootState::Confirmed, false),
            // Unreadable: a word a power cut tore during a mark (an ECC error; the bootloader
            // read it as it could and started this firmware). Nothing is marked or erased until
            // `confirm` has rewritten the pages.
            Err(()) => (BootState::Unknown, true),
        };
        if self.unconfirmed {
            info!("update: a trial (or a rollback) until the bus and the PLC link answer");
        }
        self.boot
    }

    /// Confirms a trial once the node says it passed and the bus is quiet: embassy-boot's
    /// `mark_booted`, after which the bootloader keeps this firmware. (After a rollback the old
    /// firmware is confirmed the same way, so that the next image may be marked.)
    #[inline(never)]
    pub fn confirm(&mut self, node: &mut Node, settings: &mut crate::settings::SavedSettings) {
        if !self.unconfirmed || !node.trial_passed() || !node.quiet_for_flash() {
            return;
        }
        let confirmed = self.home.parts(settings).state().and_then(|mut state| {
            let mut word = [0; WORD];
            let marked = BlockingFirmwareState::new(&mut state, &mut word).mark_booted();
            if marked.is_ok() {
                return Ok(());
            }
            // The pages unreadable (a mark torn by a power cut: embassy-boot reads the magic
            // before it erases, and fails on the ECC error every time): erased whole, then the
            // mark. Safe: this firmware runs, so the swap or the revert before it was whole.
            warn!("update: the state pages are unreadable: erased");
            let capacity = state.capacity() as u32;
            state.erase(0, capacity).map_err(|_| ())?;
            BlockingFirmwareState::new(&mut state, &mut word)
                .mark_booted()
                .map_err(|_| ())
        });
        match confirmed {
            Ok(()) => {
                info!("update: this firmware confirmed");
                self.unconfirmed = false;
                if matches!(self.boot, BootState::Trial | BootState::Unknown) {
                    self.boot = BootState::Confirmed;
                    node.set_boot_state(BootState::Confirmed);
                }
            }
            // Tried again at the next quiet pass.
            Err(()) => warn!("update: the confirmation could not be written"),
        }
    }

    /// The firmware that runs is not confirmed yet (a trial, a rollback, unreadable STATE
    /// pages): [`Dfu::confirm`] has work to do. Asked before the call, so that the loop's passes
    /// do not carry its frame.
    pub fn unconfirmed(&self) -> bool {
        self.unconfirmed
    }

    /// A job is under way: the gateway task does not sleep until it is done.
    pub fn busy(&self) -> bool {
        !matches!(self.job, Job::None)
    }

    /// With a job under way, when its next step is due: at once, or (the flash erasing a sector
    /// without waiting: the F429) after [`ERASE_LOOK`], so that the gateway task sleeps in
    /// between instead of looking at FLASH_SR on every pass for a second or two (the other tasks
    /// run either way: the wait yields even when it is due at once).
    pub fn step_in(&self) -> protocol::time::Duration {
        if self.erasing {
            ERASE_LOOK
        } else {
            protocol::time::Duration(0)
        }
    }

    /// Takes `job` (the node hands out one at a time: a job under way is replaced, which the
    /// node never asks). A chunk is written at once (its bytes are the node's, lent for this
    /// call only), a refusal given at once: the outcome; an erase or a check goes on in
    /// [`Dfu::step`]: `None`.
    #[inline(never)]
    pub fn start(
        &mut self,
        job: &UpdateJob<'_>,
        settings: &mut crate::settings::SavedSettings,
    ) -> Option<Outcome> {
        self.job = Job::None;
        // DFU holds the firmware a trial would go back to, and no second image may be marked.
        if self.unconfirmed && !matches!(job, UpdateJob::Write { .. }) {
            return Some(Outcome::failed(UpdateError::OnTrial));
        }
        let mut parts = self.home.parts(settings);
        match *job {
            UpdateJob::Erase { len } => {
                // An image marked earlier in this run is unmarked before its pages go.
                let unmarked = parts.state().and_then(|mut state| {
                    let mut word = [0; WORD];
                    let mut marks = BlockingFirmwareState::new(&mut state, &mut word);
                    match marks.get_state() {
                        Ok(State::Swap) => marks.mark_booted().map_err(|_| ()),
                        Ok(_) => Ok(()),
                        Err(_) => Err(()),
                    }
                });
                if unmarked.is_err() {
                    return Some(Outcome::failed(UpdateError::Flash));
                }
                let partition = Dfu::target().partition;
                self.job = Job::Erase {
                    next: 0,
                    end: len.div_ceil(PAGE).saturating_mul(PAGE).min(partition),
                };
                None
            }
            UpdateJob::Write { offset, bytes } => Some(
                parts
                    .dfu()
                    .and_then(|mut dfu| write(&mut dfu, offset, bytes))
                    .map_err(|()| UpdateError::Flash)
                    .into(),
            ),
            UpdateJob::Finish { len, crc32 } => {
                let read = parts.dfu().map_err(|()| UpdateError::Flash);
                let trailer = match read.and_then(|mut dfu| read_trailer(&mut dfu, len)) {
                    Ok(trailer) => trailer,
                    Err(error) => return Some(Outcome::failed(error)),
                };
                let Ok(signed) = Verifier::new(&trailer) else {
                    return Some(Outcome::failed(UpdateError::NotAnImage));
                };
                self.job = Job::Verify {
                    next: 0,
                    len,
                    crc: Crc32::new(),
                    want: crc32,
                    signed,
                    version: trailer.version.to_u32(),
                };
                None
            }
        }
    }

    /// One step of the job under way: its outcome once the job is whole, `None` while it goes
    /// on or when there is none.
    #[inline(never)]
    pub fn step(&mut self, settings: &mut crate::settings::SavedSettings) -> Option<Outcome> {
        if !self.busy() {
            return None;
        }
        let job = core::mem::replace(&mut self.job, Job::None);
        self.erasing = false;
        let mut parts = self.home.parts(settings);
        let (next, outcome) = match job {
            Job::None => return None,
            Job::Erase { next, end } if next >= end => (Job::None, Some(Ok(()).into())),
            Job::Erase { next, end } => match parts.erase_step(next) {
                Err(nb::Error::WouldBlock) => {
                    self.erasing = true;
                    (Job::Erase { next, end }, None)
                }
                Ok(()) => (
                    Job::Erase {
                        next: next + PAGE,
                        end,
                    },
                    None,
                ),
                Err(nb::Error::Other(())) => (Job::None, Some(Outcome::failed(UpdateError::Flash))),
            },
            Job::Verify {
                next,
                len,
                crc,
                want,
                signed,
                version,
            } if next >= len => (
                Job::None,
                Some(finish(&mut parts, crc, want, signed, version)),
            ),
            Job::Verify {
                next,
                len,
                mut crc,
                want,
                mut signed,
                version,
            } => {
                let end = (next + VERIFY_STEP).min(len);
                match parts
                    .dfu()
                    .and_then(|mut dfu| read_into(&mut dfu, next, end, &mut crc, &mut signed))
                {
                    Ok(()) => (
                        Job::Verify {
                            next: end,
                            len,
                            crc,
                            want,
                            signed,
                            version,
                        },
                        None,
                    ),
                    Err(()) => (Job::None, Some(Outcome::failed(UpdateError::Flash))),
                }
            }
        };
        self.job = next;
        outcome
    }
}

/// The last check of a Finish, once the image is read back: its CRC-32, its signature, then
/// the mark.
fn finish(parts: &mut Parts<'_>, crc: Crc32, want: u32, signed: Verifier, version: u32) -> Outcome {
    if crc.finish() != want {
        warn!("update: the image read back has another CRC-32");
        return Outcome::failed(UpdateError::Flash);
    }
    let Some(key) = &UPDATE_KEY else {
        warn!("update: built without a key (RC_GATEWAY_UPDATE_KEY): no image is taken");
        return Outcome::failed(UpdateError::Signature);
    };
    if signed.finish(key).is_err() {
        warn!("update: the image's signature does not verify");
        return Outcome::failed(UpdateError::Signature);
    }
    let marked = parts.state().and_then(|mut state| {
        let mut word = [0; WORD];
        BlockingFirmwareState::new(&mut state, &mut word)
            .mark_updated()
            .map_err(|_| ())
    });
    match marked {
        Ok(()) => {
            info!("update: image {:#x} marked for the next start", version);
            Outcome {
                result: Ok(()),
                marked: Some(version),
            }
        }
        Err(()) => Outcome::failed(UpdateError::Flash),
    }
}

/// The image's trailer, read from the end of the `len` bytes in DFU and checked for this board
/// and the length the transfer declared.
fn read_trailer(dfu: &mut impl NorFlash, len: u32) -> Result<Trailer, UpdateError> {
    let at = trailer_offset(len).map_err(|_| UpdateError::NotAnImage)?;
    let mut raw = [0; TRAILER_LEN];
    dfu.read(at, &mut raw).map_err(|_| UpdateError::Flash)?;
    let trailer = Trailer::parse(&raw).map_err(|_| UpdateError::NotAnImage)?;
    trailer
        .check(BOARD_ID, len, parts::LAYOUT.max_image())
        .map_err(|_| UpdateError::NotAnImage)?;
    Ok(trailer)
}

/// Writes `bytes` at `offset` of DFU (a multiple of the word): the whole words, then the rest
/// padded with 0xFF (the erased value) to one.
fn write(dfu: &mut impl NorFlash, offset: u32, bytes: &[u8]) -> Result<(), ()> {
    let end = offset as usize + bytes.len().div_ceil(WORD) * WORD;
    if end > dfu.capacity() {
        return Err(());
    }
    let whole = bytes.len() / WORD * WORD;
    let (words, rest) = bytes.split_at(whole);
    let mut result = dfu.write(offset, words);
    if result.is_ok() && !rest.is_empty() {
        let mut word = [0xFF; WORD];
        if let Some(to) = word.get_mut(..rest.len()) {
            to.copy_from_slice(rest);
        }
        result = dfu.write(offset + whole as u32, &word);
    }
    result.map_err(|_| {
        warn!("update: write at {:#x} failed", offset);
    })
}

/// Reads DFU's `from..to` into `crc` and `signed`, a few words at a time.
fn read_into(
    dfu: &mut impl NorFlash,
    from: u32,
    to: u32,
    crc: &mut Crc32,
    signed: &mut Verifier,
) -> Result<(), ()> {
    let mut buf = [0u8; 64];
    let mut at = from;
    while at < to {
        let n = (to - at).min(buf.len() as u32);
        let part = buf.get_mut(..n as usize).ok_or(())?;
        dfu.read(at, part).map_err(|_| ())?;
        crc.update(part);
        signed.update(part);
        at += n;
    }
    Ok(())
}
