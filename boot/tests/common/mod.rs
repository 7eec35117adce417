//! The host rig: a RAM NOR flash with a chip's sectors and write unit (the L475's 2 KiB pages and
//! 8-byte writes, or the F429's 16/64/128 KiB sectors and 4-byte writes; erased 0xFF, a word
//! written only when erased) that can lose power after a given number of operations, and
//! helpers that run embassy-boot's own `BootLoader` and `BlockingFirmwareUpdater` over it.
//!
//! embassy-boot takes each partition's erase unit from its `NorFlash::ERASE_SIZE`, a constant
//! (its page is the larger of ACTIVE's and DFU's). So the rig gives ACTIVE and DFU one flash type
//! and STATE another ([`Chip::Pages`], [`Chip::SmallPages`]: [`Sectors`] with the layout's
//! `page` and `small_page`), both windows on the same [`SimFlash`], as embassy-stm32 gives each
//! region of sectors of one size its own type. The `SimFlash` itself refuses an erase that does
//! not start and end on its chip's sector boundaries, whatever the type claimed.
#![allow(dead_code)]

use std::cell::RefCell;
use std::marker::PhantomData;
use std::rc::Rc;

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
use rc_boot::layout::{
    Layout, Region, ERASED, F429_SECTOR, F429_SMALL_SECTOR, F429_WORD, PAGE, WORD,
};
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

/// The flash, from the layout's first address (offset 0), in its chip's sectors.
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
    /// Each sector's first offset, in order; the next one's (or the flash's end) ends it.
    starts: Vec<u32>,
    /// The write unit, in bytes.
    word: usize,
}

impl SimFlash {
    /// `len` bytes of the L475's flash: 2 KiB pages, 8-byte words.
    pub fn new(len: u32) -> Self {
        assert!(len.is_multiple_of(PAGE));
        Self::with_sectors(&vec![PAGE; (len / PAGE) as usize], WORD)
    }

    /// A flash of these sectors, in order from offset 0, written in `word`s.
    pub fn with_sectors(sectors: &[u32], word: u32) -> Self {
        let mut starts = Vec::with_capacity(sectors.len());
        let mut at = 0;
        for &s in sectors {
            assert!(s > 0 && s.is_multiple_of(word));
            starts.push(at);
            at += s;
        }
        SimFlash {
            mem: vec![ERASED; at as usize],
            tear: Some(Tear::Nothing),
            starts,
            word: word as usize,
            ..Default::default()
        }
    }

    /// The sector holding `offset`, as offsets `start..end`.
    pub fn sector_at(&self, offset: u32) -> Option<Region> {
        if offset as usize >= self.mem.len() {
            return None;
        }
        let i = self.starts.partition_point(|&s| s <= offset) - 1;
        Some(Region {
            start: self.starts[i],
            end: self.bound(i + 1),
        })
    }

    /// Where sector `i` starts (the flash's end for the one past the last).
    fn bound(&self, i: usize) -> u32 {
        self.starts.get(i).copied().unwrap_or(self.mem.len() as u32)
    }

    /// Whether a sector starts (or the flash ends) at `offset`.
    fn on_boundary(&self, offset: u32) -> bool {
        offset as usize == self.mem.len() || self.starts.binary_search(&offset).is_ok()
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
        let word = &self.mem[at..at + self.word];
        let erased = word.iter().all(|&b| b == ERASED);
        let zeros = data.iter().all(|&b| b == 0);
        // The L4 refuses to program a double word that is not erased (PROGERR), except with
        // all zeros; the F4 would program it, but embassy-boot must never need more.
        assert!(
            erased || zeros,
            "write onto a programmed word at {at:#x}: {word:02x?} <- {data:02x?}"
        );
        for (m, d) in self.mem[at..at + self.word].iter_mut().zip(data) {
            *m &= *d;
        }
    }

    pub fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), SimError> {
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

    /// Erases the sectors `from..to`: both ends on sector boundaries, as the chip (and
    /// embassy-stm32's driver) takes an erase, whatever the partition's type claimed.
    pub fn erase(&mut self, from: u32, to: u32) -> Result<(), SimError> {
        if from > to || to as usize > self.mem.len() {
            return Err(SimError::OutOfBounds);
        }
        if !self.on_boundary(from) || !self.on_boundary(to) {
            return Err(SimError::NotAligned);
        }
        let first = self.starts.partition_point(|&s| s < from);
        let last = self.starts.partition_point(|&s| s < to);
        let (from, to) = (from as usize, to as usize);
        match self.gate()? {
            None => self.mem[from..to].fill(ERASED),
            Some(Tear::Nothing) => return Err(SimError::PowerCut),
            Some(Tear::Half) => {
                // The first half of the sectors erased, then half of the next one.
                let done = first + (last - first) / 2;
                let end = self.bound(done) as usize;
                self.mem[from..end].fill(ERASED);
                if done < last {
                    let half = (self.bound(done + 1) as usize - end) / 2;
                    self.mem[end..end + half].fill(ERASED);
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

    /// Programs `bytes` at `offset`, whole words only.
    pub fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), SimError> {
        let at = offset as usize;
        let word = self.word;
        if at + bytes.len() > self.mem.len() {
            return Err(SimError::OutOfBounds);
        }
        if !at.is_multiple_of(word) || !bytes.len().is_multiple_of(word) {
            return Err(SimError::NotAligned);
        }
        let words = bytes.len() / word;
        let tear = self.gate()?;
        let applied = match tear {
            None => words,
            Some(Tear::Nothing) => 0,
            Some(Tear::Half) => words / 2,
            Some(Tear::Garbage) => 0,
        };
        let dest = &mut self.mem[at..at + applied * word];
        if dest.iter().all(|&b| b == ERASED) {
            // All erased (a page copy, the common case): each word is programmed as given.
            dest.copy_from_slice(&bytes[..applied * word]);
        } else {
            for w in 0..applied {
                let o = w * word;
                self.program_word(at + o, &bytes[o..o + word]);
            }
        }
        match tear {
            None => Ok(()),
            Some(Tear::Nothing) => Err(SimError::PowerCut),
            Some(Tear::Half) => {
                // The word being programmed: some of its 0 bits made it, some did not.
                if applied < words {
                    let o = applied * word;
                    for i in 0..word {
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

/// The flash as a `NorFlash` of one erase unit and one write unit, as a flash driver's region
/// type is: embassy-boot reads `ERASE_SIZE` and `WRITE_SIZE` from the type. Every window of a
/// rig shares one [`SimFlash`], which checks each erase against the chip's real sectors.
pub struct Sectors<const ERASE: usize, const WRITE: usize>(Rc<RefCell<SimFlash>>);

impl<const E: usize, const W: usize> From<Rc<RefCell<SimFlash>>> for Sectors<E, W> {
    fn from(flash: Rc<RefCell<SimFlash>>) -> Self {
        assert_eq!(
            flash.borrow().word,
            W,
            "the type's write unit is not the flash's"
        );
        Sectors(flash)
    }
}

impl<const E: usize, const W: usize> ErrorType for Sectors<E, W> {
    type Error = SimError;
}

impl<const E: usize, const W: usize> ReadNorFlash for Sectors<E, W> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), SimError> {
        self.0.borrow_mut().read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.0.borrow().mem.len()
    }
}

impl<const E: usize, const W: usize> NorFlash for Sectors<E, W> {
    const WRITE_SIZE: usize = W;
    const ERASE_SIZE: usize = E;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), SimError> {
        self.0.borrow_mut().erase(from, to)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), SimError> {
        self.0.borrow_mut().write(offset, bytes)
    }
}

/// A chip: its sectors, and the flash types its driver gives the partitions.
pub trait Chip: Clone + Default + std::fmt::Debug {
    /// ACTIVE's and DFU's flash type: erase unit `Layout::page`.
    type Pages: NorFlash<Error = SimError> + From<Rc<RefCell<SimFlash>>>;
    /// STATE's flash type: erase unit `Layout::small_page`.
    type SmallPages: NorFlash<Error = SimError> + From<Rc<RefCell<SimFlash>>>;
    /// The sizes of the chip's sectors, in order from the flash's first address.
    fn sectors(layout: &Layout) -> Vec<u32>;
}

/// The STM32L475's flash: 2 KiB pages everywhere, 8-byte writes (and the scaled-down layouts').
#[derive(Clone, Copy, Debug, Default)]
pub struct L4;

impl Chip for L4 {
    type Pages = Sectors<{ PAGE as usize }, { WORD as usize }>;
    type SmallPages = Sectors<{ PAGE as usize }, { WORD as usize }>;

    fn sectors(layout: &Layout) -> Vec<u32> {
        vec![PAGE; (layout.flash.len() / PAGE) as usize]
    }
}

/// The STM32F429ZI's 2 MiB flash: each bank of 1 MiB is four 16 KiB sectors, one of 64 KiB and
/// seven of 128 KiB (RM0090, "Flash module organization", dual bank); 4-byte writes
/// (embassy-stm32 programs at x32 parallelism). embassy-stm32 gives each bank's run of sectors of
/// one size its own region type (BANK_2_REGION_1: 16 KiB sectors; BANK_n_REGION_3: 128 KiB).
#[derive(Clone, Copy, Debug, Default)]
pub struct F4;

/// The F429's sectors of one bank, in order.
pub const F429_BANK_SECTORS: [u32; 12] = [
    F429_SMALL_SECTOR,
    F429_SMALL_SECTOR,
    F429_SMALL_SECTOR,
    F429_SMALL_SECTOR,
    64 * 1024,
    F429_SECTOR,
    F429_SECTOR,
    F429_SECTOR,
    F429_SECTOR,
    F429_SECTOR,
    F429_SECTOR,
    F429_SECTOR,
];

impl Chip for F4 {
    type Pages = Sectors<{ F429_SECTOR as usize }, { F429_WORD as usize }>;
    type SmallPages = Sectors<{ F429_SMALL_SECTOR as usize }, { F429_WORD as usize }>;

    fn sectors(layout: &Layout) -> Vec<u32> {
        let bank: u32 = F429_BANK_SECTORS.iter().sum();
        assert_eq!(bank, 1024 * 1024);
        assert_eq!(layout.flash.len(), 2 * bank, "the F429ZI's flash is 2 MiB");
        assert_eq!(layout.bank2, layout.flash.start + bank);
        F429_BANK_SECTORS.repeat(2)
    }
}

/// Whether `layout` sits on `flash`'s sectors: each region starts and ends on a sector
/// boundary, and ACTIVE's and DFU's sectors are all `page` long, STATE's and the settings' all
/// `small_page` (an erase of a partition's unit must be an erase of whole sectors).
pub fn on_sectors(layout: &Layout, flash: &SimFlash) -> Result<(), String> {
    let base = layout.flash.start;
    for (name, r, unit) in [
        ("ACTIVE", layout.active, layout.page),
        ("DFU", layout.dfu, layout.page),
        ("STATE", layout.state, layout.small_page),
        ("settings", layout.settings, layout.small_page),
    ] {
        let mut at = r.start - base;
        while at < r.end - base {
            let s = flash
                .sector_at(at)
                .ok_or_else(|| format!("{name} runs past the flash at {:#x}", at + base))?;
            if s.start != at || s.len() != unit {
                return Err(format!(
                    "{name}: at {:#x}, the chip's sector is {:#x}..{:#x}, not {unit} bytes from there",
                    at + base,
                    s.start + base,
                    s.end + base
                ));
            }
            at = s.end;
        }
        if at != r.end - base {
            return Err(format!("{name} does not end on a sector"));
        }
    }
    Ok(())
}

pub type Part<'a, T> = BlockingPartition<'a, NoopRawMutex, T>;

fn part<'a, T: NorFlash>(
    m: &'a Mutex<NoopRawMutex, RefCell<T>>,
    l: &Layout,
    r: Region,
) -> Part<'a, T> {
    BlockingPartition::new(m, r.offset_from(l.flash.start), r.len())
}

/// A board: its layout, its flash and the board id its images carry.
#[derive(Clone)]
pub struct Rig<C: Chip = L4> {
    pub layout: Layout,
    pub flash: SimFlash,
    /// The length of the buffer given to `prepare_boot`.
    pub boot_buf: usize,
    /// The board id its images are signed for and checked against.
    pub board: u16,
    /// What the flash holds outside ACTIVE, DFU and STATE (the bootloader, the settings, the
    /// spare sectors), as offsets and bytes: programmed at the start, and nothing may change it.
    outside: Rc<Vec<(usize, Vec<u8>)>>,
    chip: PhantomData<fn() -> C>,
}

impl Rig {
    /// An L475 board (or a scaled-down one with the L475's units).
    pub fn new(layout: Layout, boot_buf: usize) -> Self {
        Rig::on(layout, BOARD_L475, boot_buf)
    }
}

impl<C: Chip> Rig<C> {
    /// A board of chip `C` with this layout, its images for `board`.
    pub fn on(layout: Layout, board: u16, boot_buf: usize) -> Self {
        assert_eq!(layout.check(), Ok(()));
        let rig = Self::unchecked(layout, board, boot_buf);
        if let Err(e) = on_sectors(&layout, &rig.flash) {
            panic!("the layout is not on the chip's sectors: {e}");
        }
        rig
    }

    /// [`Rig::on`] without the layout's own check nor the check against the chip's sectors:
    /// for the tests that show what embassy-boot and the chip make of a broken layout.
    pub fn unchecked(layout: Layout, board: u16, boot_buf: usize) -> Self {
        // The partitions' types carry the layout's units (embassy-boot reads them there).
        assert_eq!(C::Pages::ERASE_SIZE, layout.page as usize);
        assert_eq!(C::SmallPages::ERASE_SIZE, layout.small_page as usize);
        assert_eq!(C::Pages::WRITE_SIZE, layout.word as usize);
        assert_eq!(C::SmallPages::WRITE_SIZE, layout.word as usize);
        let mut flash = SimFlash::with_sectors(&C::sectors(&layout), layout.word);
        assert_eq!(flash.mem.len(), layout.flash.len() as usize);
        // Everything but the partitions programmed with bytes of its own.
        let mut parts = [layout.active, layout.dfu, layout.state].map(|r| {
            let s = r.offset_from(layout.flash.start) as usize;
            (s, s + r.len() as usize)
        });
        parts.sort();
        let mut outside = Vec::new();
        let mut at = 0;
        for (start, end) in parts
            .into_iter()
            .chain([(flash.mem.len(), flash.mem.len())])
        {
            if at < start {
                let bytes = app_bytes(start - at, outside.len() as u8 ^ 0x5A);
                flash.mem[at..start].copy_from_slice(&bytes);
                outside.push((at, bytes));
            }
            at = at.max(end);
        }
        Rig {
            flash,
            layout,
            boot_buf,
            board,
            outside: Rc::new(outside),
            chip: PhantomData,
        }
    }

    /// Panics unless the bootloader, the settings and the spare sectors hold what they held at
    /// the start: embassy-boot erases and writes only ACTIVE, DFU and STATE.
    pub fn check_outside(&self) {
        for (at, bytes) in self.outside.iter() {
            let now = &self.flash.mem[*at..*at + bytes.len()];
            if now != &bytes[..] {
                let first = now.iter().zip(bytes).position(|(a, b)| a != b).unwrap_or(0);
                panic!(
                    "the flash changed outside the partitions at {:#x}",
                    self.layout.flash.start as usize + at + first
                );
            }
        }
    }

    /// Runs `f` with ACTIVE, DFU and STATE as partitions: ACTIVE and DFU of type `C::Pages`
    /// (one flash, as the driver's region), STATE of type `C::SmallPages`, all on this flash.
    fn parts<R>(
        &mut self,
        f: impl FnOnce(Part<'_, C::Pages>, Part<'_, C::Pages>, Part<'_, C::SmallPages>) -> R,
    ) -> R {
        let flash = Rc::new(RefCell::new(std::mem::take(&mut self.flash)));
        let l = self.layout;
        let r = {
            let pages = Mutex::new(RefCell::new(C::Pages::from(flash.clone())));
            let small = Mutex::new(RefCell::new(C::SmallPages::from(flash.clone())));
            f(
                part(&pages, &l, l.active),
                part(&pages, &l, l.dfu),
                part(&small, &l, l.state),
            )
        };
        self.flash = Rc::try_unwrap(flash)
            .ok()
            .expect("a window outlived the call")
            .into_inner();
        r
    }

    /// The bootloader's one call at reset: embassy-boot's `prepare_boot`.
    pub fn boot(&mut self) -> Result<State, BootError> {
        let buf_len = self.boot_buf;
        self.parts(|active, dfu, state| {
            let mut bl = BootLoader::new(BootLoaderConfig { active, dfu, state });
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
        f: impl FnOnce(
            &mut BlockingFirmwareUpdater<'_, Part<'_, C::Pages>, Part<'_, C::SmallPages>>,
        ) -> R,
    ) -> R {
        let word = self.layout.word as usize;
        self.parts(|_, dfu, state| {
            let mut aligned = vec![0; word];
            let mut u =
                BlockingFirmwareUpdater::new(FirmwareUpdaterConfig { dfu, state }, &mut aligned);
            f(&mut u)
        })
    }

    /// embassy-boot's swap mark written directly (`BlockingFirmwareState::mark_updated`), as
    /// an application does after `rc_boot::update::Verifier` approved the image.
    pub fn mark_updated_unchecked(&mut self) {
        let word = self.layout.word as usize;
        self.parts(|_, _, state| {
            let mut aligned = vec![0; word];
            let mut s = embassy_boot::BlockingFirmwareState::new(state, &mut aligned);
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
    marked_on(Rig::new(layout, buf), old_seed, new_seed)
}

/// [`marked`] on any board: `rig` fresh from [`Rig::on`]; the image is signed for `rig.board`,
/// as large as the layout takes.
pub fn marked_on<C: Chip>(
    mut rig: Rig<C>,
    old_seed: u8,
    new_seed: u8,
) -> (Rig<C>, Vec<u8>, Vec<u8>) {
    let layout = rig.layout;
    let board = rig.board;
    let max = layout.max_image() as usize;
    rig.flash_active(&app_bytes(max - 100, old_seed));
    let image = signed(&app_bytes(max - 96 - 13, new_seed), board, &test_key());
    rig.transfer(&image).unwrap();
    let key = test_key().public_key();
    rig.app(|u| verify_and_mark(u, image.len() as u32, board, max as u32, &key))
        .unwrap();
    let old = rig.active();
    let new = rig.dfu()[..layout.active.len() as usize].to_vec();
    assert_ne!(old, new);
    (rig, old, new)
}

/// Panics unless ACTIVE holds exactly `old` or exactly `new` (and nothing changed outside the
/// partitions); true for `new`.
pub fn holds_one_of<C: Chip>(rig: &Rig<C>, old: &[u8], new: &[u8]) -> bool {
    rig.check_outside();
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
