//! The RAM flash itself: it must refuse what the L475 (and the F429) refuses and really lose power, or the
//! other tests prove nothing.

mod common;

use common::*;
use rc_boot::layout::{F429, F429_SECTOR, F429_SMALL_SECTOR, F429_WORD};

#[test]
#[should_panic(expected = "write onto a programmed word")]
fn refuses_a_write_onto_a_programmed_word() {
    let mut f = SimFlash::new(4096);
    f.write(8, &[1; 8]).unwrap();
    let _ = f.write(8, &[1; 8]);
}

#[test]
fn zeros_go_over_anything_and_bits_only_fall() {
    let mut f = SimFlash::new(4096);
    f.write(0, &[0x5A; 8]).unwrap();
    f.write(0, &[0; 8]).unwrap();
    let mut b = [0xEE; 8];
    f.read(0, &mut b).unwrap();
    assert_eq!(b, [0; 8]);
    f.erase(0, 2048).unwrap();
    f.read(0, &mut b).unwrap();
    assert_eq!(b, [0xFF; 8]);
    assert!(f.write(4, &[0; 8]).is_err());
    assert!(f.erase(0, 1024).is_err());
    assert!(f.write(4096, &[0; 8]).is_err());
}

#[test]
fn a_cut_stops_everything_and_tears_as_told() {
    for tear in TEARS {
        let mut f = SimFlash::new(8192);
        f.arm(2, tear);
        f.write(0, &[0x11; 16]).unwrap();
        f.erase(2048, 4096).unwrap();
        let before = f.mem.clone();
        assert!(f.write(16, &[0; 64]).is_err());
        let changed = f.mem[16..80] != before[16..80];
        assert_eq!(changed, tear != Tear::Nothing, "{tear:?}");
        // Nothing else was touched, and nothing goes through afterwards.
        assert_eq!(f.mem[..16], before[..16]);
        assert_eq!(f.mem[80..], before[80..]);
        assert!(f.erase(0, 2048).is_err());
        assert!(f.read(0, &mut [0; 8]).is_err());
        f.power_on();
        f.erase(0, 2048).unwrap();
    }
}

#[test]
#[should_panic(expected = "a mix")]
fn a_mixed_active_is_caught() {
    // The check the power-cut tests rely on: half the old application, half the new.
    let layout = small_layout();
    let mut rig = Rig::new(layout, 512);
    let n = layout.active.len() as usize;
    let (old, new) = (app_bytes(n, 1), app_bytes(n, 2));
    let mut mix = old.clone();
    mix[n / 2..].copy_from_slice(&new[n / 2..]);
    rig.flash_active(&mix);
    holds_one_of(&rig, &old, &new);
}

/// The F429's sectors, as RM0090 gives them: an erase must start and end on them, a write be
/// whole 4-byte words; the F429's layout sits on them (ACTIVE and DFU on 128 KiB sectors, STATE
/// and the settings on 16 KiB ones).
#[test]
fn f429_sectors_refuse_what_the_chip_refuses() {
    let mut f = SimFlash::with_sectors(&F4::sectors(&F429), F429_WORD);
    assert_eq!(f.mem.len(), 2 << 20);
    let off = |a: u32| a - F429.flash.start;
    let (k16, k64, k128) = (16 << 10, 64 << 10, 128 << 10);
    // Bank 2: sectors 12-15 of 16 KiB, 16 of 64 KiB, 17-23 of 128 KiB.
    let b2 = off(F429.bank2);
    assert_eq!(f.sector_at(b2 + 3 * k16 + 5).map(|r| r.len()), Some(k16));
    assert_eq!(f.sector_at(b2 + 4 * k16).map(|r| r.len()), Some(k64));
    assert_eq!(f.sector_at(b2 + 4 * k16 + k64).map(|r| r.len()), Some(k128));
    assert_eq!(on_sectors(&F429, &f), Ok(()));
    let (active, state) = (off(F429.active.start), off(F429.state.start));
    // A 16 KiB erase inside a 128 KiB sector, or half of one, is refused, the flash untouched.
    f.write(active + k16, &[0; 4]).unwrap();
    for (from, to) in [
        (active, active + k16),
        (active + k16, active + 2 * k16),
        (active, active + k64),
        (state, state + k16 / 2),
        (b2 + 4 * k16, b2 + 4 * k16 + k16),
    ] {
        assert_eq!(
            f.erase(from, to),
            Err(SimError::NotAligned),
            "{from:#x}..{to:#x}"
        );
    }
    assert_eq!(f.mem[(active + k16) as usize], 0);
    // Whole sectors go, across sizes too.
    f.erase(state, state + k16).unwrap();
    f.erase(b2 + 3 * k16, b2 + 4 * k16 + k64 + k128).unwrap();
    f.erase(active, active + k128).unwrap();
    assert_eq!(f.mem[(active + k16) as usize], 0xFF);
    // Words of 4 bytes.
    f.write(active + 4, &[0x12; 4]).unwrap();
    assert_eq!(f.write(active + 2, &[0; 4]), Err(SimError::NotAligned));
    assert_eq!(f.write(active + 8, &[0; 6]), Err(SimError::NotAligned));
}

/// A layout off the chip's sectors is caught though its own check passes: STATE in sector 16
/// (64 KiB) is 16 KiB-aligned, but erasing it erases 64 KiB.
#[test]
fn a_layout_off_the_f429_sectors_is_caught() {
    let f = SimFlash::with_sectors(&F4::sectors(&F429), F429_WORD);
    let mut l = F429;
    l.state.start = l.bank2 + 4 * F429_SMALL_SECTOR;
    l.state.end = l.state.start + F429_SMALL_SECTOR;
    assert_eq!(l.check(), Ok(()));
    let e = on_sectors(&l, &f).unwrap_err();
    assert!(e.starts_with("STATE"), "{e}");
}

#[test]
fn f429_torn_erase_of_a_big_sector_erases_half_of_it() {
    let mut f = SimFlash::with_sectors(&F4::sectors(&F429), F429_WORD);
    f.mem.fill(0);
    let active = F429.active.start - F429.flash.start;
    f.arm(0, Tear::Half);
    assert_eq!(
        f.erase(active, active + F429_SECTOR),
        Err(SimError::PowerCut)
    );
    let s = active as usize;
    let half = F429_SECTOR as usize / 2;
    assert!(f.mem[s..s + half].iter().all(|&b| b == 0xFF));
    assert!(f.mem[s + half..s + 2 * half].iter().all(|&b| b == 0));
}

/// The check every cut point makes besides ACTIVE's: the settings (next to STATE on the F429)
/// and the bootloader keep their bytes.
#[test]
#[should_panic(expected = "the flash changed outside the partitions at 0x8107ffc")]
fn a_change_outside_the_partitions_is_caught() {
    let mut rig = Rig::<F4>::on(F429, rc_boot::BOARD_F429, rc_boot::BOOT_BUF_LEN);
    rig.check_outside();
    let at = (F429.settings.end - 4 - F429.flash.start) as usize;
    rig.flash.mem[at] ^= 1;
    rig.check_outside();
}
