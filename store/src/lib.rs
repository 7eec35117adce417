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
//! | [`KEY_SAVES`] | saves so far (u32): kept apart so that a factory reset does not clear it |
//! | [`KEY_LOAD_ERRORS`] | starts that found the settings unreadable (u16) |
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

    async fn fetch_u32(&mut self, key: u8) -> Result<Option<u32>, StoreError> {
        self.map
            .fetch_item::<u32>(&mut self.buffer.0, &key)
            .await
            .map_err(|_| StoreError::Flash)
    }

    async fn fetch_u16(&mut self, key: u8) -> Result<Option<u16>, StoreError> {
        self.map
            .fetch_item::<u16>(&mut self.buffer.0, &key)
            .await
            .map_err(|_| StoreError::Flash)
    }

    /// Read the settings at start-up. Unreadable settings (a damaged record, another format,
    /// a flash error) give the defaults and are counted, in flash too.
    pub async fn load(&mut self) -> Loaded {
        let saves = self.fetch_u32(KEY_SAVES).await.ok().flatten().unwrap_or(0);
        let errors = self
            .fetch_u16(KEY_LOAD_ERRORS)
            .await
            .ok()
            .flatten()
            .unwrap_or(0);
        let record = self
            .map
            .fetch_item::<&[u8]>(&mut self.buffer.0, &KEY_SETTINGS)
            .await;
        let (settings, source) = match record {
            // Nothing stored yet, or a factory reset since.
            Ok(None) => (None, ConfigSource::Defaults),
            Ok(Some([])) => (None, ConfigSource::Defaults),
            Ok(Some(record)) => match Settings::decode(record) {
                Ok(settings) => (Some(settings), ConfigSource::Flash),
                Err(_) => (None, ConfigSource::Damaged),
            },
            Err(_) => (None, ConfigSource::Damaged),
        };
        let mut load_errors = errors;
        if source == ConfigSource::Damaged {
            load_errors = load_errors.saturating_add(1);
            // Best effort: a flash that cannot be read may not take a write either.
            let _ = self
                .map
                .store_item(&mut self.buffer.0, &KEY_LOAD_ERRORS, &load_errors)
                .await;
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
        let saves = self.fetch_u32(KEY_SAVES).await?.unwrap_or(0);
        self.map
            .store_item(&mut self.buffer.0, &KEY_SETTINGS, &record.as_slice())
            .await
            .map_err(|_| StoreError::Flash)?;
        let saves = saves.wrapping_add(1);
        self.map
            .store_item(&mut self.buffer.0, &KEY_SAVES, &saves)
            .await
            .map_err(|_| StoreError::Flash)?;
        Ok(saves)
    }

    /// Forget the settings: the next start uses the defaults. The counts stay.
    pub async fn factory_reset(&mut self) -> Result<(), StoreError> {
        let empty: &[u8] = &[];
        self.map
            .store_item(&mut self.buffer.0, &KEY_SETTINGS, &empty)
            .await
            .map_err(|_| StoreError::Flash)
    }
}
