//! The gateway's settings in flash, over any NOR flash: what the firmware loads at start-up and
//! stores when the PLC writes SAVE.
//!
//! A small log of records in a range of at least two erase pages. Every save appends one record
//! after the last one; the record with the highest sequence number is the one in force. The
//! records fill the pages one after the other, round the range: when the newest record's page
//! has no room left for the next one, the following page (cyclically: the one holding the
//! oldest records) is erased and written from its start. A page is thus erased only when the
//! range has filled up, oldest first, and wear is spread over every page of the range (the
//! first time round, each page is erased once more, before its first record). Nothing
//! is written but to erased (0xFF) flash, and a record is written in one go, at a position
//! aligned to the flash's write and read words (`WRITE_SIZE`, `READ_SIZE`: powers of two up to
//! 32 bytes, 2 on the F103, 8 on the L475).
//!
//! A record (`size` bytes: the first 9 + the item's, rounded up to the flash word):
//!
//! | Bytes | Value |
//! |---|---|
//! | 0 | `0xA5`: the start of a record |
//! | 1 | the item's length `n` (at most [`ITEM_LEN`]) |
//! | 2-5 | sequence number (u32, little endian): the newest record's plus one |
//! | 6..6+n | the item (below) |
//! | then 2 | CRC-16/MODBUS of the bytes before it (`protocol::modbus::crc`), low byte first |
//! | then to `size` | `0x00` (at least one: a record's last word is never erased-looking) |
//!
//! An item ([`ITEM_LEN`] bytes at most):
//!
//! | Bytes | Value |
//! |---|---|
//! | 0 | [`FORMAT`]: an item without it is not this store's, and is passed over |
//! | 1-4 | saves so far (u32, little endian): kept by a factory reset |
//! | 5-6 | starts that found the settings unreadable (u16, little endian) |
//! | 7.. | the settings record ([`RECORD_LEN`] bytes), or nothing after a factory reset |
//!
//! On the settings record's own version and CRC ([`Settings::decode`]), a record written by
//! another firmware is refused whole.
//!
//! Each operation first scans every page, word by word: a word starting a record whose CRC is
//! right is a record (the scan goes on after it); anything else (erased space, a record cut
//! short by a power loss, a page whose erase was cut short, another format) is passed over one
//! word at a time. A page's erased space starts after its last word that is not 0xFF, or after
//! the whole length that a record start there announces (a record cut short may have written
//! words of 0xFF): that is where the next record goes in the newest record's page.
//!
//! Power loss: a save writes one record, after erasing a page that holds none of the newest
//! records if it must. Cut anywhere, the record fails its CRC (or was not begun) and the
//! previous newest record stays in force: the old settings or the new ones, never a mix. (A
//! record damaged so that its CRC still matches, one chance in 65 536, would be taken: the
//! settings record's own CRC then stands behind it.) The sequence number wraps after 2³²
//! records, far beyond the flash's endurance.
//!
//! At start-up: an erased range (a new board) gives the defaults. A start whose newest record's
//! item is not this store's (or not a readable record), or whose range holds no record but is
//! not erased (a range in another format, such as the `sequential-storage` queue of the
//! firmware before this store; or a first save cut short), runs the defaults and counts it, in
//! a record of its own: the next start finds that record and runs the defaults without
//! counting again. Settings stored by firmware that kept them with `sequential-storage` are
//! thus not read: the user enters them again (or restores them), and the saves count starts
//! again from 0 (with one load error). A flash that cannot be read is never written over: the
//! counts it holds are unknown, and a later start may read it (a factory reset then erases the
//! whole range, the way out).
//!
//! (This store replaced `sequential-storage`'s queue: the same guarantees in 4.6 KB less flash
//! on both boards, measured by `scripts/size-report.sh`.)

#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing
    )
)]

use core::ops::Range;

use embedded_storage_async::nor_flash::NorFlash;
use protocol::modbus::crc;
use protocol::plc::settings::{Settings, RECORD_LEN};
use protocol::plc::{Boot, ConfigSource};

/// The first byte of every item this store writes.
pub const FORMAT: u8 = 0x5A;
/// The head of an item: the format, saves (u32) and load errors (u16).
const COUNTS_LEN: usize = 7;
/// The longest item: the counts and a settings record.
pub const ITEM_LEN: usize = COUNTS_LEN + RECORD_LEN;

/// The first byte of every record.
const MAGIC: u8 = 0xA5;
/// A record's head: the magic, the item's length and the sequence number.
const HEAD: usize = 6;
/// A record's tail: the CRC and at least one [`END`].
const TAIL: usize = 3;
/// What a record is padded with after its CRC.
const END: u8 = 0x00;
/// The longest flash word the store supports (the alignment of its buffer).
const MAX_WORD: usize = 32;

// The item's length fits the record's length byte.
const _: () = assert!(ITEM_LEN <= u8::MAX as usize);

/// The scratch buffer: the longest record, rounded up to the longest flash word, aligned like
/// one.
#[repr(align(32))]
struct Buffer([u8; Buffer::LEN]);

impl Buffer {
    const LEN: usize = (HEAD + ITEM_LEN + TAIL).div_ceil(MAX_WORD) * MAX_WORD;
}

/// Why the store could not do what it was asked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreError {
    /// The flash failed.
    Flash,
}

/// What a start found in flash.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Loaded {
    /// The stored settings, if there are readable ones.
    pub settings: Option<Settings>,
    /// Where the settings come from, saves and load errors so far (the reset cause is the
    /// firmware's to fill in).
    pub boot: Boot,
}

/// A record found in flash.
#[derive(Clone, Copy)]
struct Found {
    seq: u32,
    /// Its address.
    at: u32,
    /// Its item's length.
    len: usize,
}

/// What a scan of the range found.
#[derive(Clone, Copy)]
struct Scan {
    /// The newest record.
    newest: Option<Found>,
    /// The newest record whose item is this store's.
    ours: Option<Found>,
    /// The newest record's page (the first page if there is none) ...
    page: u32,
    /// ... and where its erased space starts (an offset in the page).
    free: usize,
    /// Whether the whole range is erased.
    blank: bool,
}

impl Scan {
    /// A range erased.
    const BLANK: Scan = Scan {
        newest: None,
        ours: None,
        page: 0,
        free: 0,
        blank: true,
    };

    /// Whether the newest item of ours is the newest record, or there is nothing at all.
    fn ours_last(&self) -> bool {
        match (self.ours, self.newest) {
            (Some(ours), Some(newest)) => ours.seq == newest.seq,
            (None, None) => self.blank,
            _ => false,
        }
    }
}

/// The settings store on `F`, in a range of at least two erase pages.
pub struct Store<F: NorFlash> {
    flash: F,
    /// The range's first address.
    start: u32,
    /// Its erase pages.
    pages: u32,
    buffer: Buffer,
}

impl<F: NorFlash> Store<F> {
    /// The flash word records are aligned to: the larger of the write and read sizes.
    const WORD: usize = if F::READ_SIZE > F::WRITE_SIZE {
        F::READ_SIZE
    } else {
        F::WRITE_SIZE
    };
    /// How much of a word's start is read to see whether a record starts there.
    const HEAD_READ: usize = HEAD.div_ceil(Self::WORD) * Self::WORD;
    /// An erase page's length.
    const PAGE: u32 = F::ERASE_SIZE as u32;

    /// A store on `flash` in `range`; `None` if the range is not whole erase pages, or fewer than
    /// two, or the flash's words are not powers of two up to 32 bytes.
    pub fn new(flash: F, range: Range<u32>) -> Option<Store<F>> {
        let word = Self::WORD;
        let whole_words = word.is_power_of_two()
            && word <= MAX_WORD
            && usize::try_from(Self::PAGE).is_ok_and(|page| page == F::ERASE_SIZE)
            && F::ERASE_SIZE.is_multiple_of(word)
            && range.start.is_multiple_of(Self::PAGE);
        let len = range.end.checked_sub(range.start)?;
        let pages = len.checked_div(Self::PAGE)?;
        if !whole_words || !len.is_multiple_of(Self::PAGE) || pages < 2 {
            return None;
        }
        Some(Store {
            flash,
            start: range.start,
            pages,
            buffer: Buffer([0; Buffer::LEN]),
        })
    }

    /// The flash back (the store is done with it).
    pub fn into_flash(self) -> F {
        self.flash
    }

    /// A record's length, with an item of `len` bytes.
    const fn size(len: usize) -> usize {
        (HEAD + len + TAIL).div_ceil(Self::WORD) * Self::WORD
    }

    /// `bytes` from the flash at `at` into the buffer.
    async fn read(&mut self, at: u32, len: usize) -> Result<&[u8], StoreError> {
        let bytes = self.buffer.0.get_mut(..len).ok_or(StoreError::Flash)?;
        self.flash
            .read(at, bytes)
            .await
            .map_err(|_| StoreError::Flash)?;
        Ok(bytes)
    }

    /// Every page, every record: see the module's description.
    async fn scan(&mut self) -> Result<Scan, StoreError> {
        let word = Self::WORD;
        let page_len = F::ERASE_SIZE;
        let mut scan = Scan::BLANK;
        for page in 0..self.pages {
            let base = self.start + page * Self::PAGE;
            // The page's offset up to which something was written.
            let (mut at, mut used) = (0, 0);
            while at < page_len {
                let addr = base + at as u32;
                let head = self.read(addr, Self::HEAD_READ.min(page_len - at)).await?;
                if head.iter().take(word).any(|&b| b != 0xFF) {
                    used = used.max(at + word);
                }
                let mut step = word;
                if let &[MAGIC, len, s0, s1, s2, s3, ..] = head {
                    let len = usize::from(len);
                    let size = Self::size(len);
                    if len <= ITEM_LEN && size <= page_len - at {
                        // Written up to there, maybe with words of 0xFF, if it was cut short.
                        used = used.max(at + size);
                        let record = self.read(addr, size).await?;
                        if let Some(item) = item(record, len) {
                            step = size;
                            let found = Found {
                                seq: u32::from_le_bytes([s0, s1, s2, s3]),
                                at: addr,
                                len,
                            };
                            if len >= COUNTS_LEN && item.first() == Some(&FORMAT) {
                                scan.ours = newer(scan.ours, found);
                            }
                            if scan.newest.is_none_or(|n| found.seq > n.seq) {
                                scan.newest = Some(found);
                                scan.page = page;
                            }
                        }
                    }
                }
                at += step;
            }
            if used > 0 {
                scan.blank = false;
            }
            if scan.page == page {
                scan.free = used;
            }
        }
        Ok(scan)
    }

    /// The scan, and the newest item of ours read into the buffer (an item with no counts and
    /// no settings if there is none); the item's length.
    async fn newest(&mut self) -> Result<(Scan, usize), StoreError> {
        let scan = self.scan().await?;
        Ok(match scan.ours {
            Some(ours) => {
                self.read(ours.at, Self::size(ours.len)).await?;
                (scan, ours.len)
            }
            None => {
                self.set_counts(0, 0);
                (scan, COUNTS_LEN)
            }
        })
    }

    /// The counts of the item in the buffer: saves, load errors.
    fn counts(&self) -> (u32, u16) {
        match self.buffer.0.get(HEAD..HEAD + COUNTS_LEN) {
            Some(&[_, s0, s1, s2, s3, e0, e1]) => (
                u32::from_le_bytes([s0, s1, s2, s3]),
                u16::from_le_bytes([e0, e1]),
            ),
            _ => (0, 0),
        }
    }

    /// The format and counts of the item in the buffer.
    fn set_counts(&mut self, saves: u32, load_errors: u16) {
        let head = [FORMAT]
            .into_iter()
            .chain(saves.to_le_bytes())
            .chain(load_errors.to_le_bytes());
        if let Some(counts) = self.buffer.0.get_mut(HEAD..HEAD + COUNTS_LEN) {
            for (to, from) in counts.iter_mut().zip(head) {
                *to = from;
            }
        }
    }

    /// Append the item of `len` bytes in the buffer as the newest record, after `scan`: in the
    /// newest record's page if it fits, else at the start of the next page, erased first.
    async fn append(&mut self, scan: &Scan, len: usize) -> Result<(), StoreError> {
        let size = Self::size(len);
        let (mut page, mut at) = (scan.page, scan.free);
        if size > F::ERASE_SIZE.saturating_sub(at) {
            page = (page + 1) % self.pages;
            at = 0;
            let from = self.start + page * Self::PAGE;
            self.flash
                .erase(from, from + Self::PAGE)
                .await
                .map_err(|_| StoreError::Flash)?;
        }
        let seq = scan.newest.map_or(0, |n| n.seq.wrapping_add(1));
        let [s0, s1, s2, s3] = seq.to_le_bytes();
        let record = self.buffer.0.get_mut(..size).ok_or(StoreError::Flash)?;
        let (body, tail) = record
            .split_at_mut_checked(HEAD + len)
            .ok_or(StoreError::Flash)?;
        for (to, from) in body.iter_mut().zip([MAGIC, len as u8, s0, s1, s2, s3]) {
            *to = from;
        }
        let sum = crc::to_wire(crc::checksum(body));
        tail.fill(END);
        for (to, from) in tail.iter_mut().zip(sum) {
            *to = from;
        }
        let addr = self.start + page * Self::PAGE + at as u32;
        self.flash
            .write(addr, record)
            .await
            .map_err(|_| StoreError::Flash)
    }

    /// Read the settings at start-up. Unreadable settings (a damaged record, another format,
    /// a flash error) give the defaults and are counted, in flash too.
    pub async fn load(&mut self) -> Loaded {
        let Ok((scan, mut len)) = self.newest().await else {
            // Not written over: the counts it holds are unknown, and a later start may read it.
            return Loaded {
                settings: None,
                boot: Boot {
                    source: ConfigSource::Damaged,
                    load_errors: 1,
                    save_count: 0,
                    reset: Boot::DEFAULT.reset,
                },
            };
        };
        let last = scan.ours_last();
        let record = self.buffer.0.get(HEAD + COUNTS_LEN..HEAD + len);
        let source = match (last, record) {
            // Nothing stored yet, or a factory reset since.
            (true, Some([])) => ConfigSource::Defaults,
            (true, Some(record)) if Settings::decode(record).is_ok() => ConfigSource::Flash,
            _ => ConfigSource::Damaged,
        };
        let (saves, mut load_errors) = self.counts();
        if source == ConfigSource::Damaged {
            load_errors = load_errors.saturating_add(1);
            self.set_counts(saves, load_errors);
            if !last {
                // Something else came after the last item of ours: not its settings, which
                // that replaced. The defaults from now on (this start is the one counted).
                len = COUNTS_LEN;
            }
            // A record of ours that does not decode stays as it was: every start counts it.
            // Best effort: a flash that will not take the write is counted next start again.
            let _ = self.append(&scan, len).await;
        }
        let settings = match (source, self.buffer.0.get(HEAD + COUNTS_LEN..HEAD + len)) {
            (ConfigSource::Flash, Some(record)) => Settings::decode(record).ok(),
            _ => None,
        };
        Loaded {
            settings,
            boot: Boot {
                source,
                load_errors,
                save_count: saves,
                reset: Boot::DEFAULT.reset,
            },
        }
    }

    /// Store `record` ([`Settings::encode`]) as the settings; the saves so far, this one
    /// included. If the power fails meanwhile, the next start finds the old settings or the
    /// new ones, never a mix.
    pub async fn save(&mut self, record: &[u8; RECORD_LEN]) -> Result<u32, StoreError> {
        // Refused if the flash cannot be read: the saves so far would be lost.
        let (scan, _) = self.newest().await?;
        let (saves, load_errors) = self.counts();
        let saves = saves.wrapping_add(1);
        self.set_counts(saves, load_errors);
        self.buffer
            .0
            .get_mut(HEAD + COUNTS_LEN..HEAD + ITEM_LEN)
            .ok_or(StoreError::Flash)?
            .copy_from_slice(record);
        self.append(&scan, ITEM_LEN).await?;
        Ok(saves)
    }

    /// Forget the settings: the next start uses the defaults. The counts stay, unless the flash
    /// cannot be read: then the whole range is erased (the way out of a range nothing can read).
    pub async fn factory_reset(&mut self) -> Result<(), StoreError> {
        let scan = match self.newest().await {
            Ok((scan, _)) => scan,
            Err(_) => {
                self.flash
                    .erase(self.start, self.start + self.pages * Self::PAGE)
                    .await
                    .map_err(|_| StoreError::Flash)?;
                self.set_counts(0, 0);
                Scan::BLANK
            }
        };
        self.append(&scan, COUNTS_LEN).await
    }
}

/// The item of `record` (an item of `len` bytes), if its CRC is right.
fn item(record: &[u8], len: usize) -> Option<&[u8]> {
    let (body, tail) = record.split_at_checked(HEAD + len)?;
    let sum = crc::to_wire(crc::checksum(body));
    (tail.get(..2)? == sum).then_some(body.get(HEAD..)?)
}

/// The newer of `found` and `than`.
fn newer(than: Option<Found>, found: Found) -> Option<Found> {
    match than {
        Some(than) if than.seq >= found.seq => Some(than),
        _ => Some(found),
    }
}
