//! The gateway's settings in flash, over any NOR flash: what the firmware loads at start-up and
//! stores when the PLC writes SAVE.
//!
//! [sequential-storage]'s queue does the hard part: every save appends one item to a range of
//! flash pages, and the newest item is the one in force, so a page is erased only when the
//! range has filled up (then the oldest page: wear is spread over every page of the range), and
//! an item is written with a CRC, so a save cut short by a power loss leaves the previous item
//! in force. On top of that the settings record carries its own version and CRC
//! ([`Settings::decode`]), so a record written by another firmware is refused whole.
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
//! A start whose newest item is not this store's (or not a readable record) runs the defaults and
//! counts it. A flash that cannot be read is never written over: the counts it holds are
//! unknown, and a later start may read it.
//!
//! (A queue rather than sequential-storage's map of three keys: the same guarantees in 1.2 KB
//! less of the F103's flash, measured by `scripts/size-report.sh`.)
//!
//! [sequential-storage]: https://docs.rs/sequential-storage

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
use protocol::plc::settings::{Settings, RECORD_LEN};
use protocol::plc::{Boot, ConfigSource};
use sequential_storage::cache::{Cache, Uncached};
use sequential_storage::queue::{QueueConfig, QueueStorage};

/// The first byte of every item this store writes.
pub const FORMAT: u8 = 0x5A;
/// The head of an item: the format, saves (u32) and load errors (u16).
const COUNTS_LEN: usize = 7;
/// The longest item: the counts and a settings record.
pub const ITEM_LEN: usize = COUNTS_LEN + RECORD_LEN;

/// The scratch buffer of the queue: the longest item, rounded up to the largest flash word
/// sequential-storage supports (32 bytes), aligned like one.
#[repr(align(32))]
struct Buffer([u8; Buffer::LEN]);

impl Buffer {
    const LEN: usize = ITEM_LEN.div_ceil(32) * 32;
}

/// Why the store could not do what it was asked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreError {
    /// The flash failed (or the range is full of items sequential-storage cannot move).
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

/// The queue without a RAM cache: the settings are read once at start-up and written on SAVE.
type Queue<F> = QueueStorage<F, Cache<Uncached, Uncached, Uncached, ()>>;

/// The newest item, decoded.
#[derive(Clone, Copy)]
struct Item {
    saves: u32,
    load_errors: u16,
    /// The record's length: 0 after a factory reset, [`RECORD_LEN`] for a save.
    len: usize,
    record: [u8; RECORD_LEN],
}

impl Item {
    /// Nothing stored yet.
    const NONE: Item = Item {
        saves: 0,
        load_errors: 0,
        len: 0,
        record: [0; RECORD_LEN],
    };

    /// An item as stored: the format, the counts, then the record. `None` if it is not one of
    /// this store's: another format, too short for the counts, or a record too long.
    fn decode(bytes: &[u8]) -> Option<Item> {
        let (counts, record) = bytes.split_at_checked(COUNTS_LEN)?;
        let [FORMAT, s0, s1, s2, s3, e0, e1] = <[u8; COUNTS_LEN]>::try_from(counts).ok()? else {
            return None;
        };
        if record.len() > RECORD_LEN {
            return None;
        }
        let mut item = Item {
            saves: u32::from_le_bytes([s0, s1, s2, s3]),
            load_errors: u16::from_le_bytes([e0, e1]),
            len: record.len(),
            record: [0; RECORD_LEN],
        };
        if let Some(to) = item.record.get_mut(..record.len()) {
            to.copy_from_slice(record);
        }
        Some(item)
    }

    /// The item's bytes into `out`, as their length (0 if `out` is too short).
    fn encode(&self, out: &mut [u8]) -> usize {
        let Some((counts, record)) = out.split_at_mut_checked(COUNTS_LEN) else {
            return 0;
        };
        let saves = self.saves.to_le_bytes();
        let errors = self.load_errors.to_le_bytes();
        let head = [FORMAT].into_iter().chain(saves).chain(errors);
        for (to, from) in counts.iter_mut().zip(head) {
            *to = from;
        }
        let len = self.len.min(RECORD_LEN);
        if let (Some(to), Some(from)) = (record.get_mut(..len), self.record.get(..len)) {
            to.copy_from_slice(from);
        }
        COUNTS_LEN + len
    }
}

/// The settings store on `F`, in a range of at least two erase pages.
pub struct Store<F: NorFlash> {
    queue: Queue<F>,
    buffer: Buffer,
}

impl<F: NorFlash> Store<F> {
    /// A store on `flash` in `range`; `None` if the range is not whole erase pages, or fewer than
    /// two.
    pub fn new(flash: F, range: Range<u32>) -> Option<Store<F>> {
        let pages = range
            .end
            .checked_sub(range.start)?
            .checked_div(u32::try_from(F::ERASE_SIZE).ok()?)?;
        if pages < 2 {
            return None;
        }
        let config = QueueConfig::try_new(range).ok()?;
        Some(Store {
            queue: QueueStorage::new(flash, config, Cache::new_uncached()),
            buffer: Buffer([0; Buffer::LEN]),
        })
    }

    /// The flash back (the store is done with it).
    pub fn into_flash(self) -> F {
        self.queue.destroy().0
    }

    /// The newest item of this store's ([`Item::NONE`] if there is none), and whether it is the
    /// newest item in the range (an item of another format may have come after it); `Err` if
    /// the flash could not be read.
    async fn newest(&mut self) -> Result<(Item, bool), StoreError> {
        let mut iter = self.queue.iter().await.map_err(|_| StoreError::Flash)?;
        let (mut item, mut last) = (Item::NONE, true);
        while let Some(entry) = iter
            .next(&mut self.buffer.0)
            .await
            .map_err(|_| StoreError::Flash)?
        {
            match Item::decode(&entry) {
                Some(ours) => (item, last) = (ours, true),
                None => last = false,
            }
        }
        Ok((item, last))
    }

    /// Append `item`: the newest from now on. (Encoded in the scratch buffer: the futures of
    /// the store's operations are on the stack while they run, and the firmware's deepest stack
    /// at start-up is the settings' load.)
    async fn push(&mut self, item: &Item) -> Result<(), StoreError> {
        let len = item.encode(&mut self.buffer.0);
        let bytes = self.buffer.0.get(..len).ok_or(StoreError::Flash)?;
        // Overwriting: a full range gives up its oldest page, never the newest item.
        self.queue
            .push(bytes, true)
            .await
            .map_err(|_| StoreError::Flash)
    }

    /// Read the settings at start-up. Unreadable settings (a damaged record, another format,
    /// a flash error) give the defaults and are counted, in flash too.
    pub async fn load(&mut self) -> Loaded {
        let Ok((mut item, last)) = self.newest().await else {
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
        let source = match (last, item.len) {
            // Nothing stored yet, or a factory reset since.
            (true, 0) => ConfigSource::Defaults,
            (true, RECORD_LEN) if Settings::decode(&item.record).is_ok() => ConfigSource::Flash,
            _ => ConfigSource::Damaged,
        };
        if source == ConfigSource::Damaged {
            item.load_errors = item.load_errors.saturating_add(1);
            if !last {
                // Something else came after the last item of ours: not its settings, which
                // that replaced. The defaults from now on (this start is the one counted).
                item.len = 0;
            }
            // A record of ours that does not decode stays as it was: every start counts it.
            // Best effort: a flash that will not take the write is counted next start again.
            let _ = self.push(&item).await;
        }
        // Decoded again rather than kept across the write above: the future, on the stack
        // while it runs, is then smaller by the settings (the deepest stack at start-up).
        let settings = match source {
            ConfigSource::Flash => Settings::decode(&item.record).ok(),
            _ => None,
        };
        Loaded {
            settings,
            boot: Boot {
                source,
                load_errors: item.load_errors,
                save_count: item.saves,
                reset: Boot::DEFAULT.reset,
            },
        }
    }

    /// Store `record` ([`Settings::encode`]) as the settings; the saves so far, this one
    /// included. If the power fails meanwhile, the next start finds the old settings or the
    /// new ones, never a mix.
    pub async fn save(&mut self, record: &[u8; RECORD_LEN]) -> Result<u32, StoreError> {
        // Refused if the flash cannot be read: the saves so far would be lost.
        let (newest, _) = self.newest().await?;
        // A new item rather than `newest` changed: assigning the record into the future's own
        // copy is a copy the compiler cannot prove disjoint (a `memmove`, 1.6 KB of flash).
        let item = Item {
            saves: newest.saves.wrapping_add(1),
            load_errors: newest.load_errors,
            len: RECORD_LEN,
            record: *record,
        };
        self.push(&item).await?;
        Ok(item.saves)
    }

    /// Forget the settings: the next start uses the defaults. The counts stay, unless the flash
    /// cannot be read: then the whole range is erased (the way out of a range nothing can read).
    pub async fn factory_reset(&mut self) -> Result<(), StoreError> {
        let mut item = match self.newest().await {
            Ok((item, _)) => item,
            Err(_) => {
                self.queue
                    .erase_all()
                    .await
                    .map_err(|_| StoreError::Flash)?;
                Item::NONE
            }
        };
        item.len = 0;
        self.push(&item).await
    }
}
