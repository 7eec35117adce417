//! The settings store on sequential-storage's in-memory flash, in the geometry of both boards'
//! internal flash: first start, save and load, damaged and foreign records, the fallback to the
//! newest record that decodes, sequence numbers, a range left in the previous firmware's format
//! or in the store's layout before, factory reset, identical and paced saves, power loss at
//! every byte of a save and during the erase it needs, and wear over many saves. (A harsher
//! flash, with torn bits, undefined erases and ECC errors, is `tests/harsh.rs`.)

mod common;

use common::{item, now, record, settings, write, Blocking, Layout, HEADER};
use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use futures::executor::block_on;
use protocol::plc::settings::{Settings, RECORD_LEN};
use protocol::plc::ConfigSource;
use sequential_storage::cache::Cache;
use sequential_storage::mock_flash::{MockFlashBase, WriteCountCheck};
use sequential_storage::queue::{QueueConfig, QueueStorage};
use settings_store::{Store, StoreError, SAVE_BURST, SAVE_INTERVAL_S};

/// STM32L475: 2 KiB pages, 64-bit words, written once per erase; two pages for the settings.
type L4 = Blocking<MockFlashBase<2, 8, 256>>;
/// 1 KiB pages in 16-bit half-words (the F103's page; its flash takes 32-bit words made of
/// two half-words: `tests/harsh.rs`); two pages.
type F1 = Blocking<MockFlashBase<2, 2, 512>>;

fn l4() -> L4 {
    Blocking(MockFlashBase::new(WriteCountCheck::OnceOnly, None, true))
}

fn f1() -> F1 {
    Blocking(MockFlashBase::new(WriteCountCheck::OnceOnly, None, true))
}

fn store<const P: usize, const W: usize, const N: usize>(
    flash: Blocking<MockFlashBase<P, W, N>>,
) -> Store<Blocking<MockFlashBase<P, W, N>>> {
    Store::new(flash, MockFlashBase::<P, W, N>::FULL_FLASH_RANGE).expect("a valid range")
}

/// A power cycle: a new store on the same flash.
fn restart<const P: usize, const W: usize, const N: usize>(
    s: Store<Blocking<MockFlashBase<P, W, N>>>,
) -> Store<Blocking<MockFlashBase<P, W, N>>> {
    store(s.into_flash())
}

/// Save `settings` in `s`, at the tests' clock.
fn save<F: NorFlash>(s: &mut Store<F>, settings: &Settings) -> Result<u32, StoreError> {
    s.save(&settings.encode(), now())
}

/// The flash's bytes.
fn bytes<const P: usize, const W: usize, const N: usize>(
    s: &Store<Blocking<MockFlashBase<P, W, N>>>,
) -> Vec<u8> {
    s.flash().0.as_bytes().to_vec()
}

#[test]
fn the_first_start_has_nothing_and_a_save_is_loaded_back() {
    let mut s = store(l4());
    let first = s.load();
    assert_eq!(first.settings, None);
    assert_eq!(first.boot.source, ConfigSource::Defaults);
    assert_eq!((first.boot.save_count, first.boot.load_errors), (0, 0));
    let wanted = settings(500, 3);
    assert_eq!(save(&mut s, &wanted), Ok(1));
    assert_eq!(save(&mut s, &settings(700, 2)), Ok(2));
    assert_eq!(save(&mut s, &wanted), Ok(3));
    let mut s = restart(s);
    let loaded = s.load();
    assert_eq!(loaded.settings, Some(wanted));
    assert_eq!(loaded.boot.source, ConfigSource::Flash);
    assert_eq!(loaded.boot.save_count, 3);
}

#[test]
fn the_same_works_on_the_f103s_half_word_flash() {
    let mut s = store(f1());
    let wanted = settings(250, 16);
    assert_eq!(save(&mut s, &wanted), Ok(1));
    let mut s = restart(s);
    assert_eq!(s.load().settings, Some(wanted));
}

/// A record with another format version (a firmware downgrade, say) gives the defaults, not the
/// older settings before it, and the start is counted, in flash too: once, not at every start.
#[test]
fn a_newer_format_gives_the_defaults_and_is_counted_once() {
    let mut s = store(l4());
    save(&mut s, &settings(300, 2)).unwrap();
    let mut record = settings(500, 1).encode();
    record[0] = 99; // another format version
    assert_eq!(s.save(&record, now()), Ok(2));
    let mut s = restart(s);
    let loaded = s.load();
    assert_eq!(loaded.settings, None);
    assert_eq!(loaded.boot.source, ConfigSource::Damaged);
    assert_eq!((loaded.boot.save_count, loaded.boot.load_errors), (2, 1));
    let written = bytes(&s);
    for _ in 0..3 {
        s = restart(s);
        let again = s.load();
        assert_eq!(again.settings, None);
        assert_eq!(again.boot.source, ConfigSource::Defaults, "counted once");
        assert_eq!((again.boot.save_count, again.boot.load_errors), (2, 1));
        assert_eq!(bytes(&s), written, "nothing written at later starts");
    }
    // A good save heals it; the count stays.
    save(&mut s, &settings(500, 1)).unwrap();
    let mut s = restart(s);
    let loaded = s.load();
    assert_eq!(loaded.boot.source, ConfigSource::Flash);
    assert_eq!(loaded.settings, Some(settings(500, 1)));
    assert_eq!((loaded.boot.save_count, loaded.boot.load_errors), (3, 1));
}

/// The newest record passes the store's CRC but its settings do not decode (their own CRC, or a
/// field out of range): the newest record before it that decodes is loaded, the start counted
/// once (a record of those settings with the counts), and later starts write nothing.
#[test]
fn a_newest_record_that_does_not_decode_falls_back_to_the_one_before() {
    for damage in [20usize, RECORD_LEN - 1] {
        let mut s = store(l4());
        let good = settings(450, 4);
        save(&mut s, &settings(100, 1)).unwrap();
        save(&mut s, &good).unwrap();
        for k in 0..2 {
            let mut bad = settings(900 + k, 7).encode();
            bad[damage] ^= 0x40;
            s.save(&bad, now()).unwrap();
        }
        let mut s = restart(s);
        let loaded = s.load();
        assert_eq!(loaded.settings, Some(good), "damage at {damage}");
        assert_eq!(loaded.boot.source, ConfigSource::Flash);
        assert_eq!((loaded.boot.save_count, loaded.boot.load_errors), (4, 1));
        let written = bytes(&s);
        for _ in 0..3 {
            s = restart(s);
            let again = s.load();
            assert_eq!(again.settings, Some(good));
            assert_eq!((again.boot.save_count, again.boot.load_errors), (4, 1));
            assert_eq!(bytes(&s), written, "counted once");
        }
        assert_eq!(save(&mut s, &settings(800, 2)), Ok(5));
        assert_eq!(restart(s).load().settings, Some(settings(800, 2)));
    }
}

/// Behind a factory reset there is nothing to fall back to: the defaults.
#[test]
fn no_fallback_behind_a_factory_reset() {
    let mut s = store(l4());
    save(&mut s, &settings(450, 4)).unwrap();
    s.factory_reset().unwrap();
    let mut bad = settings(900, 7).encode();
    bad[30] ^= 1;
    s.save(&bad, now()).unwrap();
    let loaded = restart(s).load();
    assert_eq!(loaded.settings, None);
    assert_eq!(loaded.boot.source, ConfigSource::Damaged);
}

#[test]
fn a_factory_reset_forgets_the_settings_and_keeps_the_counts() {
    let mut s = store(l4());
    let mut damaged = settings(500, 2).encode();
    damaged[0] = 99;
    s.save(&damaged, now()).unwrap();
    let mut s = restart(s);
    assert_eq!(s.load().boot.load_errors, 1);
    save(&mut s, &settings(500, 2)).unwrap();
    s.factory_reset().unwrap();
    let mut s = restart(s);
    let loaded = s.load();
    assert_eq!(loaded.settings, None);
    assert_eq!(loaded.boot.source, ConfigSource::Defaults);
    assert_eq!((loaded.boot.save_count, loaded.boot.load_errors), (2, 1));
}

/// A factory reset erases the whole range, whatever it holds: afterwards it has one page
/// header and one record (the counts), nothing else.
#[test]
fn a_factory_reset_erases_the_whole_range() {
    let mut s = store(l4());
    for i in 0..13 {
        save(&mut s, &settings(100 + i, 3)).unwrap();
    }
    s.factory_reset().unwrap();
    let flash = bytes(&s);
    let page = flash.len() / 2;
    let used: Vec<usize> = (0..2)
        .map(|p| {
            flash[p * page..(p + 1) * page]
                .iter()
                .rposition(|&b| b != 0xFF)
                .map_or(0, |i| i + 1)
        })
        .collect();
    // The header and a record of 6 + 7 + 4 bytes and padding, in one page.
    let holding: Vec<usize> = used.iter().copied().filter(|&u| u > 0).collect();
    assert_eq!(holding, [8 + 24], "{used:?}");
    let p = used.iter().position(|&u| u > 0).unwrap();
    assert_eq!(&flash[p * page..p * page + 8], &HEADER);
    let loaded = restart(s).load();
    assert_eq!(loaded.boot.save_count, 13);
}

/// Write `bytes` after the last written byte of the flash (in its first page).
fn append_raw<const P: usize, const W: usize, const N: usize>(
    flash: &mut Blocking<MockFlashBase<P, W, N>>,
    bytes: &[u8],
) {
    let used = flash
        .0
        .as_bytes()
        .iter()
        .rposition(|&b| b != 0xFF)
        .map_or(0, |i| i + 1);
    let at = used.div_ceil(W) * W;
    assert!(
        at + bytes.len() <= W * N,
        "the test's records fit in the first page"
    );
    write(flash, at, bytes);
}

/// An item of another format after the settings (another firmware's, or this store's before a
/// change of layout): that start runs the defaults and counts it, the counts of the last item
/// of ours stay, and nothing of the foreign item is taken for settings.
#[test]
fn an_item_of_another_format_gives_the_defaults_once_and_keeps_the_counts() {
    let mut s = store(l4());
    save(&mut s, &settings(500, 2)).unwrap();
    let foreign: &[&[u8]] = &[&[1, 2, 3], &[settings_store::FORMAT], &[0xFF; 40]];
    for (i, foreign) in foreign.iter().enumerate() {
        let mut flash = s.into_flash();
        // Newer than any record of the store's so far.
        append_raw(
            &mut flash,
            &record(Layout::Current, foreign, 1000 * (i as u32 + 1), 8),
        );
        let mut s2 = store(flash);
        let loaded = s2.load();
        assert_eq!(loaded.settings, None, "{foreign:?}");
        assert_eq!(loaded.boot.source, ConfigSource::Damaged, "{foreign:?}");
        assert_eq!(loaded.boot.save_count, 1, "{foreign:?}");
        let mut s3 = restart(s2);
        let again = s3.load();
        assert_eq!(
            again.boot.source,
            ConfigSource::Defaults,
            "counted once: {foreign:?}"
        );
        s = s3;
    }
    let mut s = restart(s);
    assert_eq!(s.load().boot.load_errors, 3);
    // A save after them is loaded back, its count following the last of ours.
    assert_eq!(save(&mut s, &settings(700, 3)), Ok(2));
    let mut s = restart(s);
    assert_eq!(s.load().settings, Some(settings(700, 3)));
}

/// Sequence numbers are serial numbers (RFC 1982): 0 follows 0xFFFFFFFF, and a record's number
/// less than 2³¹ ahead of another's is newer, else older. No stray number pins the store: a
/// record far ahead is the newest, but the next save's (its number plus one) is newer still; one
/// far behind is passed over.
#[test]
fn no_sequence_number_pins_the_store() {
    // The first record's number, how far the second's is ahead (wrapping), and whether the
    // second is then the newest.
    let cases = [
        (0xFFFF_FFFE, 1, true),
        (0, u32::MAX, false),
        (0xFFFF_FFF0, 0x20, true),
        (5, 0x4000_0000, true),
        (5, 0xC000_0000, false),
    ];
    for (first, ahead, second_newest) in cases {
        let mut flash = l4();
        write(&mut flash, 0, &HEADER);
        let old = settings(300, 2);
        let stray = settings(400, 3);
        let a = record(Layout::Current, &item(1, 0, Some(&old)), first, 8);
        let second = first.wrapping_add(ahead);
        let b = record(Layout::Current, &item(2, 0, Some(&stray)), second, 8);
        write(&mut flash, 8, &a);
        write(&mut flash, 8 + a.len(), &b);
        let mut s = store(flash);
        let what = format!("records {first:#x} and {second:#x}");
        let loaded = s.load();
        let (wanted, count) = if second_newest { (stray, 2) } else { (old, 1) };
        assert_eq!(loaded.settings, Some(wanted), "{what}");
        for i in 0..30u16 {
            let new = settings(500 + i, 1 + (i % 16) as u8);
            assert_eq!(save(&mut s, &new), Ok(count + 1 + u32::from(i)), "{what}");
            s = restart(s);
            assert_eq!(s.load().settings, Some(new), "{what}, save {i}");
        }
    }
}

/// The range as the store before page headers left it (records of magic 0xA5 with a CRC-16,
/// from the start of each page) is read: the newest record loads, with its counts; a record
/// whose settings do not decode falls back there too. The first save writes the current layout
/// in the page after the newest record's, carrying the counts over, and is loaded back.
#[test]
fn the_layout_before_is_read_then_migrated() {
    fn check<const P: usize, const W: usize, const N: usize>(
        mut flash: Blocking<MockFlashBase<P, W, N>>,
        newest_decodes: bool,
    ) {
        let page = W * N;
        let mut at = [0usize; 2];
        let mut last = None;
        // 4 records in page 0, then 4 in page 1.
        for i in 0..8u32 {
            let s = settings(100 + i as u16, 2);
            let mut encoded = s.encode();
            if i == 7 && !newest_decodes {
                encoded[40] ^= 0x10;
            } else {
                last = Some(s);
            }
            let mut it = item(i + 1, 2, None);
            it.extend(encoded);
            let r = record(Layout::Before, &it, 100 + i, W);
            let p = usize::from(i >= 4);
            write(&mut flash, p * page + at[p], &r);
            at[p] += r.len();
        }
        let mut s = store(flash);
        let loaded = s.load();
        assert_eq!(loaded.settings, last);
        assert_eq!(loaded.boot.source, ConfigSource::Flash);
        let errors = 2 + u16::from(!newest_decodes);
        assert_eq!(
            (loaded.boot.save_count, loaded.boot.load_errors),
            (8, errors)
        );
        if newest_decodes {
            // Nothing was written: the old layout as it was.
            assert!(bytes(&s).chunks(page).all(|p| p[..8] != HEADER));
        }
        s = restart(s);
        assert_eq!(s.load().settings, last);
        let new = settings(999, 9);
        assert_eq!(save(&mut s, &new), Ok(9));
        let flash = bytes(&s);
        // Page 0 (after the newest's, page 1) now has the header.
        assert_eq!(&flash[..8], &HEADER);
        s = restart(s);
        let loaded = s.load();
        assert_eq!(loaded.settings, Some(new));
        assert_eq!(
            (loaded.boot.save_count, loaded.boot.load_errors),
            (9, errors)
        );
        for i in 0..20u16 {
            save(&mut s, &settings(200 + i, 5)).unwrap();
        }
        assert_eq!(restart(s).load().settings, Some(settings(219, 5)));
    }
    for newest_decodes in [true, false] {
        check(l4(), newest_decodes);
        check(f1(), newest_decodes);
    }
}

/// A board whose settings range holds the format of the firmware before this store
/// (sequential-storage's queue of items, some of them the range's whole length round): the
/// first start runs the defaults and counts it once, the next ones run the defaults without
/// counting, and saves work (their count starting again).
#[test]
fn a_range_in_sequential_storages_format_gives_the_defaults_once_then_works() {
    fn check<const P: usize, const W: usize, const N: usize>(
        empty: Blocking<MockFlashBase<P, W, N>>,
        items: u32,
    ) {
        let mut queue = QueueStorage::new(
            empty.0,
            QueueConfig::new(MockFlashBase::<P, W, N>::FULL_FLASH_RANGE),
            Cache::new_uncached(),
        );
        for i in 0..items {
            // The previous store's items: the format, saves, load errors, the record.
            let item = item(i + 1, 0, Some(&settings(100 + i as u16, 2)));
            let mut aligned = common::Aligned([0; 512]);
            aligned.0[..item.len()].copy_from_slice(&item);
            block_on(queue.push(&aligned.0[..item.len()], true)).unwrap();
        }
        let mut s = store(Blocking(queue.destroy().0));
        let first = s.load();
        assert_eq!(first.settings, None, "{items} items");
        assert_eq!(first.boot.source, ConfigSource::Damaged, "{items} items");
        assert_eq!((first.boot.save_count, first.boot.load_errors), (0, 1));
        for _ in 0..2 {
            let mut again = restart(s);
            let loaded = again.load();
            assert_eq!(loaded.boot.source, ConfigSource::Defaults, "{items} items");
            assert_eq!(loaded.boot.load_errors, 1, "counted once: {items} items");
            s = again;
        }
        for i in 0..25u16 {
            assert_eq!(save(&mut s, &settings(300 + i, 4)), Ok(u32::from(i) + 1));
            let mut again = restart(s);
            let loaded = again.load();
            assert_eq!(loaded.settings, Some(settings(300 + i, 4)), "{items} items");
            assert_eq!(loaded.boot.load_errors, 1);
            s = again;
        }
    }
    for items in [1, 3, 30] {
        check(l4(), items);
        check(f1(), items);
    }
}

/// A save of the settings the newest record holds writes nothing and keeps the count.
#[test]
fn a_save_of_the_same_settings_writes_nothing() {
    let mut s = store(l4());
    let wanted = settings(500, 3);
    assert_eq!(save(&mut s, &wanted), Ok(1));
    let written = bytes(&s);
    for _ in 0..50 {
        assert_eq!(save(&mut s, &wanted), Ok(1));
    }
    assert_eq!(bytes(&s), written);
    assert_eq!(save(&mut s, &settings(501, 3)), Ok(2));
}

/// Saves that write are paced: SAVE_BURST at once, then one per SAVE_INTERVAL_S; a save too
/// soon is refused (TooSoon: the PLC sees SAVESTAT 3) and writes nothing; a save of the same
/// settings is never refused.
#[test]
fn saves_are_paced() {
    let mut s = store(l4());
    let t0 = 1000;
    for i in 0..SAVE_BURST {
        assert_eq!(s.save(&settings(100 + i as u16, 2).encode(), t0), Ok(i + 1));
    }
    let written = bytes(&s);
    let next = settings(99, 3).encode();
    assert_eq!(s.save(&next, t0), Err(StoreError::TooSoon));
    assert_eq!(
        s.save(&next, t0 + SAVE_INTERVAL_S - 1),
        Err(StoreError::TooSoon)
    );
    assert_eq!(bytes(&s), written, "a refused save writes nothing");
    let last = settings(100 + SAVE_BURST as u16 - 1, 2).encode();
    assert_eq!(s.save(&last, t0), Ok(SAVE_BURST), "the same settings");
    assert_eq!(s.save(&next, t0 + SAVE_INTERVAL_S), Ok(SAVE_BURST + 1));
    assert_eq!(
        s.save(&settings(98, 3).encode(), t0 + SAVE_INTERVAL_S),
        Err(StoreError::TooSoon)
    );
    // After a long pause, a whole burst again.
    let later = t0 + (SAVE_BURST + 2) * SAVE_INTERVAL_S;
    for i in 0..SAVE_BURST {
        assert!(s.save(&settings(200 + i as u16, 2).encode(), later).is_ok());
    }
    assert_eq!(s.save(&next, later), Err(StoreError::TooSoon));
}

/// A thousand saves in a row, round and round both boards' ranges: the last one is loaded back,
/// with its count.
#[test]
fn a_thousand_saves_then_a_load() {
    fn check<const P: usize, const W: usize, const N: usize>(
        empty: Blocking<MockFlashBase<P, W, N>>,
    ) {
        let mut s = store(empty);
        for i in 0..1000u16 {
            save(&mut s, &settings(100 + i, 1 + (i % 16) as u8)).unwrap();
        }
        let mut s = restart(s);
        let loaded = s.load();
        assert_eq!(loaded.settings, Some(settings(1099, 1 + (999 % 16) as u8)));
        assert_eq!(loaded.boot.source, ConfigSource::Flash);
        assert_eq!((loaded.boot.save_count, loaded.boot.load_errors), (1000, 0));
    }
    check(l4());
    check(f1());
}

/// Power lost while a save erases the page it needs (the page of the oldest records), at
/// several points of the erase, on both boards' geometries: the old settings stay, nothing is
/// counted as unreadable, and the next save works.
#[test]
fn power_loss_during_the_erase_a_save_needs() {
    fn check<const P: usize, const W: usize, const N: usize>(
        empty: Blocking<MockFlashBase<P, W, N>>,
    ) {
        let page = (W * N) as u32;
        let old = settings(500, 2);
        let new = settings(900, 5);
        // Saves until the next one must erase a page that holds records: the range's pages
        // have all been written, the next save's erase is the P+1-th.
        let (mut flash, mut saves, mut erasing) = (empty, 0u32, 0);
        loop {
            let mut s = store(flash);
            save(&mut s, &settings(100 + saves as u16, 1)).unwrap();
            save(&mut s, &old).unwrap();
            saves += 2;
            flash = s.into_flash();
            let counting = Counting {
                flash: flash.clone(),
                erases: vec![0; P],
                page,
            };
            let mut trial =
                Store::new(counting, MockFlashBase::<P, W, N>::FULL_FLASH_RANGE).unwrap();
            save(&mut trial, &new).unwrap();
            if trial.into_flash().erases.iter().sum::<u32>() > 0 {
                erasing += 1;
                if erasing > P {
                    break;
                }
            }
        }
        let base = flash;
        for cut in [0, 1, W as u32, page / 2, page - 1] {
            let mut flash = base.clone();
            flash.0.bytes_until_shutoff = Some(cut);
            let mut s = store(flash);
            assert!(save(&mut s, &new).is_err(), "cut after {cut} bytes");
            let mut flash = s.into_flash();
            flash.0.bytes_until_shutoff = None;
            let mut s = store(flash);
            let loaded = s.load();
            assert_eq!(loaded.settings, Some(old), "cut after {cut} bytes");
            assert_eq!(loaded.boot.load_errors, 0, "cut after {cut} bytes");
            assert_eq!(save(&mut s, &new), Ok(saves + 1));
            let mut s = restart(s);
            assert_eq!(s.load().settings, Some(new), "cut after {cut} bytes");
        }
    }
    check(l4());
    check(f1());
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

/// The same in half-words.
#[test]
fn power_loss_during_a_save_on_the_f103s_flash() {
    let mut erasing = 0;
    for saves_before in [3, 6, 7, 8, 9] {
        erasing += usize::from(cut_every_byte_of_a_save(f1(), saves_before));
    }
    assert!(erasing > 0, "no save cut short had to erase a page");
}

/// The power-loss check on `empty` after `saves_before` saves; whether the save cut short
/// erases a page.
fn cut_every_byte_of_a_save<const P: usize, const W: usize, const N: usize>(
    empty: Blocking<MockFlashBase<P, W, N>>,
    saves_before: u16,
) -> bool {
    let page = (W * N) as u32;
    let old = settings(500, 2);
    let new = settings(900, 5);
    let mut base = store(empty);
    for i in 0..saves_before {
        save(&mut base, &settings(100 + i, 1)).unwrap();
    }
    save(&mut base, &old).unwrap();
    let base = base.into_flash();
    let erases = {
        let counting = Counting {
            flash: base.clone(),
            erases: vec![0; P],
            page,
        };
        let mut s = Store::new(counting, MockFlashBase::<P, W, N>::FULL_FLASH_RANGE).unwrap();
        save(&mut s, &new).unwrap();
        s.into_flash().erases.iter().sum::<u32>()
    };
    let mut outcomes = [0usize; 2];
    // The mock flash counts an erase as the page's bytes: a save that erases first is cut
    // during the erase for the first page's worth.
    let span = if erases > 0 { page } else { 0 } + 4 * RECORD_LEN as u32;
    for cut in 0..span {
        let mut flash = base.clone();
        flash.0.bytes_until_shutoff = Some(cut);
        let mut s = store(flash);
        let _ = save(&mut s, &new);
        let mut flash = s.into_flash();
        flash.0.bytes_until_shutoff = None;
        let mut s = store(flash);
        let loaded = s.load();
        match loaded.settings {
            Some(found) if found == old => outcomes[0] += 1,
            Some(found) if found == new => outcomes[1] += 1,
            other => panic!("cut after {cut} bytes: {other:?} ({:?})", loaded.boot),
        }
        assert_eq!(loaded.boot.load_errors, 0, "cut after {cut} bytes");
        // And a save after the power comes back works.
        save(&mut s, &new)
            .unwrap_or_else(|e| panic!("the store recovers: {e:?}, cut after {cut} bytes"));
        let mut s = restart(s);
        assert_eq!(s.load().settings, Some(new), "cut after {cut} bytes");
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
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.flash.read(offset, bytes)
    }
    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl<F: NorFlash> NorFlash for Counting<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        for page in from / self.page..to / self.page {
            self.erases[page as usize] += 1;
        }
        self.flash.erase(from, to)
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.flash.write(offset, bytes)
    }
}

/// Many saves wear the pages evenly: the range is written round and round, each page erased
/// as often as the others (give or take one), and far less often than once per save.
#[test]
fn wear_spreads_over_the_pages() {
    const SAVES: u32 = 2_000;
    type Wide = MockFlashBase<4, 8, 256>;
    let counting = Counting {
        flash: Blocking(Wide::new(WriteCountCheck::OnceOnly, None, true)),
        erases: vec![0; 4],
        page: 2048,
    };
    let mut s = Store::new(counting, Wide::FULL_FLASH_RANGE).unwrap();
    for i in 0..SAVES {
        let wanted = settings(50 + (i % 1000) as u16, 1 + (i % 15) as u8);
        save(&mut s, &wanted).unwrap();
    }
    let counting = s.into_flash();
    let erases = &counting.erases;
    let (least, most) = (*erases.iter().min().unwrap(), *erases.iter().max().unwrap());
    assert!(most - least <= 1, "uneven wear: {erases:?}");
    // Each save appends one record of 232 bytes: a 2 KiB page takes 8 after its header, so
    // the pages are erased SAVES / 8 times in all, each of the 4 SAVES / 32 times.
    let total: u32 = erases.iter().sum();
    assert!(
        total <= SAVES / 8 + 1,
        "{erases:?} erases for {SAVES} saves"
    );
    assert!(
        least >= SAVES / 32 - 1,
        "{erases:?}: the range was really cycled"
    );
    let mut s = Store::new(counting.flash, Wide::FULL_FLASH_RANGE).unwrap();
    let last = settings(
        50 + ((SAVES - 1) % 1000) as u16,
        1 + ((SAVES - 1) % 15) as u8,
    );
    let loaded = s.load();
    assert_eq!(loaded.settings, Some(last));
    assert_eq!(loaded.boot.save_count, SAVES);
}

/// Power lost during the very first save of a new board (which erases the first page before
/// it writes its header and the record): nothing readable is in the range, but it may not be
/// erased either. That start runs the defaults and counts it if anything after the header was
/// written, once; then saves work. (Cut after the record's CRC, in its padding, the record is
/// torn: refused; cut after the padding, it is whole: the new settings.)
#[test]
fn power_loss_during_the_first_save_is_counted_once() {
    let new = settings(900, 5);
    let page = 2048;
    let mut whole = 0;
    for cut in (0..8).chain(page..page + 8 + 4 * RECORD_LEN as u32) {
        let mut flash = l4();
        flash.0.bytes_until_shutoff = Some(cut);
        let mut s = store(flash);
        let _ = save(&mut s, &new);
        let mut flash = s.into_flash();
        flash.0.bytes_until_shutoff = None;
        let mut s = store(flash);
        let loaded = s.load();
        if loaded.settings == Some(new) {
            // Erase, header, record head, item, CRC and padding (to 232 bytes) written.
            assert!(cut >= page + 8 + 232, "cut after {cut} bytes");
            whole += 1;
            continue;
        }
        // Something of the header, or of the record, written (a header alone is no more than
        // an erased page).
        let counted = u16::from(cut > page && cut != page + 8);
        assert_eq!(loaded.settings, None, "cut after {cut} bytes");
        assert_eq!(loaded.boot.load_errors, counted, "cut after {cut} bytes");
        let mut s = restart(s);
        let again = s.load();
        assert_eq!(
            again.boot.source,
            ConfigSource::Defaults,
            "cut after {cut} bytes"
        );
        assert_eq!(
            again.boot.load_errors, counted,
            "counted once: cut after {cut} bytes"
        );
        assert_eq!(save(&mut s, &new), Ok(1), "cut after {cut} bytes");
        let mut s = restart(s);
        assert_eq!(s.load().settings, Some(new), "cut after {cut} bytes");
    }
    assert!(whole > 0, "some cuts left the record whole");
}
