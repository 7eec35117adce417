//! The RAM flash itself: it must refuse what the L475 refuses and really lose power, or the
//! other tests prove nothing.

mod common;

use common::*;
use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};

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
