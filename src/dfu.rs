//! The DFU partition: where a firmware image sent over the PLC link goes (feature `update`;
//! the transfer itself is `protocol::plc::update`'s). The gateway task carries out the node's
//! [`Action::Update`](crate::node::Action::Update) jobs here and reports each with
//! `Node::update_done` once it is whole.
//!
//! **In bounded steps.** A chunk is written as its job is handed out ([`Dfu::start`]: at most
//! 232 bytes, 29 double words of 90 µs at most, 2.6 ms); an erase or a verification is taken
//! there and then done one step per pass of the gateway task's loop ([`Dfu::step`]), between the
//! node's other actions: the lines are read, the stop input served and the watchdog fed between
//! two steps. A step is one 2 KiB page erased (the L475's page erase: 25 ms at most, datasheet)
//! or [`VERIFY_STEP`] bytes read back into the CRC-32. The partition is in bank 2 and the program runs from bank 1, so the CPU is not
//! stalled while the flash works (read-while-write), and embassy-stm32's blocking erase and write
//! leave the interrupts on (the UARTs keep filling their buffers), but the driver waits for the
//! flash: the gateway task does nothing else for up to 25 ms. So a job is handed out, and a step
//! taken, only while the bus is quiet (`Node::quiet_for_flash`: no axis moves or waits for a
//! job, no stop is owed): a move started during a transfer pauses it, and a stop that falls due
//! during a step is for an axis that stands. (The settings' SAVE waits as long.)
//!
//! **The board** (`hw`): bank 2 of the L475's flash up to the settings pages
//! (`board::l475::DFU_RANGE`, 504 KiB), written through the settings store's flash driver
//! (embassy-stm32's blocking one, with the data cache off around it: `l475::DcacheOff`): the
//! store never reads outside its own pages. A chunk whose length is not a multiple of the
//! flash's 8-byte word (an image's last) is padded with 0xFF, the erased value.
//!
//! **The emulator** (`emulator`): QEMU's `b-l475e-iot01a` models no flash interface (its flash
//! cannot be written), so the partition is [`EMU_PARTITION`] bytes of RAM: the transfer, the
//! steps and the verification run on the real ELF, the flash driver does not.
//!
//! **The mark** for the bootloader is not written yet: there is no bootloader (issue 37's
//! embassy-boot). FINISH checks the image's CRC-32 as read back and reports it ready; nothing
//! boots it.

use protocol::plc::update::{Crc32, Target, UpdateJob};

/// The board id an image must declare (BEGIN): the L475's, on the board and in the emulator
/// (the same firmware; `rcgw update --board 0x0475`).
pub const BOARD_ID: u16 = 0x0475;

/// The erase unit: a 2 KiB page of the L475 (the emulator erases its RAM in the same steps).
const PAGE: u32 = 2048;

/// Bytes read back into the CRC-32 per step (a few hundred µs on the board).
const VERIFY_STEP: u32 = 2048;

/// The flash's write unit: every write is whole double words.
#[cfg(feature = "hw")]
const WORD: usize = 8;

/// The emulator's partition, in RAM: 32 KiB of the 96 KiB the build links into (the other
/// statics and the deepest stack, the node in it, take about 16 KiB: `scripts/size-report.sh`).
#[cfg(feature = "emulator")]
pub const EMU_PARTITION: usize = 32 * 1024;

#[cfg(feature = "emulator")]
static EMU_RAM: static_cell::ConstStaticCell<[u8; EMU_PARTITION]> =
    static_cell::ConstStaticCell::new([0; EMU_PARTITION]);

/// Where the partition's bytes are, for one step.
#[cfg(feature = "hw")]
type Medium<'a> = Option<&'a mut crate::board::SettingsFlash>;
#[cfg(feature = "emulator")]
type Medium<'a> = &'a mut [u8];

/// The job under way.
#[derive(Clone, Copy)]
enum Job {
    None,
    /// Erasing from `next` (an offset in the partition) up to `end`.
    Erase {
        next: u32,
        end: u32,
    },
    /// Reading back from `next` up to `len`, into `crc`; `want` is the image's CRC-32.
    Verify {
        next: u32,
        len: u32,
        crc: Crc32,
        want: u32,
    },
}

/// The partition and the job under way.
pub struct Dfu {
    job: Job,
    /// The partition's bytes (the emulator's RAM).
    #[cfg(feature = "emulator")]
    ram: &'static mut [u8],
}

impl Dfu {
    /// No job; the emulator's RAM partition taken (once: the gateway task's).
    pub fn new() -> Dfu {
        Dfu {
            job: Job::None,
            #[cfg(feature = "emulator")]
            ram: EMU_RAM.take().as_mut_slice(),
        }
    }

    /// What the node is told: this board, and the partition's size.
    pub fn target() -> Target {
        #[cfg(feature = "hw")]
        let partition = {
            let range = crate::board::DFU_RANGE;
            range.end - range.start
        };
        #[cfg(feature = "emulator")]
        let partition = EMU_PARTITION as u32;
        Target {
            board: BOARD_ID,
            partition,
        }
    }

    /// A job is under way: the gateway task does not sleep until it is done.
    pub fn busy(&self) -> bool {
        !matches!(self.job, Job::None)
    }

    /// Takes `job` (the node hands out one at a time: a job under way is replaced, which the
    /// node never asks). A chunk is written at once (its bytes are the node's, lent for this
    /// call only): its result; an erase or a verification goes on in [`Dfu::step`]: `None`.
    #[inline(never)]
    pub fn start(
        &mut self,
        job: &UpdateJob<'_>,
        settings: &mut crate::settings::SavedSettings,
    ) -> Option<Result<(), ()>> {
        let partition = Dfu::target().partition;
        self.job = match *job {
            UpdateJob::Erase { len } => Job::Erase {
                next: 0,
                end: len.div_ceil(PAGE).saturating_mul(PAGE).min(partition),
            },
            UpdateJob::Write { offset, bytes } => {
                self.job = Job::None;
                #[cfg(feature = "hw")]
                return Some(write(&mut settings.flash(), offset, bytes));
                #[cfg(feature = "emulator")]
                {
                    let _ = settings;
                    return Some(write(&mut &mut *self.ram, offset, bytes));
                }
            }
            UpdateJob::Finish { len, crc32 } => Job::Verify {
                next: 0,
                len: len.min(partition),
                crc: Crc32::new(),
                want: crc32,
            },
        };
        None
    }

    /// One step of the job under way, on the board's flash (the settings store's driver); its
    /// result once the job is whole (for `Node::update_done`), `None` while it goes on or when
    /// there is none.
    #[cfg(feature = "hw")]
    #[inline(never)]
    pub fn step(
        &mut self,
        settings: &mut crate::settings::SavedSettings,
    ) -> Option<Result<(), ()>> {
        if !self.busy() {
            return None;
        }
        self.step_on(settings.flash())
    }

    /// One step of the job under way, in the emulator's RAM partition.
    #[cfg(feature = "emulator")]
    #[inline(never)]
    pub fn step(
        &mut self,
        _settings: &mut crate::settings::SavedSettings,
    ) -> Option<Result<(), ()>> {
        if !self.busy() {
            return None;
        }
        // Out of `self` while the step changes the job.
        let ram = core::mem::take(&mut self.ram);
        let result = self.step_on(&mut *ram);
        self.ram = ram;
        result
    }

    fn step_on(&mut self, mut medium: Medium<'_>) -> Option<Result<(), ()>> {
        let (next, result) = match self.job {
            Job::None => return None,
            Job::Erase { next, end } => {
                if next >= end {
                    (Job::None, Some(Ok(())))
                } else {
                    match erase(&mut medium, next, next + PAGE) {
                        Ok(()) => (
                            Job::Erase {
                                next: next + PAGE,
                                end,
                            },
                            None,
                        ),
                        Err(()) => (Job::None, Some(Err(()))),
                    }
                }
            }
            Job::Verify {
                next,
                len,
                mut crc,
                want,
            } => {
                if next >= len {
                    let result = if crc.finish() == want {
                        mark(&mut medium, len, want)
                    } else {
                        warn!("update: the image read back has another CRC-32");
                        Err(())
                    };
                    (Job::None, Some(result))
                } else {
                    let end = (next + VERIFY_STEP).min(len);
                    match read_into(&mut medium, next, end, &mut crc) {
                        Ok(()) => (
                            Job::Verify {
                                next: end,
                                len,
                                crc,
                                want,
                            },
                            None,
                        ),
                        Err(()) => (Job::None, Some(Err(()))),
                    }
                }
            }
        };
        self.job = next;
        result
    }
}

/// "Mark the image for the bootloader": nothing yet. TODO(issue 37, the bootloader): write
/// embassy-boot's state partition (its magic for a swap at the next start) here. Until then an
/// image reported ready is only checked, never started.
fn mark(_medium: &mut Medium<'_>, _len: u32, _crc32: u32) -> Result<(), ()> {
    Ok(())
}

/// Erases the partition's page at `from..to` (whole pages inside the partition).
#[cfg(feature = "hw")]
fn erase(flash: &mut Medium<'_>, from: u32, to: u32) -> Result<(), ()> {
    use embedded_storage::nor_flash::NorFlash;
    let base = crate::board::DFU_RANGE.start;
    if to > crate::board::DFU_RANGE.end - base {
        return Err(());
    }
    let flash = flash.as_deref_mut().ok_or(())?;
    flash.erase(base + from, base + to).map_err(|_| {
        warn!("update: erase at {:#x} failed", base + from);
    })
}

/// Writes `bytes` at `offset` of the partition (a multiple of the word): the whole words, then
/// the rest padded with 0xFF to one.
#[cfg(feature = "hw")]
fn write(flash: &mut Medium<'_>, offset: u32, bytes: &[u8]) -> Result<(), ()> {
    use embedded_storage::nor_flash::NorFlash;
    let base = crate::board::DFU_RANGE.start;
    let end = offset as usize + bytes.len().div_ceil(WORD) * WORD;
    if end > (crate::board::DFU_RANGE.end - base) as usize {
        return Err(());
    }
    let flash = flash.as_deref_mut().ok_or(())?;
    let whole = bytes.len() / WORD * WORD;
    let (words, rest) = bytes.split_at(whole);
    let mut result = flash.write(base + offset, words);
    if result.is_ok() && !rest.is_empty() {
        let mut word = [0xFF; WORD];
        if let Some(to) = word.get_mut(..rest.len()) {
            to.copy_from_slice(rest);
        }
        result = flash.write(base + offset + whole as u32, &word);
    }
    result.map_err(|_| {
        warn!("update: write at {:#x} failed", base + offset);
    })
}

/// Reads the partition's `from..to` into `crc`, a few words at a time.
#[cfg(feature = "hw")]
fn read_into(flash: &mut Medium<'_>, from: u32, to: u32, crc: &mut Crc32) -> Result<(), ()> {
    use embedded_storage::nor_flash::ReadNorFlash;
    let base = crate::board::DFU_RANGE.start;
    let flash = flash.as_deref_mut().ok_or(())?;
    let mut buf = [0u8; 64];
    let mut at = from;
    while at < to {
        let n = (to - at).min(buf.len() as u32);
        let part = buf.get_mut(..n as usize).ok_or(())?;
        flash.read(base + at, part).map_err(|_| ())?;
        crc.update(part);
        at += n;
    }
    Ok(())
}

/// Fills the RAM partition's `from..to` with the erased value.
#[cfg(feature = "emulator")]
fn erase(ram: &mut Medium<'_>, from: u32, to: u32) -> Result<(), ()> {
    ram.get_mut(from as usize..to as usize)
        .ok_or(())?
        .fill(0xFF);
    Ok(())
}

#[cfg(feature = "emulator")]
fn write(ram: &mut Medium<'_>, offset: u32, bytes: &[u8]) -> Result<(), ()> {
    let end = offset as usize + bytes.len();
    ram.get_mut(offset as usize..end)
        .ok_or(())?
        .copy_from_slice(bytes);
    Ok(())
}

#[cfg(feature = "emulator")]
fn read_into(ram: &mut Medium<'_>, from: u32, to: u32, crc: &mut Crc32) -> Result<(), ()> {
    crc.update(ram.get(from as usize..to as usize).ok_or(())?);
    Ok(())
}
