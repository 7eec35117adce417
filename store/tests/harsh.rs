//! The settings store on a harsh model of NOR flash, in each board's geometry, and a seeded
//! campaign of random power cuts.
//!
//! The model ([`Nor`]): erase pages; words of `WRITE` bytes (the store's unit) programmed as
//! program units of `UNIT` bytes one after the other; optionally an ECC over `ECC`-byte words.
//! A power cut while a unit is programmed leaves a random subset of the bits that were to be
//! cleared cleared (or none, or all); with ECC, that word then reads back as an error (the
//! L475's double ECC error) until its page is erased. A cut erase leaves the page half erased:
//! either each of its cleared bits set with a random probability, or random bytes here and
//! there (undefined), the rest erased or as they were; with ECC, any word neither erased nor
//! as it was, and some that look as they were, read back as errors. Writing a unit that is not
//! erased, or a word that reads back as an error, is the store's fault (counted as a violation).
//! Reads are stable (a cell reads the same every time).
//!
//! The campaign ([`campaign`]) runs saves (and now and then a factory reset) with random
//! settings, cuts the power during half of the operations that write and nine in ten of those
//! that erase (at a random program unit, or in the erase), restarts and checks, after every
//! cut:
//! - the start loads the settings of the last completed save or of the one cut short, never the
//!   defaults while a completed save is in flash (after a factory reset: the defaults, or the
//!   settings before it if it was cut short);
//! - SAVECOUNT is that save's (a factory reset keeps it);
//! - no SAVE (nor factory reset) is refused afterwards, and the store never writes flash that is
//!   not erased.
//!
//! `cargo test -p settings-store --test harsh` runs 2 000 cuts per board (seconds);
//! `STORE_CAMPAIGN_CUTS=1000000 cargo test -p settings-store --test harsh campaign --
//! --nocapture` a long one (`scripts/store-campaign.sh`), `STORE_CAMPAIGN_SEED` another seed.

mod common;

use std::fmt::Write as _;

use common::{item, record, settings, write, Layout};
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use protocol::plc::settings::Settings;
use protocol::plc::ConfigSource;
use settings_store::{Store, SAVE_INTERVAL_S};

/// SplitMix64: small, seeded, good enough for choosing cuts.
#[derive(Clone)]
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
    fn byte(&mut self) -> u8 {
        self.next() as u8
    }
    /// A probability, uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }
}

/// Why the model refused an operation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Fault {
    /// The power is off (cut).
    Off,
    /// An ECC error: the word cannot be read.
    Ecc,
    /// The store wrote a unit that was not erased (or unreadable): its fault.
    Misuse,
    /// Out of range or misaligned.
    Bounds,
}

impl NorFlashError for Fault {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            Fault::Bounds => NorFlashErrorKind::OutOfBounds,
            _ => NorFlashErrorKind::Other,
        }
    }
}

/// One flash operation, as the journal keeps it to undo it.
#[derive(Clone)]
enum Done {
    /// A program unit at an address, and what it held before.
    Unit {
        at: usize,
        old: Vec<u8>,
        new: Vec<u8>,
    },
    /// A page erased, and what it held before (with its ECC words' state).
    Erase {
        page: usize,
        old: Vec<u8>,
        bad: Vec<bool>,
    },
}

/// The harsh NOR flash: see the module's description. `ECC` 0: no ECC.
#[derive(Clone)]
struct Nor<const PAGE: usize, const WRITE: usize, const UNIT: usize, const ECC: usize> {
    data: Vec<u8>,
    /// Per ECC word: reads back as an error (until its page is erased).
    bad: Vec<bool>,
    /// The power is off: everything fails until [`Nor::power_on`].
    off: bool,
    /// The operations since [`Nor::journal`], to cut one of them afterwards.
    journal: Vec<Done>,
    /// Writes of units that were not erased (the store's fault).
    misuse: u64,
    /// Erases per page.
    erases: Vec<u64>,
}

impl<const PAGE: usize, const WRITE: usize, const UNIT: usize, const ECC: usize>
    Nor<PAGE, WRITE, UNIT, ECC>
{
    /// The bytes an entry of `bad` stands for (without ECC, a byte: never bad).
    const EW: usize = if ECC > 0 { ECC } else { 1 };

    fn new(pages: usize) -> Self {
        Nor {
            data: vec![0xFF; pages * PAGE],
            bad: vec![false; pages * PAGE / Self::EW],
            off: false,
            journal: Vec::new(),
            misuse: 0,
            erases: vec![0; pages],
        }
    }

    fn range(&self) -> std::ops::Range<u32> {
        0..self.data.len() as u32
    }

    /// Whether the ECC words over `at..at + len` read back right.
    fn readable(&self, at: usize, len: usize) -> bool {
        (at / Self::EW..(at + len).div_ceil(Self::EW)).all(|w| !self.bad[w])
    }

    fn power_on(&mut self) {
        self.off = false;
        self.journal.clear();
    }

    /// The power fails during one of the operations journaled since the last
    /// [`Nor::power_on`]: the ones after it are undone, it is torn. `erase_first`: the erase,
    /// if there was one, rather than a program unit. Whether anything was cut (the journal
    /// held an operation).
    fn cut(&mut self, rng: &mut Rng, erase_first: bool) -> Option<&'static str> {
        let journal = std::mem::take(&mut self.journal);
        let erases: Vec<usize> = (0..journal.len())
            .filter(|&i| matches!(journal[i], Done::Erase { .. }))
            .collect();
        let at = if erase_first && !erases.is_empty() {
            erases[rng.below(erases.len() as u64) as usize]
        } else if journal.is_empty() {
            return None;
        } else {
            rng.below(journal.len() as u64) as usize
        };
        // Undo what came after it, newest first.
        for done in journal[at + 1..].iter().rev() {
            self.undo(done);
        }
        let what = match &journal[at] {
            Done::Unit { at, old, new } => {
                // The bits to clear: cleared or not, at random (sometimes none: the cut came
                // just before the unit; sometimes all: just after it).
                let r = rng.below(8);
                for (i, (&o, &n)) in old.iter().zip(new).enumerate() {
                    let clear = o & !n;
                    let torn = match r {
                        0 => 0,
                        1 => clear,
                        _ => clear & rng.byte(),
                    };
                    self.data[at + i] = o & !torn;
                }
                // A unit torn anywhere but at its ends: its ECC is wrong.
                if ECC > 0 && r > 1 {
                    self.bad[at / Self::EW] = true;
                }
                "program"
            }
            Done::Erase { page, old, bad } => {
                let base = page * PAGE;
                self.data[base..base + PAGE].copy_from_slice(old);
                self.bad[base / Self::EW..(base + PAGE) / Self::EW].copy_from_slice(bad);
                match rng.below(4) {
                    // Each cleared bit set with probability p.
                    0 | 1 => {
                        let p = match rng.below(4) {
                            0 => rng.unit() * 0.01,
                            1 => 1.0 - rng.unit() * 0.01,
                            _ => rng.unit(),
                        };
                        for b in &mut self.data[base..base + PAGE] {
                            for bit in 0..8 {
                                if *b & (1 << bit) == 0 && rng.chance(p) {
                                    *b |= 1 << bit;
                                }
                            }
                        }
                    }
                    // Undefined: random bytes here and there, the rest erased or as it was.
                    _ => {
                        let (q, p) = (rng.unit() * 0.2, rng.unit());
                        for b in &mut self.data[base..base + PAGE] {
                            if rng.chance(q) {
                                *b = rng.byte();
                            } else if rng.chance(p) {
                                *b = 0xFF;
                            }
                        }
                    }
                }
                if ECC > 0 {
                    for w in 0..PAGE / Self::EW {
                        let word = base + w * Self::EW;
                        let now = &self.data[word..word + Self::EW];
                        let erased = now.iter().all(|&b| b == 0xFF);
                        let same = now == &old[w * Self::EW..(w + 1) * Self::EW];
                        // Half erased, or (some) looking as they were with their ECC bits
                        // half erased.
                        if !erased && (!same || rng.chance(0.25)) {
                            self.bad[word / Self::EW] = true;
                        }
                    }
                }
                "erase"
            }
        };
        self.off = true;
        Some(what)
    }

    fn undo(&mut self, done: &Done) {
        match done {
            Done::Unit { at, old, .. } => {
                self.data[*at..*at + old.len()].copy_from_slice(old);
                // A unit is programmed only where its ECC word read right before (and this
                // model's ECC word is one unit).
                self.bad[at / Self::EW] = false;
            }
            Done::Erase { page, old, bad } => {
                let base = page * PAGE;
                self.data[base..base + PAGE].copy_from_slice(old);
                self.bad[base / Self::EW..(base + PAGE) / Self::EW].copy_from_slice(bad);
                self.erases[*page] -= 1;
            }
        }
    }
}

/// The index of the journal's entry for the unit at `at` (the one being torn: the last one
/// at that address).
fn at_index(journal: &[Done], at: usize) -> usize {
    journal
        .iter()
        .rposition(|d| matches!(d, Done::Unit { at: a, .. } if *a == at))
        .expect("journaled")
}

impl<const PAGE: usize, const WRITE: usize, const UNIT: usize, const ECC: usize> ErrorType
    for Nor<PAGE, WRITE, UNIT, ECC>
{
    type Error = Fault;
}

impl<const PAGE: usize, const WRITE: usize, const UNIT: usize, const ECC: usize> ReadNorFlash
    for Nor<PAGE, WRITE, UNIT, ECC>
{
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Fault> {
        let at = offset as usize;
        if self.off {
            return Err(Fault::Off);
        }
        if at + bytes.len() > self.data.len() {
            return Err(Fault::Bounds);
        }
        if !self.readable(at, bytes.len()) {
            return Err(Fault::Ecc);
        }
        bytes.copy_from_slice(&self.data[at..at + bytes.len()]);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.data.len()
    }
}

impl<const PAGE: usize, const WRITE: usize, const UNIT: usize, const ECC: usize> NorFlash
    for Nor<PAGE, WRITE, UNIT, ECC>
{
    const WRITE_SIZE: usize = WRITE;
    const ERASE_SIZE: usize = PAGE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Fault> {
        let (from, to) = (from as usize, to as usize);
        if self.off {
            return Err(Fault::Off);
        }
        if !from.is_multiple_of(PAGE)
            || !to.is_multiple_of(PAGE)
            || to > self.data.len()
            || from > to
        {
            return Err(Fault::Bounds);
        }
        for page in from / PAGE..to / PAGE {
            let base = page * PAGE;
            self.journal.push(Done::Erase {
                page,
                old: self.data[base..base + PAGE].to_vec(),
                bad: self.bad[base / Self::EW..(base + PAGE) / Self::EW].to_vec(),
            });
            self.data[base..base + PAGE].fill(0xFF);
            self.bad[base / Self::EW..(base + PAGE) / Self::EW].fill(false);
            self.erases[page] += 1;
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Fault> {
        let at = offset as usize;
        if self.off {
            return Err(Fault::Off);
        }
        if !at.is_multiple_of(WRITE)
            || !bytes.len().is_multiple_of(WRITE)
            || at + bytes.len() > self.data.len()
        {
            return Err(Fault::Bounds);
        }
        for (i, unit) in bytes.chunks(UNIT).enumerate() {
            let u = at + i * UNIT;
            let old = self.data[u..u + UNIT].to_vec();
            if old.iter().any(|&b| b != 0xFF) || !self.readable(u, UNIT) {
                self.misuse += 1;
                return Err(Fault::Misuse);
            }
            self.data[u..u + UNIT].copy_from_slice(unit);
            self.journal.push(Done::Unit {
                at: u,
                old,
                new: unit.to_vec(),
            });
        }
        Ok(())
    }
}

// The boards' settings ranges: STM32F103C8 4 pages of 1 KiB, 32-bit words programmed as two
// half-words: `Nor<1024, 4, 2, 0>`; STM32L475VG 4 pages of 2 KiB, 64-bit double words with
// ECC: `Nor<2048, 8, 8, 8>`; STM32F429ZI 2 sectors of 16 KiB, 32-bit words (PSIZE 32):
// `Nor<16384, 4, 4, 0>`.

/// The L475's.
type L475 = Nor<2048, 8, 8, 8>;

/// What a campaign did and found.
#[derive(Default, Debug)]
struct Tally {
    /// Saves and factory resets attempted (cut or not).
    ops: u64,
    /// Of them, factory resets.
    factory: u64,
    /// Power cuts: during a program unit, during an erase (of a save, a factory reset or a
    /// start's counting record).
    cuts: u64,
    cut_programs: u64,
    cut_erases: u64,
    /// Starts, and those that found the settings unreadable (CFGSOURCE 2).
    starts: u64,
    damaged: u64,
    /// Starts that loaded the save cut short (it had taken).
    took: u64,
    violations: u64,
    /// The first violations, for the report.
    first: String,
}

impl Tally {
    fn violation(&mut self, what: String) {
        self.violations += 1;
        if self.violations <= 5 {
            let _ = writeln!(self.first, "  {what}");
        }
    }
}

/// Random settings (watchdog and axes: almost never the same twice in a row).
fn random_settings(rng: &mut Rng) -> Settings {
    let watchdog = 50 + rng.below(59_951) as u16;
    settings(watchdog, 1 + rng.below(16) as u8)
}

/// The range in the store's layout before page headers, as that firmware left it after `n`
/// saves (records of 0xA5 with a CRC-16, from each page's start, round the range): the newest
/// settings and their count.
fn layout_before<const PAGE: usize, const WRITE: usize, const UNIT: usize, const ECC: usize>(
    flash: &mut Nor<PAGE, WRITE, UNIT, ECC>,
    rng: &mut Rng,
    n: u32,
) -> Settings {
    let pages = flash.data.len() / PAGE;
    let mut last = settings(100, 1);
    let (mut page, mut at) = (0, 0);
    for i in 0..n {
        last = random_settings(rng);
        let r = record(Layout::Before, &item(i + 1, 0, Some(&last)), i, WRITE);
        if at + r.len() > PAGE {
            page = (page + 1) % pages;
            at = 0;
            flash
                .erase((page * PAGE) as u32, ((page + 1) * PAGE) as u32)
                .unwrap();
        }
        write(flash, page * PAGE + at, &r);
        at += r.len();
    }
    flash.journal.clear();
    last
}

/// A power-cut campaign on a flash of `pages` pages in the geometry `Nor<PAGE, ...>`: `cuts`
/// cuts from `seed` (a new flash every 5 000 cuts: erased, or every other time in the layout
/// before).
fn campaign<const PAGE: usize, const WRITE: usize, const UNIT: usize, const ECC: usize>(
    pages: usize,
    seed: u64,
    cuts: u64,
) -> Tally {
    let mut rng = Rng(seed);
    let mut tally = Tally::default();
    let mut episode = 0;
    while tally.cuts < cuts {
        let mut flash = Nor::<PAGE, WRITE, UNIT, ECC>::new(pages);
        let range = flash.range();
        // What the flash must give at the next start: the last completed save's settings
        // (None: the defaults) and count, and what a cut operation would give if it took.
        let (mut last, mut count) = (None, 0u32);
        if episode % 2 == 1 {
            let n = 1 + rng.below(40) as u32;
            last = Some(layout_before(&mut flash, &mut rng, n));
            count = n;
        }
        let mut pending: Option<(Option<Settings>, bool)> = None;
        let mut clock = 0u32;
        let end = (tally.cuts + 5_000).min(cuts);
        episode += 1;
        while tally.cuts < end {
            flash.power_on();
            let cycle = tally.cuts;
            let mut store = Store::new(flash, range.clone()).expect("a valid range");
            let loaded = store.load();
            flash = store.into_flash();
            if !flash.journal.is_empty() && rng.chance(0.5) {
                // The start wrote (its counting record): cut that.
                let erase = rng.chance(0.5);
                let what = flash.cut(&mut rng, erase).unwrap();
                tally.cuts += 1;
                count_cut(&mut tally, what);
                continue;
            }
            tally.starts += 1;
            tally.damaged += u64::from(loaded.boot.source == ConfigSource::Damaged);
            let took = pending.is_some_and(|(s, _)| loaded.settings == s);
            let factory_cut = pending.is_some_and(|(_, factory)| factory);
            if loaded.settings != last && !took {
                tally.violation(format!(
                    "cut {cycle}: loaded {:?} (source {:?}), wanted the last save {:?} or the one cut short {:?}",
                    loaded.settings.map(|s| s.gateway.watchdog),
                    loaded.boot.source,
                    last.map(|s| s.gateway.watchdog),
                    pending.map(|(s, _)| s.map(|s| s.gateway.watchdog)),
                ));
            }
            if took {
                tally.took += u64::from(loaded.settings != last);
                last = loaded.settings;
                if !factory_cut {
                    count = count.wrapping_add(1);
                }
            }
            if loaded.boot.save_count != count {
                tally.violation(format!(
                    "cut {cycle}: SAVECOUNT {} where {count} were saved",
                    loaded.boot.save_count
                ));
            }
            count = loaded.boot.save_count;
            if flash.misuse > 0 {
                tally.violation(format!("cut {cycle}: the start wrote over written flash"));
                flash.misuse = 0;
            }
            flash.journal.clear();
            // Operations until one is cut.
            let mut store = Store::new(flash, range.clone()).expect("a valid range");
            loop {
                clock += SAVE_INTERVAL_S;
                tally.ops += 1;
                let factory = rng.chance(0.03);
                let wanted = random_settings(&mut rng);
                let result = if factory {
                    tally.factory += 1;
                    store.factory_reset().map(|()| count)
                } else {
                    store.save(&wanted.encode(), clock)
                };
                let mut flash = store.into_flash();
                let outcome = (!factory).then_some(wanted);
                // Half the operations that write are cut; nine in ten of those that erase, in
                // the erase three times in four (erases are rare: every 4 saves on the F103,
                // every 70 on the F429, and the longest operations).
                let erased = flash
                    .journal
                    .iter()
                    .any(|d| matches!(d, Done::Erase { .. }));
                let p = if erased { 0.9 } else { 0.5 };
                if !flash.journal.is_empty() && rng.chance(p) {
                    let erase = rng.chance(0.75);
                    let what = flash.cut(&mut rng, erase).unwrap();
                    tally.cuts += 1;
                    count_cut(&mut tally, what);
                    pending = Some((outcome, factory));
                    store = Store::new(flash, range.clone()).expect("a valid range");
                    break;
                }
                flash.journal.clear();
                if flash.misuse > 0 {
                    tally.violation(format!("cut {cycle}: a save wrote over written flash"));
                    flash.misuse = 0;
                }
                match result {
                    Ok(n) => {
                        let same = outcome == last && !factory;
                        if n != count.wrapping_add(u32::from(!same && !factory)) {
                            tally.violation(format!(
                                "cut {cycle}: the save counted {n} after {count}"
                            ));
                        }
                        count = n;
                        last = outcome;
                    }
                    Err(e) => tally.violation(format!(
                        "cut {cycle}: {} refused: {e:?}",
                        if factory { "FACTORY" } else { "SAVE" }
                    )),
                }
                store = Store::new(flash, range.clone()).expect("a valid range");
            }
            flash = store.into_flash();
        }
    }
    tally
}

fn count_cut(tally: &mut Tally, what: &str) {
    match what {
        "erase" => tally.cut_erases += 1,
        _ => tally.cut_programs += 1,
    }
}

/// A campaign on one board's geometry: (seed, cuts).
type Campaign = fn(u64, u64) -> Tally;

/// The campaign on every board's geometry: STORE_CAMPAIGN_CUTS cuts each (default 2 000: a few
/// seconds), from STORE_CAMPAIGN_SEED (default fixed). Fails on any violation, listing the
/// first ones.
#[test]
fn campaign_of_power_cuts_on_every_board() {
    let cuts: u64 = std::env::var("STORE_CAMPAIGN_CUTS")
        .ok()
        .map(|v| v.parse().expect("STORE_CAMPAIGN_CUTS: a number"))
        .unwrap_or(2_000);
    let seed: u64 = std::env::var("STORE_CAMPAIGN_SEED")
        .ok()
        .map(|v| v.parse().expect("STORE_CAMPAIGN_SEED: a number"))
        .unwrap_or(0x35);
    let boards: [(&str, Campaign); 3] = [
        ("F103 (4 x 1 KiB, half-words)", |seed, cuts| {
            campaign::<1024, 4, 2, 0>(4, seed, cuts)
        }),
        ("L475 (4 x 2 KiB, double words, ECC)", |seed, cuts| {
            campaign::<2048, 8, 8, 8>(4, seed, cuts)
        }),
        ("F429 (2 x 16 KiB, words)", |seed, cuts| {
            campaign::<16384, 4, 4, 0>(2, seed, cuts)
        }),
    ];
    let handles: Vec<_> = boards
        .into_iter()
        .enumerate()
        .map(|(i, (name, run))| {
            std::thread::spawn(move || {
                let started = std::time::Instant::now();
                let tally = run(seed.wrapping_add(i as u64), cuts);
                (name, tally, started.elapsed())
            })
        })
        .collect();
    let mut violations = 0;
    for handle in handles {
        let (name, t, took) = handle.join().expect("a campaign");
        println!(
            "{name}: {} saves/resets ({} factory resets), {} cuts ({} in a program unit, {} in \
             an erase), {} starts ({} CFGSOURCE 2), {} starts took the save cut short, {} \
             violations ({:.1} s, seed {seed}+)",
            t.ops,
            t.factory,
            t.cuts,
            t.cut_programs,
            t.cut_erases,
            t.starts,
            t.damaged,
            t.took,
            t.violations,
            took.as_secs_f64()
        );
        print!("{}", t.first);
        violations += t.violations;
    }
    assert_eq!(violations, 0, "violations: see above");
}

/// On the L475, a double word whose programming was cut reads back as an ECC error: the store
/// passes over it (that record is garbage), not over the whole range; the records before load,
/// and saves go on after it.
#[test]
fn an_unreadable_word_is_garbage_not_a_failed_scan() {
    let mut flash = L475::new(4);
    let range = flash.range();
    let old = settings(300, 2);
    let mut s = Store::new(flash, range.clone()).unwrap();
    s.save(&settings(200, 1).encode(), 0).unwrap();
    s.save(&old.encode(), 0).unwrap();
    flash = s.into_flash();
    flash.journal.clear();
    let mut s = Store::new(flash, range.clone()).unwrap();
    s.save(&settings(400, 4).encode(), 0).unwrap();
    flash = s.into_flash();
    // That save's record: its fourth double word torn, the rest never written.
    let units: Vec<usize> = flash
        .journal
        .iter()
        .filter_map(|d| match d {
            Done::Unit { at, .. } => Some(*at),
            _ => None,
        })
        .collect();
    let torn = units[3];
    for &at in units[3..].iter().rev() {
        let i = at_index(&flash.journal, at);
        let done = flash.journal[i].clone();
        flash.undo(&done);
    }
    flash.data[torn] = 0x12;
    flash.bad[torn / 8] = true;
    flash.journal.clear();
    let mut s = Store::new(flash, range.clone()).unwrap();
    let loaded = s.load();
    assert_eq!(loaded.settings, Some(old));
    assert_eq!(loaded.boot.source, ConfigSource::Flash);
    assert_eq!((loaded.boot.save_count, loaded.boot.load_errors), (2, 0));
    let new = settings(500, 5);
    assert_eq!(s.save(&new.encode(), 0), Ok(3));
    let mut s = Store::new(s.into_flash(), range.clone()).unwrap();
    assert_eq!(s.load().settings, Some(new));
    // A whole page of unreadable words (its erase cut short) is passed over too.
    let mut flash = s.into_flash();
    let newest_page = (0..4)
        .rev()
        .find(|p| flash.data[p * 2048..p * 2048 + 8] == common::HEADER)
        .unwrap();
    let other = (newest_page + 1) % 4;
    flash.bad[other * 256..(other + 1) * 256].fill(true);
    let mut s = Store::new(flash, range).unwrap();
    assert_eq!(s.load().settings, Some(new));
    for i in 0..40u16 {
        let now = u32::from(i) * SAVE_INTERVAL_S;
        s.save(&settings(600 + i, 3).encode(), now).unwrap();
    }
    assert_eq!(s.load().settings, Some(settings(639, 3)));
    assert_eq!(s.into_flash().misuse, 0);
}

/// The F103 and the F429 geometries take a save and load it back (the campaign does the rest).
#[test]
fn every_geometry_saves_and_loads() {
    fn check<const PAGE: usize, const WRITE: usize, const UNIT: usize, const ECC: usize>(
        pages: usize,
    ) {
        let flash = Nor::<PAGE, WRITE, UNIT, ECC>::new(pages);
        let range = flash.range();
        let mut s = Store::new(flash, range.clone()).unwrap();
        for i in 0..300u16 {
            s.save(
                &settings(100 + i, 2).encode(),
                u32::from(i) * SAVE_INTERVAL_S,
            )
            .unwrap();
        }
        let flash = s.into_flash();
        assert_eq!(flash.misuse, 0);
        let mut s = Store::new(flash, range).unwrap();
        assert_eq!(s.load().settings, Some(settings(399, 2)));
    }
    check::<1024, 4, 2, 0>(4);
    check::<2048, 8, 8, 8>(4);
    check::<16384, 4, 4, 0>(2);
}
