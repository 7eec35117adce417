//! The gateway's settings in flash, over any NOR flash: what the firmware loads at start-up and
//! stores when the PLC writes SAVE.
//!
//! [sequential-storage]'s map does the hard part: items are appended to a range of flash pages
//! and the newest item of a key wins, so a page is erased only when the range has filled up
//! (wear is spread over every page of the range), and an item is written with a CRC, so a
//! save cut short by a power loss leaves the previous item in force. On top of that the
//! settings record carries its own version and CRC ([`Settings::decode`]), so a record written
//! by another firmware is refused whole.
//!
//! Three keys:
//!
//! | Key | Value |
//! |---|---|
//! | [`KEY_SETTINGS`] | the settings record ([`RECORD_LEN`] bytes), or empty after a factory reset |
//! | [`KEY_SAVES`] | saves so far (u32, little endian): kept apart so that a factory reset does not clear it |
//! | [`KEY_LOAD_ERRORS`] | starts that found the settings unreadable (u16, little endian) |
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
use sequential_storage::map::{MapConfig, MapStorage};

/// The settings record (empty after a factory reset).
pub const KEY_SETTINGS: u8 = 1;
/// Saves so far.
pub const KEY_SAVES: u8 = 2;
/// Starts that found the settings unreadable.
pub const KEY_LOAD_ERRORS: u8 = 3;

/// The scratch buffer of the map: a key and the longest value, rounded up to the largest flash
/// word sequential-storage supports (32 bytes), aligned like one.
#[repr(align(32))]
struct Buffer([u8; Buffer::LEN]);

impl Buffer {
    const LEN: usize = (1 + RECORD_LEN).div_ceil(32) * 32;
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

/// The map without a RAM cache: the settings are read once at start-up and written on SAVE.
type Map<F> = MapStorage<u8, F, Cache<Uncached, Uncached, Uncached, u8>>;

/// The settings store on `F`, in a range of at least two erase pages.
pub struct Store<F: NorFlash> {
    map: Map<F>,
    buffer: Buffer,
}

impl<F: NorFlash> Store<F> {
    /// A store on `flash` in `range`; `None` if the range is not whole erase pages, or fewer than
    /// two.
    pub fn new(flash: F, range: Range<u32>) -> Option<Store<F>> {
        let config = MapConfig::try_new(range).ok()?;
        Some(Store {
            map: MapStorage::new(flash, config, Cache::new_uncached()),
            buffer: Buffer([0; Buffer::LEN]),
        })
    }

    /// The flash back (the store is done with it).
    pub fn into_flash(self) -> F {
        self.map.destroy().0
    }

    /// The newest value of `key` (copied into `out`), as its length; every item is a byte
    /// string, so that the firmware carries one copy of the map's fetch code, not one per type.
    async fn get(&mut self, key: u8, out: &mut [u8]) -> Result<Option<usize>, StoreError> {
        let value = self
            .map
            .fetch_item::<&[u8]>(&mut self.buffer.0, &key)
            .await
            .map_err(|_| StoreError::Flash)?;
        Ok(value.map(|v| {
            let n = v.len().min(out.len());
            if let (Some(to), Some(from)) = (out.get_mut(..n), v.get(..n)) {
                to.copy_from_slice(from);
            }
            v.len()
        }))
    }

    /// Store `value` as the newest value of `key`.
    async fn put(&mut self, key: u8, value: &[u8]) -> Result<(), StoreError> {
        self.map
            .store_item(&mut self.buffer.0, &key, &value)
            .await
            .map_err(|_| StoreError::Flash)
    }

    /// A little-endian counter of `N` bytes, 0 if absent or unreadable.
    async fn count<const N: usize>(&mut self, key: u8) -> u32 {
        let mut bytes = [0u8; 4];
        match self.get(key, &mut bytes).await {
            Ok(Some(len)) if len == N => u32::from_le_bytes(bytes),
            _ => 0,
        }
    }

    /// Read the settings at start-up. Unreadable settings (a damaged record, another format,
    /// a flash error) give the defaults and are counted, in flash too.
    pub async fn load(&mut self) -> Loaded {
        let saves = self.count::<4>(KEY_SAVES).await;
        let errors = u16::try_from(self.count::<2>(KEY_LOAD_ERRORS).await).unwrap_or(u16::MAX);
        let mut record = [0u8; RECORD_LEN];
        let (settings, source) = match self.get(KEY_SETTINGS, &mut record).await {
            // Nothing stored yet, or a factory reset since.
            Ok(None | Some(0)) => (None, ConfigSource::Defaults),
            Ok(Some(RECORD_LEN)) => match Settings::decode(&record) {
                Ok(settings) => (Some(settings), ConfigSource::Flash),
                Err(_) => (None, ConfigSource::Damaged),
            },
            Ok(Some(_)) | Err(_) => (None, ConfigSource::Damaged),
        };
        let mut load_errors = errors;
        if source == ConfigSource::Damaged {
            load_errors = load_errors.saturating_add(1);
            // Best effort: a flash that cannot be read may not take a write either.
            let _ = self.put(KEY_LOAD_ERRORS, &load_errors.to_le_bytes()).await;
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

    /// Store `record` ([`Settings::encode`]) as the settings; the saves so far, this one
    /// included. If the power fails meanwhile, the next start finds the old settings or the
    /// new ones, never a mix.
    pub async fn save(&mut self, record: &[u8; RECORD_LEN]) -> Result<u32, StoreError> {
        let saves = self.count::<4>(KEY_SAVES).await.wrapping_add(1);
        self.put(KEY_SETTINGS, record).await?;
        self.put(KEY_SAVES, &saves.to_le_bytes()).await?;
        Ok(saves)
    }

    /// Forget the settings: the next start uses the defaults. The counts stay.
    pub async fn factory_reset(&mut self) -> Result<(), StoreError> {
        self.put(KEY_SETTINGS, &[]).await
    }
}
