//! The bootloader's side without power cuts: embassy-boot's `prepare_boot` swaps a marked image
//! in for a trial, keeps it once confirmed, and puts the old application back otherwise; on the
//! L475's layout (and a scaled-down one) and on the F429's.

mod common;

use common::*;
use embassy_boot::State;
use rc_boot::layout::{LayoutError, F429, F429_SECTOR, F429_SMALL_SECTOR, L475};
use rc_boot::update::verify_and_mark;
use rc_boot::{BOARD_F429, BOOT_BUF_LEN};

/// A marked board (from [`marked_on`]): the swap, then the confirmation, which keeps it.
fn swap_then_confirm<C: Chip>((mut rig, old, new): (Rig<C>, Vec<u8>, Vec<u8>)) {
    let layout = rig.layout;
    assert_eq!(rig.boot(), Ok(State::Swap));
    assert_eq!(rig.active(), new);
    // The old application is kept in DFU, one page up.
    let page = layout.page as usize;
    assert_eq!(&rig.dfu()[page..page + old.len()], &old[..]);
    assert_eq!(rig.app(|u| u.get_state().unwrap()), State::Swap);
    // The new application confirms itself.
    rig.app(|u| u.mark_booted().unwrap());
    for _ in 0..3 {
        assert_eq!(rig.boot(), Ok(State::Boot));
        assert_eq!(rig.active(), new);
    }
    rig.check_outside();
}

/// A marked board: the swap, a reset before the confirmation, the revert; then a new update.
fn unconfirmed_rolls_back<C: Chip>((mut rig, old, new): (Rig<C>, Vec<u8>, Vec<u8>)) {
    let layout = rig.layout;
    let board = rig.board;
    assert_eq!(rig.boot(), Ok(State::Swap));
    assert_eq!(rig.active(), new);
    // A reset before mark_booted: the bootloader reverts. `prepare_boot` returns the state
    // it read, still Swap: only ACTIVE tells a revert from a swap.
    assert_eq!(rig.boot(), Ok(State::Swap));
    assert_eq!(rig.active(), old);
    // And stays reverted, now with the revert mark.
    assert_eq!(rig.boot(), Ok(State::Revert));
    assert_eq!(rig.active(), old);
    // The old application may take a new image afterwards.
    let max = layout.max_image() as usize;
    let image = signed(&app_bytes(max / 3, 5), board, &test_key());
    rig.transfer(&image).unwrap();
    let key = test_key().public_key();
    rig.app(|u| verify_and_mark(u, image.len() as u32, board, max as u32, &key))
        .unwrap();
    let newer = rig.dfu()[..layout.active.len() as usize].to_vec();
    assert_eq!(rig.boot(), Ok(State::Swap));
    assert_eq!(rig.active(), newer);
    assert_eq!(&rig.active()[..max / 3], &app_bytes(max / 3, 5)[..]);
    rig.check_outside();
}

#[test]
fn swap_then_confirm_keeps_the_new_application() {
    for (layout, buf) in [(small_layout(), 512), (L475, 2048)] {
        swap_then_confirm(marked(layout, buf, 1, 2));
    }
}

#[test]
fn unconfirmed_trial_is_rolled_back() {
    for (layout, buf) in [(small_layout(), 512), (L475, 2048)] {
        unconfirmed_rolls_back(marked(layout, buf, 3, 4));
    }
}

/// The F429 board: its layout on its chip's sectors, the bootloader's buffer.
fn f429() -> Rig<F4> {
    Rig::on(F429, BOARD_F429, BOOT_BUF_LEN)
}

#[test]
fn f429_swap_then_confirm_keeps_the_new_application() {
    swap_then_confirm(marked_on(f429(), 1, 2));
}

#[test]
fn f429_unconfirmed_trial_is_rolled_back() {
    unconfirmed_rolls_back(marked_on(f429(), 3, 4));
}

/// The F429's layout with DFU one sector short (sectors 18-23), past the layout's own check:
/// embassy-boot's bootloader refuses it (`assert_partitions`: DFU must be ACTIVE and a page).
#[test]
#[should_panic(expected = "dfu.capacity() as u32 - active.capacity() as u32 >= page_size")]
fn f429_dfu_one_sector_short_is_refused_by_embassy_boot() {
    let mut layout = F429;
    layout.dfu.start += F429_SECTOR;
    assert_eq!(layout.check(), Err(LayoutError::DfuTooSmall));
    let mut rig = Rig::<F4>::unchecked(layout, BOARD_F429, BOOT_BUF_LEN);
    rig.flash_active(&app_bytes(1000, 1));
    let _ = rig.boot();
}

/// STATE moved to sector 16, past the check against the chip's sectors: 16 KiB-aligned, so the
/// layout's own check passes, but the sector is 64 KiB. The first mark erases STATE's 16 KiB,
/// which the chip refuses: no image can ever be marked.
#[test]
fn f429_state_on_a_64_kib_sector_cannot_be_marked() {
    let mut layout = F429;
    layout.state.start = layout.bank2 + 4 * F429_SMALL_SECTOR;
    layout.state.end = layout.state.start + F429_SMALL_SECTOR;
    assert_eq!(layout.check(), Ok(()));
    let rig = Rig::<F4>::unchecked(layout, BOARD_F429, BOOT_BUF_LEN);
    assert!(on_sectors(&layout, &rig.flash).is_err());
    let Err(e) = std::panic::catch_unwind(|| marked_on(rig, 1, 2)) else {
        panic!("marked on a STATE the chip cannot erase");
    };
    let e = e.downcast_ref::<String>().unwrap();
    assert!(e.contains("Flash(NotAligned)"), "{e}");
}

#[test]
fn nothing_marked_boots_as_is() {
    let mut rig = Rig::new(small_layout(), 512);
    rig.flash_active(&app_bytes(5000, 1));
    let before = rig.flash.mem.clone();
    assert_eq!(rig.boot(), Ok(State::Boot));
    assert_eq!(rig.flash.mem, before);
}
