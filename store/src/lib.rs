//! The gateway's settings in flash, over any NOR flash: what the firmware loads at start-up and
//! stores when the PLC writes SAVE.
//!
//! A small log of records in a range of at least two erase pages. Every save appends one record
//! after the last one; the newest record (by sequence number) is the one in force. The records
//! fill the pages one after the other, round the range: when the newest record's page has no
//! room left for the next one, the following page (cyclically: the one holding the oldest
//! records) is erased, given its header and written from there on. A page is thus erased only
//! when the range has filled up, oldest first, and wear is spread over every page of the range.
//! Nothing is written but to erased (0xFF) flash, and a record is written in one go, at a
//! position aligned to the flash's write and read words (`WRITE_SIZE`, `READ_SIZE`: powers of
//! two up to 8 bytes; 4 on the F103 and the F429, 8 on the L475).
//!
//! A page starts with its header, the 8 bytes `RCGW 02 00 00 00`, written right after each erase
//! of it (with the page's first record). A page without it holds records of the layout before
//! (below), or nothing: erased, an erase cut short, another format. The store writes to a page
//! without a header only after erasing it again: records go only where an erase completed.
//!
//! A record (`size` bytes: the first 11 + the item's, rounded up to the flash word):
//!
//! | Bytes | Value |
//! |---|---|
//! | 0 | `0xC5`: the start of a record |
//! | 1 | the item's length `n` (at most [`ITEM_LEN`]) |
//! | 2-5 | sequence number (u32, little endian): the newest record's plus one |
//! | 6..6+n | the item (below) |
//! | then 4 | CRC-32 (IEEE, as zip's) of the bytes before it, little endian |
//! | then to `size` | `0x00`, each exactly (at least one byte) |
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
//! Each operation first scans every page, word by word: a word starting a record (of the page's
//! layout) whose CRC and padding are right is a record (the scan goes on after it); anything else
//! (erased space, a record cut short, a word the flash cannot read: the L475's ECC error after
//! a double word's programming was cut short) is passed over one word at a time. A page's erased
//! space starts after its last word that is not 0xFF (or unreadable), or after the whole length
//! a record start there announces: that is where the next record goes in the newest record's
//! page. Sequence numbers are compared as serial numbers (RFC 1982: `a` is newer than `b` when
//! `a - b`, wrapping, is below 2³¹), so no single value, not even 0xFFFFFFFF, can outrank every
//! record after it.
//!
//! Power loss: a save writes one record, after erasing a page that holds none of the newest
//! records (and writing its header) if it must. The flash programs a record unit after unit (a
//! half-word on the F103, a word on the F429: a record's last unit holds only CRC and padding;
//! a double word on the L475, whose ECC makes a double word cut short an unreadable word): a
//! record cut anywhere fails its CRC, or its padding is not all 0x00, or cannot be read, or was
//! not begun. A page whose erase was cut has no header, or (cut very early) holds records that
//! its erase has set bits of: a set bit in the padding, or the CRC-32, gives them away. The
//! previous newest record stays in force: the old settings or the new ones, never a mix. A
//! factory reset erases the other pages, writes the counts alone in a freshly erased page as
//! the newest record, and only then erases the newest settings' page: cut before that record is
//! whole, the settings stay; after, the defaults run, the counts kept.
//!
//! At start-up: an erased range (a new board) gives the defaults. Else the newest item of ours
//! is loaded. If its settings record does not decode ([`Settings::decode`]), the newest older
//! one that does is loaded instead (after a factory reset's item, or an item whose settings are a
//! newer firmware's format version, none is: the defaults); a start that found the newest
//! record unusable counts it (CFGERRORS) in a record of its own, appended once: the settings it
//! runs (or none) with the counts. The next start finds that record and runs the same without
//! counting again. The same for a newest item that is not this store's, or a range that holds
//! no record but is not erased (a range in another format, such as the `sequential-storage`
//! queue of the firmware before this store; or a first save cut short): the defaults, counted
//! once.
//!
//! The layout before this one (this store before page headers) had no page headers, records
//! starting with `0xA5`, a CRC-16/MODBUS instead of the CRC-32 and at least one byte of padding
//! (0x00). A page without a header is read in that layout; the first record written after it
//! (a save, a counted start or a factory reset) erases the page after the newest one, gives it
//! its header and carries the counts over; its sequence number follows the old records', so the
//! old pages left are older, until their turn to be erased comes.
//!
//! Wear: a save whose settings are those of the newest record writes nothing, and saves that
//! write are paced: [`SAVE_BURST`] back to back, then one per [`SAVE_INTERVAL_S`] (a save
//! sooner is refused, [`StoreError::TooSoon`]). A full record takes `size(ITEM_LEN)` = 232
//! bytes: the F103's 4 pages of 1 KiB hold 4 a page, 16 in all, so with 10 000 erases a page
//! its range takes 160 000 saves (the L475's 4 x 2 KiB 320 000, the F429's 2 x 16 KiB sectors
//! 1 400 000); at the paced rate, saving nonstop, that is 1.8 years on the F103. The pace is
//! kept in RAM: it starts afresh with every start of the board (a start writes nothing but, once,
//! a record that counts unreadable settings).
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

use embedded_storage::nor_flash::NorFlash;
use protocol::modbus::crc;
use protocol::plc::settings::{Settings, SettingsError, RECORD_LEN};
use protocol::plc::{Boot, ConfigSource};

/// The first byte of every item this store writes.
pub const FORMAT: u8 = 0x5A;
/// The head of an item: the format, saves (u32) and load errors (u16).
const COUNTS_LEN: usize = 7;
/// The longest item: the counts and a settings record.
pub const ITEM_LEN: usize = COUNTS_LEN + RECORD_LEN;

/// Saves that write the flash allowed back to back ([`Store::save`]) ...
pub const SAVE_BURST: u32 = 10;
/// ... then one per this many seconds: 10 an hour.
pub const SAVE_INTERVAL_S: u32 = 360;

/// The first byte of every record.
const MAGIC: u8 = 0xC5;
/// The first byte of a record of the layout before (no page headers, a CRC-16).
const MAGIC_1: u8 = 0xA5;
/// A record's head: the magic, the item's length and the sequence number.
const HEAD: usize = 6;
/// What a record is padded with after its CRC.
const END: u8 = 0x00;
/// The longest flash word the store supports (the alignment of its buffer).
const MAX_WORD: usize = 8;

/// A page's header, written after each erase.
const HEADER: [u8; HDR] = *b"RCGW\x02\0\0\0";
/// The header's length: a whole number of flash words.
const HDR: usize = MAX_WORD;

// The item's length fits the record's length byte.
const _: () = assert!(ITEM_LEN <= u8::MAX as usize);

/// The scratch buffer: a page header, then the longest record, rounded up to the longest flash
/// word, aligned like one (a record and the header before it are written in one go).
#[repr(align(8))]
struct Buffer([u8; Buffer::LEN]);

impl Buffer {
    const LEN: usize = AT + (HEAD + ITEM_LEN + 5).div_ceil(MAX_WORD) * MAX_WORD;
}

/// Where a record is in the buffer: after room for the header.
const AT: usize = HDR;

/// Why the store could not do what it was asked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreError {
    /// The flash failed.
    Flash,
    /// A save that would write came sooner than the pace allows ([`SAVE_BURST`]).
    TooSoon,
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
    /// Whether it is in a page with a header (this layout, else the one before).
    headers: bool,
}

/// What a scan of the range found.
#[derive(Clone, Copy)]
struct Scan {
    /// The newest record.
    newest: Option<Found>,
    /// The newest record whose item is this store's (older than the scan's bound, if any).
    ours: Option<Found>,
    /// The newest record's page (the first page if there is none) ...
    page: u32,
    /// ... and where its erased space starts (an offset in the page).
    free: usize,
    /// Whether the whole range is erased (but for page headers).
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

/// Whether sequence number `a` is newer than `b` (serial number arithmetic).
fn newer(a: u32, b: u32) -> bool {
    (a.wrapping_sub(b) as i32) > 0
}

/// The settings store on `F`, in a range of at least two erase pages.
pub struct Store<F: NorFlash> {
    flash: F,
    /// The range's first address.
    start: u32,
    /// Its erase pages.
    pages: u32,
    /// The pace of saves: the time (s) up to which the saves so far used it up.
    paced: u32,
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
    /// two, or the flash's words are not powers of two up to 8 bytes, or a page cannot hold its
    /// header and a record.
    pub fn new(flash: F, range: Range<u32>) -> Option<Store<F>> {
        let word = Self::WORD;
        let whole_words = word.is_power_of_two()
            && word <= MAX_WORD
            && usize::try_from(Self::PAGE).is_ok_and(|page| page == F::ERASE_SIZE)
            && F::ERASE_SIZE >= HDR + Self::size(ITEM_LEN, true)
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
            paced: 0,
            buffer: Buffer([0; Buffer::LEN]),
        })
    }

    /// The flash back (the store is done with it).
    pub fn into_flash(self) -> F {
        self.flash
    }

    /// The flash, to look at.
    pub fn flash(&self) -> &F {
        &self.flash
    }

    /// The flash, for a caller that shares it with the store outside the store's range (the
    /// firmware's DFU partition): whatever it writes there, the store never reads.
    pub fn flash_mut(&mut self) -> &mut F {
        &mut self.flash
    }

    /// A record's length, with an item of `len` bytes, in this layout or (`!headers`) the one
    /// before: the head, the item, the CRC-32 (CRC-16) and at least one byte of padding.
    const fn size(len: usize, headers: bool) -> usize {
        let tail = if headers { 5 } else { 3 };
        (HEAD + len + tail).div_ceil(Self::WORD) * Self::WORD
    }

    /// `len` bytes from the flash at `at` into the buffer (where a record goes).
    fn read(&mut self, at: u32, len: usize) -> Result<&[u8], StoreError> {
        let bytes = self
            .buffer
            .0
            .get_mut(AT..AT + len)
            .ok_or(StoreError::Flash)?;
        self.flash.read(at, bytes).map_err(|_| StoreError::Flash)?;
        Ok(bytes)
    }

    /// Every page, every record (only those older than `below`, if given, for
    /// [`Scan::ours`]): see the module's description.
    fn scan(&mut self, below: Option<u32>) -> Scan {
        let word = Self::WORD;
        let page_len = F::ERASE_SIZE;
        let mut scan = Scan::BLANK;
        for page in 0..self.pages {
            let base = self.start + page * Self::PAGE;
            // A page with a header holds records of this layout; one without, of the layout
            // before (or nothing: erased, an erase cut short, another format).
            let headers = self.read(base, HDR).is_ok_and(|h| h == HEADER);
            let magic = if headers { MAGIC } else { MAGIC_1 };
            // The page's offset up to which something was written.
            let (mut at, mut used) = (0, 0);
            while at < page_len {
                let addr = base + at as u32;
                let mut step = word;
                let head = match self.read(addr, Self::HEAD_READ.min(page_len - at)) {
                    Ok(head) => head,
                    // Unreadable: written (cut short), not a record.
                    Err(_) => &[0; HEAD][..],
                };
                if head.iter().take(word).any(|&b| b != 0xFF) {
                    used = used.max(at + word);
                }
                if let &[m, len, s0, s1, s2, s3, ..] = head {
                    let len = usize::from(len);
                    let size = Self::size(len, headers);
                    if m == magic && len <= ITEM_LEN && size <= page_len - at {
                        // Written up to there, maybe with words of 0xFF, if it was cut short.
                        used = used.max(at + size);
                        let record = self.read(addr, size).unwrap_or(&[]);
                        if let Some(item) = item(record, len, headers) {
                            step = size;
                            let found = Found {
                                seq: u32::from_le_bytes([s0, s1, s2, s3]),
                                at: addr,
                                len,
                                headers,
                            };
                            if len >= COUNTS_LEN
                                && item.first() == Some(&FORMAT)
                                && below.is_none_or(|b| newer(b, found.seq))
                                && scan.ours.is_none_or(|o| !newer(o.seq, found.seq))
                            {
                                scan.ours = Some(found);
                            }
                            if scan.newest.is_none_or(|n| newer(found.seq, n.seq)) {
                                scan.newest = Some(found);
                                scan.page = page;
                            }
                        }
                    }
                }
                at += step;
            }
            if used > if headers { HDR } else { 0 } {
                scan.blank = false;
            }
            if scan.page == page {
                scan.free = used;
            }
        }
        scan
    }

    /// The scan, and the newest item of ours (older than `below`, if given) read into the
    /// buffer (an item with no counts and no settings if there is none); the item's length.
    fn newest(&mut self, below: Option<u32>) -> Result<(Scan, usize), StoreError> {
        let scan = self.scan(below);
        Ok(match scan.ours {
            Some(ours) => {
                self.read(ours.at, Self::size(ours.len, ours.headers))?;
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
        match self.buffer.0.get(AT + HEAD..AT + HEAD + COUNTS_LEN) {
            Some(&[_, s0, s1, s2, s3, e0, e1]) => (
                u32::from_le_bytes([s0, s1, s2, s3]),
                u16::from_le_bytes([e0, e1]),
            ),
            _ => (0, 0),
        }
    }

    /// The format and counts of the item in the buffer.
    fn set_counts(&mut self, saves: u32, load_errors: u16) {
        let [s0, s1, s2, s3] = saves.to_le_bytes();
        let [e0, e1] = load_errors.to_le_bytes();
        if let Some(counts) = self.buffer.0.get_mut(AT + HEAD..AT + HEAD + COUNTS_LEN) {
            counts.copy_from_slice(&[FORMAT, s0, s1, s2, s3, e0, e1]);
        }
    }

    /// The settings record of the item of `len` bytes in the buffer (empty: none).
    fn record(&self, len: usize) -> &[u8] {
        self.buffer
            .0
            .get(AT + HEAD + COUNTS_LEN..AT + HEAD + len)
            .unwrap_or(&[])
    }

    /// Erase `page`.
    fn erase(&mut self, page: u32) -> Result<(), StoreError> {
        let from = self.start + page * Self::PAGE;
        self.flash
            .erase(from, from + Self::PAGE)
            .map_err(|_| StoreError::Flash)
    }

    /// Append the item of `len` bytes in the buffer as the newest record, after `scan`: in the
    /// newest record's page if it fits (and has a header), else at the start of the next page
    /// (`scan.page` if there is no record), erased first, after its header.
    fn append(&mut self, scan: &Scan, len: usize) -> Result<(), StoreError> {
        let size = Self::size(len, true);
        let mut page = scan.page;
        // Where the write starts, in the page and in the buffer.
        let (mut at, mut from) = (scan.free, AT);
        let fits =
            scan.newest.is_some_and(|n| n.headers) && size <= F::ERASE_SIZE - at.min(F::ERASE_SIZE);
        if !fits {
            if scan.newest.is_some() {
                page = (page + 1) % self.pages;
            }
            self.erase(page)?;
            if let Some(header) = self.buffer.0.get_mut(..AT) {
                header.copy_from_slice(&HEADER);
            }
            (at, from) = (0, 0);
        }
        let seq = scan.newest.map_or(0, |n| n.seq.wrapping_add(1));
        let [s0, s1, s2, s3] = seq.to_le_bytes();
        let record = self
            .buffer
            .0
            .get_mut(AT..AT + size)
            .ok_or(StoreError::Flash)?;
        let (body, tail) = record
            .split_at_mut_checked(HEAD + len)
            .ok_or(StoreError::Flash)?;
        if let Some(head) = body.get_mut(..HEAD) {
            head.copy_from_slice(&[MAGIC, len as u8, s0, s1, s2, s3]);
        }
        let sum = crc32(body).to_le_bytes();
        tail.fill(END);
        if let Some(to) = tail.get_mut(..4) {
            to.copy_from_slice(&sum);
        }
        let bytes = self
            .buffer
            .0
            .get(from..AT + size)
            .ok_or(StoreError::Flash)?;
        self.flash
            .write(self.start + page * Self::PAGE + at as u32, bytes)
            .map_err(|_| StoreError::Flash)
    }

    /// Read the settings at start-up. Unreadable settings (a damaged record, another format)
    /// give the newest older ones that are readable, or the defaults, and are counted, in flash
    /// too (once).
    pub fn load(&mut self) -> Loaded {
        let Ok((scan, mut len)) = self.newest(None) else {
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
        let (saves, mut load_errors) = self.counts();
        let mut source = ConfigSource::Damaged;
        // The settings of the item the start uses, decoded once (the fallback that finds them
        // copies the same bytes to the newest record).
        let mut settings = None;
        // The item appended to count this start: its length (the counts only: the defaults).
        let mut counted = Some(COUNTS_LEN);
        if scan.ours_last() {
            let mut ours = scan.ours;
            // The newest item of ours, then (if its settings do not decode) older ones.
            for fallback in 0..FALLBACKS {
                let record = self.record(len);
                if record.is_empty() {
                    // Nothing stored yet, or a factory reset since: not behind it either.
                    if fallback == 0 {
                        source = ConfigSource::Defaults;
                        counted = None;
                    }
                    break;
                }
                match Settings::decode(record) {
                    Ok(decoded) => {
                        settings = Some(decoded);
                        source = ConfigSource::Flash;
                        counted = (fallback > 0).then_some(len);
                        break;
                    }
                    // A newer firmware's format: not older settings in its place.
                    Err(SettingsError::Version) => break,
                    Err(_) => {}
                }
                let Some(below) = ours.map(|o| o.seq) else {
                    break;
                };
                match self.newest(Some(below)) {
                    Ok((older, older_len)) if older.ours.is_some() => {
                        ours = older.ours;
                        len = older_len;
                    }
                    _ => break,
                }
            }
        }
        if let Some(item_len) = counted {
            load_errors = load_errors.saturating_add(1);
            self.set_counts(saves, load_errors);
            len = item_len;
            // Best effort: a flash that will not take the write is counted next start again.
            let _ = self.append(&scan, len);
        }
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

    /// Store `record` ([`Settings::encode`]) as the settings at `now` (seconds, from any
    /// start: the pace's clock); the saves so far, this one included. If the power fails
    /// meanwhile, the next start finds the old settings or the new ones, never a mix.
    ///
    /// Settings the same as the newest record's write nothing (the count stays). A save that
    /// would write is refused ([`StoreError::TooSoon`]) after [`SAVE_BURST`] of them in a row,
    /// until [`SAVE_INTERVAL_S`] has passed for each.
    pub fn save(&mut self, record: &[u8; RECORD_LEN], now: u32) -> Result<u32, StoreError> {
        let (scan, len) = self.newest(None)?;
        let (saves, load_errors) = self.counts();
        if scan.ours_last() && self.record(len) == record {
            return Ok(saves);
        }
        let paced = self.paced.max(now);
        if paced - now > (SAVE_BURST - 1) * SAVE_INTERVAL_S {
            return Err(StoreError::TooSoon);
        }
        self.paced = paced.saturating_add(SAVE_INTERVAL_S);
        let saves = saves.wrapping_add(1);
        self.set_counts(saves, load_errors);
        self.buffer
            .0
            .get_mut(AT + HEAD + COUNTS_LEN..AT + HEAD + ITEM_LEN)
            .ok_or(StoreError::Flash)?
            .copy_from_slice(record);
        self.append(&scan, ITEM_LEN)?;
        Ok(saves)
    }

    /// Forget the settings: the next start uses the defaults. Every page of the range is erased,
    /// the newest record's last: first the others but the one after it, then that one, given
    /// the counts in a record of their own (newer than any before), then the newest record's.
    /// Cut before that record is whole, the settings stay; after, the defaults run. The counts
    /// stay (unless the flash cannot read them).
    pub fn factory_reset(&mut self) -> Result<(), StoreError> {
        let mut scan = match self.newest(None) {
            Ok((scan, _)) => scan,
            Err(_) => {
                self.set_counts(0, 0);
                Scan::BLANK
            }
        };
        let newest = scan.page;
        // Where the counts go: the page after the newest record's (`newest` if there is none).
        let to = match scan.newest {
            Some(_) => (newest + 1) % self.pages,
            None => newest,
        };
        for i in 1..self.pages {
            let page = (to + i) % self.pages;
            if page != newest {
                self.erase(page)?;
            }
        }
        // No room in the newest record's page: the next one, erased.
        scan.free = F::ERASE_SIZE;
        self.append(&scan, COUNTS_LEN)?;
        if to != newest {
            self.erase(newest)?;
        }
        Ok(())
    }
}

/// How many items of ours a start tries, newest first, for settings that decode.
const FALLBACKS: usize = 8;

/// The item of `record` (an item of `len` bytes), if its CRC and padding are right, in this
/// layout or (`!headers`) the one before.
fn item(record: &[u8], len: usize, headers: bool) -> Option<&[u8]> {
    let (body, tail) = record.split_at_checked(HEAD + len)?;
    let (sum, pad) = tail.split_at_checked(if headers { 4 } else { 2 })?;
    let right = if headers {
        sum == crc32(body).to_le_bytes()
    } else {
        sum == crc::to_wire(crc::checksum(body))
    };
    (right && pad.iter().all(|&b| b == END)).then_some(body.get(HEAD..)?)
}

/// CRC-32 (IEEE 802.3, reflected, as zip's) of `bytes`, bit by bit (no table: flash is short).
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = u32::MAX;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = (crc >> 1) ^ (0xEDB8_8320 & (crc & 1).wrapping_neg());
        }
    }
    !crc
}

#[cfg(test)]
mod tests {
    #[test]
    fn crc32_is_ieee() {
        assert_eq!(super::crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn serial_numbers() {
        assert!(super::newer(0, u32::MAX));
        assert!(super::newer(5, 4));
        assert!(!super::newer(4, 5));
        assert!(!super::newer(4, 4));
    }
}
