//! The settings store on sequential-storage's in-memory flash, in the geometry of both boards'
//! internal flash: first start, save and load, damaged and foreign records, a range left in the
//! previous firmware's format, factory reset, power loss at every byte of a save and during
//! the erase it needs, and wear over many saves.

use embedded_storage_async::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use futures::executor::block_on;
use protocol::plc::settings::{Settings, RECORD_LEN};
use protocol::plc::{ConfigSource, GatewayConfig};
use protocol::AxisSet;
use sequential_storage::cache::Cache;
use sequential_storage::mock_flash::{MockFlashBase, WriteCountCheck};
use sequential_storage::queue::{QueueConfig, QueueStorage};
use settings_store::Store;

/// STM32L475: 2 KiB pages, 64-bit words, written once per erase; two pages for the settings.
type L4 = MockFlashBase<2, 8, 256>;
/// STM32F103C8: 1 KiB pages, 16-bit half-words; two pages.
type F1 = MockFlashBase<2, 2, 512>;

fn l4() -> L4 {
    L4::new(WriteCountCheck::OnceOnly, None, true)
}

fn store<const P: usize, const W: usize, const N: usize>(
    flash: MockFlashBase<P, W, N>,
) -> Store<MockFlashBase<P, W, N>> {
    Store::new(flash, MockFlashBase::<P, W, N>::FULL_FLASH_RANGE).expect("a valid range")
}

fn settings(watchdog_ms: u16, axes: u8) -> Settings {
    let mut c = GatewayConfig::new(AxisSet::first(axes));
    c.watchdog = protocol::time::Duration::from_millis(watchdog_ms.into());
    Settings::of(&c)
}

#[test]
fn the_first_start_has_nothing_and_a_save_is_loaded_back() {
    let mut s = store(l4());
    let first = block_on(s.load());
    assert_eq!(first.settings, None);
    assert_eq!(first.boot.source, ConfigSource::Defaults);
    assert_eq!((first.boot.save_count, first.boot.load_errors), (0, 0));
    let wanted = settings(500, 3);
    assert_eq!(block_on(s.save(&wanted.encode())), Ok(1));
    assert_eq!(block_on(s.save(&settings(700, 2).encode())), Ok(2));
    assert_eq!(block_on(s.save(&wanted.encode())), Ok(3));
    // A "power cycle": a new store on the same flash.
    let mut s = store(s.into_flash());
    let loaded = block_on(s.load());
    assert_eq!(loaded.settings, Some(wanted));
    assert_eq!(loaded.boot.source, ConfigSource::Flash);
    assert_eq!(loaded.boot.save_count, 3);
}

#[test]
fn the_same_works_on_the_f103s_half_word_flash() {
    let mut s = store(F1::new(WriteCountCheck::OnceOnly, None, true));
    let wanted = settings(250, 16);
    assert_eq!(block_on(s.save(&wanted.encode())), Ok(1));
    let mut s = store(s.into_flash());
    assert_eq!(block_on(s.load()).settings, Some(wanted));
}

/// A record with another format (a firmware downgrade, say) or damaged contents gives the
/// defaults, and the start is counted, in flash too.
#[test]
fn an_unreadable_record_gives_the_defaults_and_is_counted() {
    let mut s = store(l4());
    let mut record = settings(500, 1).encode();
    record[0] = 99; // another format version
    assert_eq!(block_on(s.save(&record)), Ok(1));
    let mut s = store(s.into_flash());
    let loaded = block_on(s.load());
    assert_eq!(loaded.settings, None);
    assert_eq!(loaded.boot.source, ConfigSource::Damaged);
    assert_eq!(loaded.boot.load_errors, 1);
    let mut s = store(s.into_flash());
    assert_eq!(
        block_on(s.load()).boot.load_errors,
        2,
        "every such start counts"
    );
    // A good save heals it; the count stays.
    block_on(s.save(&settings(500, 1).encode())).unwrap();
    let mut s = store(s.into_flash());
    let loaded = block_on(s.load());
    assert_eq!(loaded.boot.source, ConfigSource::Flash);
    assert_eq!(loaded.boot.load_errors, 2);
}

#[test]
fn a_factory_reset_forgets_the_settings_and_keeps_the_counts() {
    let mut s = store(l4());
    let mut damaged = settings(500, 2).encode();
    damaged[0] = 99;
    block_on(s.save(&damaged)).unwrap();
    let mut s = store(s.into_flash());
    assert_eq!(block_on(s.load()).boot.load_errors, 1);
    block_on(s.save(&settings(500, 2).encode())).unwrap();
    block_on(s.factory_reset()).unwrap();
    let mut s = store(s.into_flash());
    let loaded = block_on(s.load());
    assert_eq!(loaded.settings, None);
    assert_eq!(loaded.boot.source, ConfigSource::Defaults);
    assert_eq!((loaded.boot.save_count, loaded.boot.load_errors), (2, 1));
}

#[repr(align(32))]
struct Aligned([u8; 256]);

/// A record of the store's format (see the crate's description) holding `item`, with sequence
/// number `seq`, written after the last written word of `flash` (the test's records all fit in
/// its first page).
fn append_raw<const P: usize, const W: usize, const N: usize>(
    flash: &mut MockFlashBase<P, W, N>,
    item: &[u8],
    seq: u32,
) {
    let mut record = vec![0xA5, item.len() as u8];
    record.extend(seq.to_le_bytes());
    record.extend(item);
    record.extend(protocol::modbus::crc::checksum(&record).to_le_bytes());
    record.push(0);
    record.resize(record.len().div_ceil(W) * W, 0);
    let used = flash
        .as_bytes()
        .iter()
        .rposition(|&b| b != 0xFF)
        .map_or(0, |i| i + 1);
    let at = used.div_ceil(W) * W;
    assert!(
        at + record.len() <= W * N,
        "the test's records fit in the first page"
    );
    // The flash takes words from word-aligned memory (the mock checks it).
    let mut aligned = Aligned([0; 256]);
    aligned.0[..record.len()].copy_from_slice(&record);
    block_on(flash.write(at as u32, &aligned.0[..record.len()])).unwrap();
}

/// An item of another format after the settings (another firmware's, or this store's before a
/// change of layout): that start runs the defaults and counts it, the counts of the last item
/// of ours stay, and nothing of the foreign item is taken for settings.
#[test]
fn an_item_of_another_format_gives_the_defaults_once_and_keeps_the_counts() {
    let mut s = store(l4());
    block_on(s.save(&settings(500, 2).encode())).unwrap();
    let foreign: &[&[u8]] = &[&[1, 2, 3], &[settings_store::FORMAT], &[0xFF; 40]];
    for (i, bytes) in foreign.iter().enumerate() {
        let mut flash = s.into_flash();
        // Newer than any record of the store's so far.
        append_raw(&mut flash, bytes, 1000 * (i as u32 + 1));
        let mut s2 = store(flash);
        let loaded = block_on(s2.load());
        assert_eq!(loaded.settings, None, "{bytes:?}");
        assert_eq!(loaded.boot.source, ConfigSource::Damaged, "{bytes:?}");
        assert_eq!(loaded.boot.save_count, 1, "{bytes:?}");
        let mut s3 = store(s2.into_flash());
        let again = block_on(s3.load());
        assert_eq!(
            again.boot.source,
            ConfigSource::Defaults,
            "counted once: {bytes:?}"
        );
        s = s3;
    }
    let mut s = store(s.into_flash());
    assert_eq!(block_on(s.load()).boot.load_errors, 3);
    // A save after them is loaded back, its count following the last of ours.
    assert_eq!(block_on(s.save(&settings(700, 3).encode())), Ok(2));
    let mut s = store(s.into_flash());
    assert_eq!(block_on(s.load()).settings, Some(settings(700, 3)));
}

/// A board whose settings range holds the format of the firmware before this store
/// (sequential-storage's queue of items, some of them the range's whole length round): the
/// first start runs the defaults and counts it once, the next ones run the defaults without
/// counting, and saves work (their count starting again).
#[test]
fn a_range_in_sequential_storages_format_gives_the_defaults_once_then_works() {
    fn check<const P: usize, const W: usize, const N: usize>(
        empty: MockFlashBase<P, W, N>,
        items: u32,
    ) {
        let mut queue = QueueStorage::new(
            empty,
            QueueConfig::new(MockFlashBase::<P, W, N>::FULL_FLASH_RANGE),
            Cache::new_uncached(),
        );
        for i in 0..items {
            // The previous store's items: the format, saves, load errors, the record.
            let mut item = Aligned([0; 256]);
            item.0[0] = settings_store::FORMAT;
            item.0[1..5].copy_from_slice(&(i + 1).to_le_bytes());
            item.0[7..7 + RECORD_LEN].copy_from_slice(&settings(100 + i as u16, 2).encode());
            block_on(queue.push(&item.0[..settings_store::ITEM_LEN], true)).unwrap();
        }
        let mut s = store(queue.destroy().0);
        let first = block_on(s.load());
        assert_eq!(first.settings, None, "{items} items");
        assert_eq!(first.boot.source, ConfigSource::Damaged, "{items} items");
        assert_eq!((first.boot.save_count, first.boot.load_errors), (0, 1));
        for _ in 0..2 {
            let mut again = store(s.into_flash());
            let loaded = block_on(again.load());
            assert_eq!(loaded.boot.source, ConfigSource::Defaults, "{items} items");
            assert_eq!(loaded.boot.load_errors, 1, "counted once: {items} items");
            s = again;
        }
        for i in 0..25u16 {
            assert_eq!(
                block_on(s.save(&settings(300 + i, 4).encode())),
                Ok(u32::from(i) + 1)
            );
            let mut again = store(s.into_flash());
            let loaded = block_on(again.load());
            assert_eq!(loaded.settings, Some(settings(300 + i, 4)), "{items} items");
            assert_eq!(loaded.boot.load_errors, 1);
            s = again;
        }
    }
    for items in [1, 3, 30] {
        check(l4(), items);
        check(F1::new(WriteCountCheck::OnceOnly, None, true), items);
    }
}

/// A thousand saves in a row, round and round both boards' ranges: the last one is loaded back,
/// with its count.
#[test]
fn a_thousand_saves_then_a_load() {
    fn check<const P: usize, const W: usize, const N: usize>(empty: MockFlashBase<P, W, N>) {
        let mut s = store(empty);
        for i in 0..1000u16 {
            block_on(s.save(&settings(100 + i, 1 + (i % 16) as u8).encode())).unwrap();
        }
        let mut s = store(s.into_flash());
        let loaded = block_on(s.load());
        assert_eq!(loaded.settings, Some(settings(1099, 1 + (999 % 16) as u8)));
        assert_eq!(loaded.boot.source, ConfigSource::Flash);
        assert_eq!((loaded.boot.save_count, loaded.boot.load_errors), (1000, 0));
    }
    check(l4());
    check(F1::new(WriteCountCheck::OnceOnly, None, true));
}

/// Power lost while a save erases the page it needs (the page of the oldest records), at
/// several points of the erase, on both boards' geometries: the old settings stay, nothing is
/// counted as unreadable, and the next save works.
#[test]
fn power_loss_during_the_erase_a_save_needs() {
    fn check<const P: usize, const W: usize, const N: usize>(empty: MockFlashBase<P, W, N>) {
        let page = (W * N) as u32;
        let old = settings(500, 2);
        let new = settings(900, 5);
        // Saves until the next one must erase a page that holds records: the range's pages
        // have all been written, the next save's erase is the P-th.
        let (mut flash, mut saves, mut erasing) = (empty, 0u32, 0);
        loop {
            let mut s = store(flash);
            block_on(s.save(&old.encode())).unwrap();
            saves += 1;
            flash = s.into_flash();
            let counting = Counting {
                flash: flash.clone(),
                erases: vec![0; P],
                page,
            };
            let mut trial =
                Store::new(counting, MockFlashBase::<P, W, N>::FULL_FLASH_RANGE).unwrap();
            block_on(trial.save(&new.encode())).unwrap();
            if trial.into_flash().erases.iter().sum::<u32>() > 0 {
                erasing += 1;
                if erasing == P {
                    break;
                }
            }
        }
        let base = flash;
        for cut in [0, 1, W as u32, page / 2, page - 1] {
            let mut flash = base.clone();
            flash.bytes_until_shutoff = Some(cut);
            let mut s = store(flash);
            assert!(
                block_on(s.save(&new.encode())).is_err(),
                "cut after {cut} bytes"
            );
            let mut flash = s.into_flash();
            flash.bytes_until_shutoff = None;
            let mut s = store(flash);
            let loaded = block_on(s.load());
            assert_eq!(loaded.settings, Some(old), "cut after {cut} bytes");
            assert_eq!(loaded.boot.load_errors, 0, "cut after {cut} bytes");
            assert_eq!(block_on(s.save(&new.encode())), Ok(saves + 1));
            let mut s = store(s.into_flash());
            assert_eq!(
                block_on(s.load()).settings,
                Some(new),
                "cut after {cut} bytes"
            );
        }
    }
    check(l4());
    check(F1::new(WriteCountCheck::OnceOnly, None, true));
}

/// Power lost after every possible number of bytes written during a save: the next start finds
/// the old settings or the new ones, never a mix, and the store keeps working. With the range
/// filled to several depths, so that the save cut short is sometimes one that must first erase
/// the oldest page (checked: at least one depth is).
#[test]
fn power_loss_during_a_save_leaves_the_old_or_the_new_settings() {
    let mut erasing = 0;
    for saves_before in [7, 16, 17, 18, 19, 20] {
        erasing += usize::from(cut_every_byte_of_a_save(l4(), saves_before));
    }
    assert!(erasing > 0, "no save cut short had to erase a page");
}

/// The same in the F103's geometry: 1 KiB pages, written in 16-bit half-words.
#[test]
fn power_loss_during_a_save_on_the_f103s_flash() {
    let mut erasing = 0;
    for saves_before in [3, 6, 7, 8, 9] {
        let empty = F1::new(WriteCountCheck::OnceOnly, None, true);
        erasing += usize::from(cut_every_byte_of_a_save(empty, saves_before));
    }
    assert!(erasing > 0, "no save cut short had to erase a page");
}

/// The power-loss check on `empty` after `saves_before` saves; whether the save cut short
/// erases a page.
fn cut_every_byte_of_a_save<const P: usize, const W: usize, const N: usize>(
    empty: MockFlashBase<P, W, N>,
    saves_before: u16,
) -> bool {
    let page = (W * N) as u32;
    let old = settings(500, 2);
    let new = settings(900, 5);
    let mut base = store(empty);
    for i in 0..saves_before {
        block_on(base.save(&settings(100 + i, 1).encode())).unwrap();
    }
    block_on(base.save(&old.encode())).unwrap();
    let base = base.into_flash();
    let erases = {
        let counting = Counting {
            flash: base.clone(),
            erases: vec![0; P],
            page,
        };
        let mut s = Store::new(counting, MockFlashBase::<P, W, N>::FULL_FLASH_RANGE).unwrap();
        block_on(s.save(&new.encode())).unwrap();
        s.into_flash().erases.iter().sum::<u32>()
    };
    let mut outcomes = [0usize; 2];
    // The mock flash counts an erase as the page's bytes: a save that erases first is cut
    // during the erase for the first page's worth.
    let span = if erases > 0 { page } else { 0 } + 4 * RECORD_LEN as u32;
    for cut in 0..span {
        let mut flash = base.clone();
        flash.bytes_until_shutoff = Some(cut);
        let mut s = store(flash);
        let _ = block_on(s.save(&new.encode()));
        let mut flash = s.into_flash();
        flash.bytes_until_shutoff = None;
        let mut s = store(flash);
        let loaded = block_on(s.load());
        match loaded.settings {
            Some(found) if found == old => outcomes[0] += 1,
            Some(found) if found == new => outcomes[1] += 1,
            other => panic!("cut after {cut} bytes: {other:?} ({:?})", loaded.boot),
        }
        // And a save after the power comes back works.
        block_on(s.save(&new.encode()))
            .unwrap_or_else(|e| panic!("the store recovers: {e:?}, cut after {cut} bytes"));
        let mut s = store(s.into_flash());
        assert_eq!(
            block_on(s.load()).settings,
            Some(new),
            "cut after {cut} bytes"
        );
    }
    assert!(
        outcomes[0] > 0 && outcomes[1] > 0,
        "both ends reached: {outcomes:?} ({saves_before} saves before)"
    );
    erases > 0
}

/// A flash that counts the erases of each page.
struct Counting<F> {
    flash: F,
    erases: Vec<u32>,
    page: u32,
}

impl<F: ErrorType> ErrorType for Counting<F> {
    type Error = F::Error;
}

impl<F: ReadNorFlash> ReadNorFlash for Counting<F> {
    const READ_SIZE: usize = F::READ_SIZE;
    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.flash.read(offset, bytes).await
    }
    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl<F: NorFlash> NorFlash for Counting<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;
    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        for page in from / self.page..to / self.page {
            self.erases[page as usize] += 1;
        }
        self.flash.erase(from, to).await
    }
    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.flash.write(offset, bytes).await
    }
}

/// Many saves wear the pages evenly: the range is written round and round, each page erased
/// as often as the others (give or take one), and far less often than once per save.
#[test]
fn wear_spreads_over_the_pages() {
    const SAVES: u32 = 2_000;
    type Wide = MockFlashBase<4, 8, 256>;
    let counting = Counting {
        flash: Wide::new(WriteCountCheck::OnceOnly, None, true),
        erases: vec![0; 4],
        page: 2048,
    };
    let mut s = Store::new(counting, Wide::FULL_FLASH_RANGE).unwrap();
    for i in 0..SAVES {
        let wanted = settings(50 + (i % 1000) as u16, 1 + (i % 15) as u8);
        block_on(s.save(&wanted.encode())).unwrap();
    }
    let counting = s.into_flash();
    let erases = &counting.erases;
    let (least, most) = (*erases.iter().min().unwrap(), *erases.iter().max().unwrap());
    assert!(most - least <= 1, "uneven wear: {erases:?}");
    // Each save appends one item (about 200 bytes with its header): a 2 KiB page takes about
    // 10 saves, so each of the 4 pages is erased about SAVES / 40 times.
    let total: u32 = erases.iter().sum();
    assert!(total <= SAVES / 5, "{erases:?} erases for {SAVES} saves");
    assert!(
        least >= SAVES / 80,
        "{erases:?}: the range was really cycled"
    );
    let mut s = Store::new(counting.flash, Wide::FULL_FLASH_RANGE).unwrap();
    let last = settings(
        50 + ((SAVES - 1) % 1000) as u16,
        1 + ((SAVES - 1) % 15) as u8,
    );
    let loaded = block_on(s.load());
    assert_eq!(loaded.settings, Some(last));
    assert_eq!(loaded.boot.save_count, SAVES);
}

/// Power lost during the very first save of a new board: nothing readable is in the range, but
/// it is not erased either. That start runs the defaults and counts it (unless nothing was
/// written at all), once; then saves work. (Cut after the record's CRC, in its padding, the
/// record is whole: the new settings.)
#[test]
fn power_loss_during_the_first_save_is_counted_once() {
    let new = settings(900, 5);
    let mut whole = 0;
    for cut in 0..4 * RECORD_LEN as u32 {
        let mut flash = l4();
        flash.bytes_until_shutoff = Some(cut);
        let mut s = store(flash);
        let _ = block_on(s.save(&new.encode()));
        let mut flash = s.into_flash();
        flash.bytes_until_shutoff = None;
        let mut s = store(flash);
        let loaded = block_on(s.load());
        if loaded.settings == Some(new) {
            // Header (6 bytes), item and CRC written.
            assert!(
                cut >= 6 + settings_store::ITEM_LEN as u32 + 2,
                "cut after {cut} bytes"
            );
            whole += 1;
            continue;
        }
        let counted = u16::from(cut > 0);
        assert_eq!(loaded.settings, None, "cut after {cut} bytes");
        assert_eq!(loaded.boot.load_errors, counted, "cut after {cut} bytes");
        let mut s = store(s.into_flash());
        let again = block_on(s.load());
        assert_eq!(
            again.boot.source,
            ConfigSource::Defaults,
            "cut after {cut} bytes"
        );
        assert_eq!(
            again.boot.load_errors, counted,
            "counted once: cut after {cut} bytes"
        );
        assert_eq!(
            block_on(s.save(&new.encode())),
            Ok(1),
            "cut after {cut} bytes"
        );
        let mut s = store(s.into_flash());
        assert_eq!(
            block_on(s.load()).settings,
            Some(new),
            "cut after {cut} bytes"
        );
    }
    assert!(whole > 0, "some cuts left the record whole");
}
