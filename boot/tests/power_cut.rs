//! Power cuts: at every erase or write of a swap, a revert, a confirmation, a transfer and a
//! mark, under each way the cut operation can be left ([`Tear`]), then a reboot with the power
//! on. ACTIVE must always hold exactly the old or exactly the new application, and what follows
//! (confirm, rollback, a new update) must still work.

mod common;

use common::*;
use embassy_boot::State;
use rc_boot::layout::{F429, F429_SECTOR, L475};
use rc_boot::update::verify_and_mark;
use rc_boot::{BOARD_F429, BOOT_BUF_LEN};

/// Erase and write operations `f` does on a copy of `rig`.
fn count_ops<C: Chip>(rig: &Rig<C>, f: impl FnOnce(&mut Rig<C>)) -> usize {
    let mut r = rig.clone();
    r.flash.arm(usize::MAX, Tear::Nothing);
    f(&mut r);
    assert!(!r.flash.dead);
    r.flash.ops
}

/// Which application ACTIVE holds; panics on a mix.
#[derive(Debug, PartialEq, Eq, Clone, Copy)]
enum Holds {
    Old,
    New,
}

fn holds<C: Chip>(rig: &Rig<C>, old: &[u8], new: &[u8], what: &str) -> Holds {
    let r = std::panic::catch_unwind(|| holds_one_of(rig, old, new));
    match r {
        Ok(false) => Holds::Old,
        Ok(true) => Holds::New,
        Err(e) => panic!("{what}: {:?}", e.downcast_ref::<String>()),
    }
}

#[derive(Default, Debug)]
struct Counts {
    swap_ops: usize,
    revert_ops: usize,
    cut_points: usize,
    /// Swap cuts after which the reboot reverted at once (see `swap_and_revert`).
    spent_trials: usize,
}

/// Cuts during the swap and during the revert, at every operation and every tear.
/// `follow_every`: how often (in cut points) the whole follow-up (confirm, rollback, a new
/// update) is run after the recovery; the recovery itself is checked at every point.
/// `(marked, old, new)`: a board with an image marked, from [`marked_on`].
fn swap_and_revert<C: Chip>(
    (marked, old, new): (Rig<C>, Vec<u8>, Vec<u8>),
    follow_every: usize,
) -> Counts {
    let (layout, buf) = (marked.layout, marked.boot_buf);
    let mut counts = Counts {
        swap_ops: count_ops(&marked, |r| assert_eq!(r.boot(), Ok(State::Swap))),
        ..Counts::default()
    };
    // Two copies a page, each an erase, page/buf writes and a progress word.
    let pages = (layout.active.len() / layout.page) as usize;
    assert_eq!(
        counts.swap_ops,
        pages * 2 * (1 + layout.page as usize / buf + 1)
    );

    for n in 0..=counts.swap_ops {
        for tear in TEARS {
            let mut rig = marked.clone();
            rig.flash.arm(n, tear);
            let first = rig.boot();
            if n < counts.swap_ops {
                assert!(first.is_err(), "cut at {n} did not stop prepare_boot");
            } else {
                assert_eq!(first, Ok(State::Swap));
            }
            let what = format!("swap cut at {n}/{tear:?}");
            // Rebooted only after a cut: a boot that returned runs the application (the trial).
            let state = match first {
                Ok(s) => s,
                Err(_) => rig.reboot_until_ok(3),
            };
            // A cut armed past the end is disarmed.
            rig.flash.power_on();
            // The swap mark stays until the swap is done: the reboot finishes it.
            assert_eq!(state, State::Swap, "{what}");
            let h = holds(&rig, &old, &new, &what);
            counts.cut_points += 1;
            if h == Holds::Old {
                // Only one cut may end there: in the swap's last operation, the progress word
                // that says it is done, torn so that it reads as written. The reboot then
                // takes the swap as done and the trial as spent (embassy-boot cannot tell a
                // reset during the trial from one before it) and reverts.
                assert!(
                    n + 1 == counts.swap_ops && tear != Tear::Nothing,
                    "{what}: reverted"
                );
                counts.spent_trials += 1;
                assert_eq!(rig.boot(), Ok(State::Revert), "{what}");
                assert_eq!(holds(&rig, &old, &new, &what), Holds::Old, "{what}");
                update_again(&mut rig, &what);
                continue;
            }
            if counts.cut_points.is_multiple_of(follow_every) || n == counts.swap_ops {
                // Confirmed: kept.
                let mut ok = rig.clone();
                ok.app(|u| u.mark_booted().unwrap());
                assert_eq!(ok.boot(), Ok(State::Boot), "{what}");
                assert_eq!(holds(&ok, &old, &new, &what), Holds::New, "{what}");
                // Not confirmed: rolled back.
                let mut back = rig.clone();
                back.boot().unwrap();
                assert_eq!(holds(&back, &old, &new, &what), Holds::Old, "{what}");
                assert_eq!(back.boot(), Ok(State::Revert), "{what}");
            }
        }
    }

    // The trial running, unconfirmed: the next reset reverts. Cut that revert.
    let mut trial = marked.clone();
    assert_eq!(trial.boot(), Ok(State::Swap));
    counts.revert_ops = count_ops(&trial, |r| assert_eq!(r.boot(), Ok(State::Swap)));
    // The page copies, then the revert word, the state erase and the revert mark.
    assert_eq!(
        counts.revert_ops,
        pages * 2 * (1 + layout.page as usize / buf + 1) + 3
    );
    for n in 0..=counts.revert_ops {
        for tear in TEARS {
            let mut rig = trial.clone();
            rig.flash.arm(n, tear);
            let first = rig.boot();
            assert_eq!(first.is_err(), n < counts.revert_ops, "revert cut at {n}");
            let what = format!("revert cut at {n}/{tear:?}");
            let state = match first {
                Ok(s) => s,
                Err(_) => rig.reboot_until_ok(3),
            };
            // A cut armed past the end is disarmed.
            rig.flash.power_on();
            assert_eq!(holds(&rig, &old, &new, &what), Holds::Old, "{what}");
            // Swap while the revert ran on; Revert once its mark is written; Boot if the cut
            // tore the state page's first word after the revert was done.
            assert!(
                matches!(state, State::Swap | State::Revert | State::Boot),
                "{what}: {state:?}"
            );
            // Reboots after that keep the old application.
            assert!(
                matches!(rig.boot(), Ok(State::Revert | State::Boot)),
                "{what}"
            );
            assert_eq!(holds(&rig, &old, &new, &what), Holds::Old, "{what}");
            counts.cut_points += 1;
            if counts.cut_points.is_multiple_of(follow_every) || n == counts.revert_ops {
                update_again(&mut rig, &what);
            }
        }
    }
    counts
}

/// A new image transferred, marked, swapped in and confirmed: the board is not stuck.
fn update_again<C: Chip>(rig: &mut Rig<C>, what: &str) {
    let (layout, board) = (rig.layout, rig.board);
    let max = layout.max_image() as usize;
    let app = app_bytes(max / 2 + 5, 99);
    let image = signed(&app, board, &test_key());
    rig.transfer(&image).unwrap();
    let key = test_key().public_key();
    rig.app(|u| verify_and_mark(u, image.len() as u32, board, max as u32, &key))
        .unwrap_or_else(|e| panic!("{what}: mark refused: {e:?}"));
    assert_eq!(rig.boot(), Ok(State::Swap), "{what}");
    assert_eq!(&rig.active()[..app.len()], &app[..], "{what}");
    rig.app(|u| u.mark_booted().unwrap());
    assert_eq!(rig.boot(), Ok(State::Boot), "{what}");
    assert_eq!(&rig.active()[..app.len()], &app[..], "{what}");
}

#[test]
fn cut_at_every_step_of_swap_and_revert_small() {
    for buf in [512, 2048] {
        let c = swap_and_revert(marked(small_layout(), buf, 11, 12), 1);
        eprintln!("small layout, buffer {buf}: {c:?}");
        assert_eq!(c.cut_points, 3 * (c.swap_ops + 1 + c.revert_ops + 1));
    }
}

#[test]
fn cut_at_every_step_of_swap_and_revert_l475() {
    let c = swap_and_revert(marked(L475, 2048, 11, 12), 37);
    eprintln!("L475 layout, buffer 2048: {c:?}");
    assert_eq!(c.swap_ops, 1440);
    assert_eq!(c.cut_points, 3 * (c.swap_ops + 1 + c.revert_ops + 1));
}

/// The F429's layout on its chip: six 128 KiB pages in ACTIVE, STATE in a 16 KiB sector, the
/// bootloader's 2 KiB buffer (64 reads and writes a page).
#[test]
fn cut_at_every_step_of_swap_and_revert_f429() {
    let board = Rig::<F4>::on(F429, BOARD_F429, BOOT_BUF_LEN);
    let c = swap_and_revert(marked_on(board, 11, 12), F429_FOLLOW_EVERY);
    eprintln!("F429 layout, buffer {BOOT_BUF_LEN}: {c:?}");
    // 6 pages, two copies each of an erase, 64 writes and a progress word.
    assert_eq!(c.swap_ops, 6 * 2 * (1 + 64 + 1));
    assert_eq!(c.revert_ops, c.swap_ops + 3);
    assert_eq!(c.cut_points, 3 * (c.swap_ops + 1 + c.revert_ops + 1));
    // The torn last progress word (see `swap_and_revert`): the model does tear.
    assert!(c.spent_trials >= 1);
}

/// How often the F429's campaign runs the whole follow-up: a full update of its 768 KiB ACTIVE
/// costs more than a cut point, and coprime with the 3 tears so that each is followed up.
const F429_FOLLOW_EVERY: usize = 53;

#[test]
fn cut_during_confirmation() {
    cut_confirmation(marked(small_layout(), 512, 21, 22));
}

/// On the F429, the confirmation erases STATE's 16 KiB sector: cut there too.
#[test]
fn cut_during_confirmation_f429() {
    cut_confirmation(marked_on(
        Rig::<F4>::on(F429, BOARD_F429, BOOT_BUF_LEN),
        21,
        22,
    ));
}

/// Cuts during the trial's `mark_booted` on a marked board: the new application is kept or the
/// old one put back, whole, and a new update goes through.
fn cut_confirmation<C: Chip>((mut trial, old, new): (Rig<C>, Vec<u8>, Vec<u8>)) {
    assert_eq!(trial.boot(), Ok(State::Swap));
    let ops = count_ops(&trial, |r| r.app(|u| u.mark_booted().unwrap()));
    assert_eq!(ops, 3);
    let mut seen = [0; 2];
    for n in 0..=ops {
        for tear in TEARS {
            let what = format!("mark_booted cut at {n}/{tear:?}");
            let mut rig = trial.clone();
            rig.flash.arm(n, tear);
            let r = rig.app(|u| u.mark_booted());
            assert_eq!(r.is_err(), n < ops, "{what}");
            rig.reboot_until_ok(3);
            // Confirmed (kept) or not (rolled back), never a mix; either way it then stays.
            let h = holds(&rig, &old, &new, &what);
            seen[h as usize] += 1;
            assert!(
                matches!(rig.boot(), Ok(State::Boot | State::Revert)),
                "{what}"
            );
            assert_eq!(holds(&rig, &old, &new, &what), h, "{what}");
            update_again(&mut rig, &what);
        }
    }
    eprintln!("confirmation: {ops} operations, old/new after the cut: {seen:?}");
    // The uncut confirmation keeps the new application.
    assert!(seen[Holds::New as usize] >= 3);
}

#[test]
fn cut_during_transfer_and_mark_keeps_the_old_application() {
    let layout = small_layout();
    let max = layout.max_image() as usize;
    let (transfer_ops, mark_ops, points) =
        transfer_and_mark_cuts(Rig::new(layout, 512), max - 96 - 40, 1);
    assert_eq!(points, 3 * (transfer_ops + mark_ops));
}

/// On the F429: an image one sector and a bit long, so that the transfer erases two of DFU's
/// 128 KiB sectors (a chunk straddles the boundary), and the mark erases STATE's 16 KiB one.
#[test]
fn cut_during_transfer_and_mark_keeps_the_old_application_f429() {
    let board = Rig::<F4>::on(F429, BOARD_F429, BOOT_BUF_LEN);
    let (transfer_ops, mark_ops, points) =
        transfer_and_mark_cuts(board, F429_SECTOR as usize + 3000, F429_FOLLOW_EVERY);
    // Two erases, the 232-byte chunks (the one across the sector boundary in two writes).
    assert_eq!(
        transfer_ops,
        2 + (F429_SECTOR as usize + 3000 + 96).div_ceil(232) + 1
    );
    assert_eq!(points, 3 * (transfer_ops + mark_ops));
}

/// Cuts at every operation of a transfer of an image of `app_len` bytes into a fresh `board`'s
/// DFU, and of its mark, with every tear: the reboot runs the old application, and (every
/// `follow_every` cut points in the transfer, at each in the mark) the image sent again from the
/// start goes through. Returns the transfer's operations, the mark's and the cut points.
fn transfer_and_mark_cuts<C: Chip>(
    mut board: Rig<C>,
    app_len: usize,
    follow_every: usize,
) -> (usize, usize, usize) {
    let (layout, id) = (board.layout, board.board);
    board.flash_active(&app_bytes(layout.max_image() as usize - 100, 31));
    let old = board.active();
    let max = layout.max_image() as usize;
    let image = signed(&app_bytes(app_len, 32), id, &test_key());
    let key = test_key().public_key();
    let mark =
        |r: &mut Rig<C>| r.app(|u| verify_and_mark(u, image.len() as u32, id, max as u32, &key));

    let transfer_ops = count_ops(&board, |r| r.transfer(&image).unwrap());
    let mut transferred = board.clone();
    transferred.transfer(&image).unwrap();
    let mark_ops = count_ops(&transferred, |r| {
        mark(r).unwrap();
    });
    assert_eq!(mark_ops, 3);
    let mut points = 0;
    for (phase, start, ops) in [
        ("transfer", &board, transfer_ops),
        ("mark", &transferred, mark_ops),
    ] {
        for n in 0..ops {
            for tear in TEARS {
                let what = format!("{phase} cut at {n}/{tear:?}");
                let mut rig = start.clone();
                rig.flash.arm(n, tear);
                let cut = if phase == "transfer" {
                    rig.transfer(&image).is_err()
                } else {
                    mark(&mut rig).is_err()
                };
                assert!(cut, "{what}");
                assert_eq!(rig.reboot_until_ok(3), State::Boot, "{what}");
                assert_eq!(rig.active(), old, "{what}");
                rig.check_outside();
                points += 1;
                if points % follow_every != 0 && phase == "transfer" {
                    continue;
                }
                // Sent again from the start, the image goes through.
                rig.transfer(&image).unwrap();
                mark(&mut rig).unwrap_or_else(|e| panic!("{what}: {e:?}"));
                assert_eq!(rig.boot(), Ok(State::Swap), "{what}");
                assert_eq!(&rig.active()[..image.len()], &image[..], "{what}");
            }
        }
    }
    eprintln!("transfer: {transfer_ops} operations, mark: {mark_ops}; {points} cut points checked");
    (transfer_ops, mark_ops, points)
}
