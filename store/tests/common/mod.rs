//! What the store's tests share: settings to store, the pace's clock, the blocking face of
//! sequential-storage's async mock flash, and records written by hand in either layout.
#![allow(dead_code)]

use std::sync::atomic::{AtomicU32, Ordering};

use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use futures::executor::block_on;
use protocol::plc::settings::Settings;
use protocol::plc::{GatewayConfig, WatchdogTime};
use protocol::AxisSet;

/// Settings with `watchdog_ms` (0 or 50-60 000) and the first `axes` axes (1-16).
pub fn settings(watchdog_ms: u16, axes: u8) -> Settings {
    let mut c = GatewayConfig::new(AxisSet::first(axes));
    c.settings.watchdog = WatchdogTime::from_millis(watchdog_ms).expect("0 or 50-60 000 ms");
    Settings::of(&c)
}

/// A time for a save: each call a pace's interval after the one before, so the tests' saves
/// are never paced (the pace has tests of its own).
pub fn now() -> u32 {
    static CLOCK: AtomicU32 = AtomicU32::new(0);
    CLOCK.fetch_add(settings_store::SAVE_INTERVAL_S, Ordering::Relaxed)
}

/// An async flash (sequential-storage's mock) as the blocking flash the store takes.
#[derive(Clone)]
pub struct Blocking<F>(pub F);

impl<F: embedded_storage_async::nor_flash::ErrorType> ErrorType for Blocking<F> {
    type Error = F::Error;
}

impl<F: embedded_storage_async::nor_flash::ReadNorFlash> ReadNorFlash for Blocking<F> {
    const READ_SIZE: usize = F::READ_SIZE;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        block_on(self.0.read(offset, bytes))
    }
    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl<F: embedded_storage_async::nor_flash::NorFlash> NorFlash for Blocking<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        block_on(self.0.erase(from, to))
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        block_on(self.0.write(offset, bytes))
    }
}

/// The layout a record is written in by [`record`].
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Layout {
    /// The store's: magic 0xC5, CRC-32, in pages with a header.
    Current,
    /// The one before (no page headers): magic 0xA5, CRC-16/MODBUS.
    Before,
}

/// A page header of the current layout.
pub const HEADER: [u8; 8] = *b"RCGW\x02\0\0\0";

/// The store's CRC-32 (IEEE).
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = u32::MAX;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = (crc >> 1) ^ (0xEDB8_8320 & (crc & 1).wrapping_neg());
        }
    }
    !crc
}

/// A record holding `item` with sequence number `seq`, in `layout`, padded to `word` bytes:
/// the bytes the store writes (see the crate's description).
pub fn record(layout: Layout, item: &[u8], seq: u32, word: usize) -> Vec<u8> {
    let magic = match layout {
        Layout::Current => 0xC5,
        Layout::Before => 0xA5,
    };
    let mut record = vec![magic, item.len() as u8];
    record.extend(seq.to_le_bytes());
    record.extend(item);
    match layout {
        Layout::Current => record.extend(crc32(&record).to_le_bytes()),
        Layout::Before => record.extend(protocol::modbus::crc::checksum(&record).to_le_bytes()),
    }
    record.push(0);
    record.resize(record.len().div_ceil(word) * word, 0);
    record
}

/// An item of the store's: the format, `saves`, `load_errors`, then `settings` (if any).
pub fn item(saves: u32, load_errors: u16, settings: Option<&Settings>) -> Vec<u8> {
    let mut item = vec![settings_store::FORMAT];
    item.extend(saves.to_le_bytes());
    item.extend(load_errors.to_le_bytes());
    if let Some(s) = settings {
        item.extend(s.encode());
    }
    item
}

/// Aligned bytes to write from (sequential-storage's mock wants word-aligned buffers).
#[repr(align(32))]
pub struct Aligned(pub [u8; 512]);

/// Write `bytes` at `at` in `flash`, from an aligned buffer.
pub fn write<F: NorFlash>(flash: &mut F, at: usize, bytes: &[u8]) {
    let mut aligned = Aligned([0; 512]);
    aligned.0[..bytes.len()].copy_from_slice(bytes);
    flash
        .write(at as u32, &aligned.0[..bytes.len()])
        .unwrap_or_else(|_| panic!("write at {at}"));
}
