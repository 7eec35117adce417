//! The host rig: a RAM flash like the L475's (2 KiB pages, 8-byte writes, erased 0xFF, a word
//! written only when erased) that can lose power after a given number of operations, and
//! helpers that run embassy-boot's own `BootLoader` and `BlockingFirmwareUpdater` over it.
#![allow(dead_code)]

use std::cell::RefCell;

use embassy_boot::{
    BlockingFirmwareUpdater, BootError, BootLoader, BootLoaderConfig, FirmwareUpdaterConfig, State,
};
use embassy_embedded_hal::flash::partition::BlockingPartition;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use rc_boot::image::{sign, SecretKey, Version};
use rc_boot::layout::{Layout, Region, ERASED, PAGE, WORD};
use rc_boot::update::verify_and_mark;
use rc_boot::BOARD_L475;

/// How an operation hit by the power cut is left.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tear {
    /// Not applied at all.
    Nothing,
    /// Applied to its first half (pages or words); the next page half erased or the next word
    /// partly programmed (some of its 0 bits still 1).
    Half,
    /// Every byte it touches left as garbage.
    Garbage,
}

pub const TEARS: [Tear; 3] = [Tear::Nothing, Tear::Half, Tear::Garbage];

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SimError {
    /// The power is off.
    PowerCut,
    OutOfBounds,
    NotAligned,
}

impl NorFlashError for SimError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            SimError::PowerCut => NorFlashErrorKind::Other,
            SimError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            SimError::NotAligned => NorFlashErrorKind::NotAligned,
        }
    }
}

/// The flash, from the layout's first address (offset 0).
#[derive(Clone, Default)]
pub struct SimFlash {
    pub mem: Vec<u8>,
    /// Erase and write operations carried out (or cut) since the cut was armed.
    pub ops: usize,
    /// The operation (counted from 0) at which the power fails; `None`: it never does.
    pub cut_at: Option<usize>,
    pub tear: Option<Tear>,
    /// The power is off: every operation fails.
    pub dead: bool,
    rng: u64,
}

impl SimFlash {
    pub fn new(len: u32) -> Self {
        SimFlash {
            mem: vec![ERASED; len as usize],
            tear: Some(Tear::Nothing),
            ..Default::default()
        }
    }

    /// Loses power at operation `n` (0: the next one), leaving it as `tear` says.
    pub fn arm(&mut self, n: usize, tear: Tear) {
        self.ops = 0;
        self.cut_at = Some(n);
        self.tear = Some(tear);
        self.dead = false;
        self.rng = 0x9E37_79B9_7F4A_7C15 ^ (n as u64) << 8 ^ tear as u64;
    }

    /// Power back, no cut armed, the operation counter at 0 (a reboot).
    pub fn power_on(&mut self) {
        self.ops = 0;
        self.cut_at = None;
        self.dead = false;
    }

    fn random(&mut self) -> u8 {
        // xorshift64*
        self.rng ^= self.rng >> 12;
        self.rng ^= self.rng << 25;
        self.rng ^= self.rng >> 27;
        (self.rng.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 56) as u8
    }

    pub fn region(&self, r: Region, base: u32) -> &[u8] {
        let s = (r.start - base) as usize;
        &self.mem[s..s + r.len() as usize]
    }

    /// Whether this operation goes through: counts it, and at the cut returns the tear.
    fn gate(&mut self) -> Result<Option<Tear>, SimError> {
        if self.dead {
            return Err(SimError::PowerCut);
        }
        let n = self.ops;
        self.ops += 1;
        if self.cut_at == Some(n) {
            self.dead = true;
            return Ok(self.tear);
        }
        Ok(None)
    }

    fn program_word(&mut self, at: usize, data: &[u8]) {
        let word = &self.mem[at..at + WORD as usize];
        let erased = word.iter().all(|&b| b == ERASED);
        let zeros = data.iter().all(|&b| b == 0);
        // The L4 refuses to program a double word that is not erased (PROGERR), except with
        // all zeros. embassy-boot must never need more.
        assert!(
            erased || zeros,
            "write onto a programmed word at {at:#x}: {word:02x?} <- {data:02x?}"
        );
        for (m, d) in self.mem[at..at + WORD as usize].iter_mut().zip(data) {
            *m &= *d;
        }
    }
}

impl ErrorType for SimFlash {
    type Error = SimError;
}

impl ReadNorFlash for SimFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), SimError> {
        if self.dead {
            return Err(SimError::PowerCut);
        }
        let s = offset as usize;
        let src = self
            .mem
            .get(s..s + bytes.len())
            .ok_or(SimError::OutOfBounds)?;
        bytes.copy_from_slice(src);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.mem.len()
    }
}

impl NorFlash for SimFlash {
    const WRITE_SIZE: usize = WORD as usize;
    const ERASE_SIZE: usize = PAGE as usize;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), SimError> {
        let (from, to) = (from as usize, to as usize);
        if from > to || to > self.mem.len() {
            return Err(SimError::OutOfBounds);
        }
        if !from.is_multiple_of(PAGE as usize) || !to.is_multiple_of(PAGE as usize) {
            return Err(SimError::NotAligned);
        }
        match self.gate()? {
            None => self.mem[from..to].fill(ERASED),
            Some(Tear::Nothing) => return Err(SimError::PowerCut),
            Some(Tear::Half) => {
                let pages = (to - from) / PAGE as usize;
                let done = from + pages / 2 * PAGE as usize;
                self.mem[from..done].fill(ERASED);
                if done < to {
                    self.mem[done..done + PAGE as usize / 2].fill(ERASED);
                }
                return Err(SimError::PowerCut);
            }
            Some(Tear::Garbage) => {
                for i in from..to {
                    self.mem[i] = self.random();
                }
                return Err(SimError::PowerCut);
            }
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), SimError> {
        let at = offset as usize;
        if at + bytes.len() > self.mem.len() {
            return Err(SimError::OutOfBounds);
        }
        if !at.is_multiple_of(WORD as usize) || !bytes.len().is_multiple_of(WORD as usize) {
            return Err(SimError::NotAligned);
        }
        let words = bytes.len() / WORD as usize;
        let tear = self.gate()?;
        let applied = match tear {
            None => words,
            Some(Tear::Nothing) => 0,
            Some(Tear::Half) => words / 2,
            Some(Tear::Garbage) => 0,
        };
        for w in 0..applied {
            let o = w * WORD as usize;
            self.program_word(at + o, &bytes[o..o + WORD as usize]);
        }
        match tear {
            None => Ok(()),
            Some(Tear::Nothing) => Err(SimError::PowerCut),
            Some(Tear::Half) => {
                // The word being programmed: some of its 0 bits made it, some did not.
                if applied < words {
                    let o = applied * WORD as usize;
                    for i in 0..WORD as usize {
                        let keep = self.random();
                        let b = &mut self.mem[at + o + i];
                        *b &= bytes[o + i] | keep;
                    }
                }
                Err(SimError::PowerCut)
            }
            Some(Tear::Garbage) => {
                for i in at..at + bytes.len() {
                    self.mem[i] = self.random();
                }
                Err(SimError::PowerCut)
            }
        }
    }
}

pub type Part<'a> = BlockingPartition<'a, NoopRawMutex, SimFlash>;
type Shared = Mutex<NoopRawMutex, RefCell<SimFlash>>;

fn part<'a>(m: &'a Shared, l: &Layout, r: Region) -> Part<'a> {
    BlockingPartition::new(m, r.offset_from(l.flash.start), r.len())
}

/// A board: its layout and its flash.
#[derive(Clone)]
pub struct Rig {
    pub layout: Layout,
    pub flash: SimFlash,
    /// The length of the buffer given to `prepare_boot`.
    pub boot_buf: usize,
}

impl Rig {
    pub fn new(layout: Layout, boot_buf: usize) -> Self {
        assert_eq!(layout.check(), Ok(()));
        Rig {
            flash: SimFlash::new(layout.flash.len()),
            layout,
            boot_buf,
        }
    }

    fn shared<R>(&mut self, f: impl FnOnce(&Shared, &Layout) -> R) -> R {
        let m = Mutex::new(RefCell::new(std::mem::take(&mut self.flash)));
        let r = f(&m, &self.layout);
        self.flash = m.into_inner().into_inner();
        r
    }

    /// The bootloader's one call at reset: embassy-boot's `prepare_boot`.
    pub fn boot(&mut self) -> Result<State, BootError> {
        let buf_len = self.boot_buf;
        self.shared(|m, l| {
            let mut bl = BootLoader::new(BootLoaderConfig {
                active: part(m, l, l.active),
                dfu: part(m, l, l.dfu),
                state: part(m, l, l.state),
            });
            let mut buf = vec![0; buf_len];
            bl.prepare_boot(&mut buf)
        })
    }

    /// Reboots (power on, no cut) until `prepare_boot` returns; at most `tries` times.
    pub fn reboot_until_ok(&mut self, tries: usize) -> State {
        for _ in 0..tries {
            self.flash.power_on();
            if let Ok(s) = self.boot() {
                return s;
            }
        }
        panic!("prepare_boot failed {tries} times in a row with the power on");
    }

    /// Runs `f` with embassy-boot's updater, as the application would.
    pub fn app<R>(
        &mut self,
        f: impl FnOnce(&mut BlockingFirmwareUpdater<'_, Part<'_>, Part<'_>>) -> R,
    ) -> R {
        self.shared(|m, l| {
            let mut aligned = [0; WORD as usize];
            let mut u = BlockingFirmwareUpdater::new(
                FirmwareUpdaterConfig {
                    dfu: part(m, l, l.dfu),
                    state: part(m, l, l.state),
                },
                &mut aligned,
            );
            f(&mut u)
        })
    }

    /// embassy-boot's swap mark written directly (`BlockingFirmwareState::mark_updated`), as
    /// an application does after `rc_boot::update::Verifier` approved the image.
    pub fn mark_updated_unchecked(&mut self) {
        self.shared(|m, l| {
            let mut aligned = [0; WORD as usize];
            let mut s = embassy_boot::BlockingFirmwareState::new(part(m, l, l.state), &mut aligned);
            s.mark_updated().unwrap();
        })
    }

    pub fn active(&self) -> Vec<u8> {
        self.flash
            .region(self.layout.active, self.layout.flash.start)
            .to_vec()
    }

    pub fn dfu(&self) -> Vec<u8> {
        self.flash
            .region(self.layout.dfu, self.layout.flash.start)
            .to_vec()
    }

    pub fn state_bytes(&self) -> Vec<u8> {
        self.flash
            .region(self.layout.state, self.layout.flash.start)
            .to_vec()
    }

    /// Programs ACTIVE directly (the factory image, written by the programmer).
    pub fn flash_active(&mut self, bytes: &[u8]) {
        let s = (self.layout.active.start - self.layout.flash.start) as usize;
        let len = self.layout.active.len() as usize;
        assert!(bytes.len() <= len);
        self.flash.mem[s..s + len].fill(ERASED);
        self.flash.mem[s..s + bytes.len()].copy_from_slice(bytes);
    }

    /// The transfer: the image written into DFU from offset 0 in chunks of the link's size
    /// (232 bytes, the last one padded to 8), through embassy-boot's `write_firmware` (which
    /// erases each page as it reaches it).
    pub fn transfer(&mut self, image: &[u8]) -> Result<(), embassy_boot::FirmwareUpdaterError> {
        self.app(|u| {
            for (i, chunk) in image.chunks(232).enumerate() {
                let mut c = chunk.to_vec();
                c.resize(c.len().div_ceil(8) * 8, ERASED);
                u.write_firmware(i * 232, &c)?;
            }
            Ok(())
        })
    }
}

/// A pseudo-random application of `len` bytes, different for each `seed`.
pub fn app_bytes(len: usize, seed: u8) -> Vec<u8> {
    let mut x = 0x1234_5678u32 ^ (seed as u32) << 24 | 1;
    (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            (x >> 7) as u8
        })
        .collect()
}

/// The key the tests sign with: the crate's public TEST key.
pub fn test_key() -> SecretKey {
    SecretKey(rc_boot::TEST_KEY_SEED)
}

/// Another key, whose signatures the board must refuse.
pub fn other_key() -> SecretKey {
    SecretKey([0x24; 32])
}

pub fn signed(app: &[u8], board: u16, key: &SecretKey) -> Vec<u8> {
    sign(
        app,
        board,
        Version {
            major: 1,
            minor: 0,
            patch: 7,
        },
        key,
    )
    .unwrap()
}

/// A layout scaled down: 64 KiB in two banks of 16 pages, a 4-page bootloader, ACTIVE 12
/// pages, DFU 13, STATE 1, settings 1.
pub fn small_layout() -> Layout {
    let p = PAGE;
    let r = |a: u32, b: u32| Region {
        start: a * p,
        end: b * p,
    };
    Layout {
        flash: r(0, 32),
        bank2: 16 * p,
        page: p,
        small_page: p,
        word: WORD,
        bootloader: r(0, 4),
        active: r(4, 16),
        dfu: r(16, 29),
        state: r(30, 31),
        settings: r(31, 32),
    }
}

/// A board running `old` with a new image marked; returns the rig, `old` as ACTIVE holds it
/// and the new ACTIVE the swap must produce (DFU's first ACTIVE-size bytes).
pub fn marked(layout: Layout, buf: usize, old_seed: u8, new_seed: u8) -> (Rig, Vec<u8>, Vec<u8>) {
    let mut rig = Rig::new(layout, buf);
    let max = layout.max_image() as usize;
    rig.flash_active(&app_bytes(max - 100, old_seed));
    let image = signed(&app_bytes(max - 96 - 13, new_seed), BOARD_L475, &test_key());
    rig.transfer(&image).unwrap();
    let key = test_key().public_key();
    rig.app(|u| verify_and_mark(u, image.len() as u32, BOARD_L475, max as u32, &key))
        .unwrap();
    let old = rig.active();
    let new = rig.dfu()[..layout.active.len() as usize].to_vec();
    assert_ne!(old, new);
    (rig, old, new)
}

/// Panics unless ACTIVE holds exactly `old` or exactly `new`; true for `new`.
pub fn holds_one_of(rig: &Rig, old: &[u8], new: &[u8]) -> bool {
    let a = rig.active();
    if a == old {
        false
    } else if a == new {
        true
    } else {
        let off_old = a.iter().zip(old).filter(|(x, y)| x != y).count();
        let off_new = a.iter().zip(new).filter(|(x, y)| x != y).count();
        panic!("ACTIVE is a mix ({off_old} bytes off the old, {off_new} off the new)");
    }
}
