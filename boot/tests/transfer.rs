//! The application's side: an image transferred into DFU, checked and marked through
//! embassy-boot's `verify_and_mark_updated` (via `rc_boot::update::verify_and_mark`); on the
//! L475's layouts, and on the F429's for its board id and largest image.

mod common;

use common::*;
use embassy_boot::{FirmwareUpdaterError, State};
use rc_boot::image::{split, ImageError, Trailer, TRAILER_LEN};
use rc_boot::layout::{Layout, F429, L475};
use rc_boot::update::{verify_and_mark, UpdateError, Verifier, VerifyError};
use rc_boot::{BOARD_F429, BOARD_L475, BOOT_BUF_LEN};

/// A board running `old`, with `image` transferred into DFU.
fn board(layout: Layout, old: &[u8], image: &[u8]) -> Rig {
    let mut rig = Rig::new(layout, 2048);
    rig.flash_active(old);
    rig.transfer(image).unwrap();
    rig
}

fn mark(rig: &mut Rig, image_len: usize, key: &[u8; 32]) -> Result<Trailer, UpdateError> {
    let max = rig.layout.max_image();
    rig.app(|u| verify_and_mark(u, image_len as u32, BOARD_L475, max, key))
}

/// `mark` refused, with the mark and ACTIVE as they were.
fn refused(rig: &mut Rig, image_len: usize, key: &[u8; 32]) -> UpdateError {
    let (active, state) = (rig.active(), rig.state_bytes());
    let e = mark(rig, image_len, key).unwrap_err();
    assert_eq!(rig.state_bytes(), state, "the mark changed on a refusal");
    assert_eq!(rig.active(), active);
    assert_eq!(rig.app(|u| u.get_state().unwrap()), State::Boot);
    // And the bootloader boots the old application, untouched.
    assert_eq!(rig.boot(), Ok(State::Boot));
    assert_eq!(rig.active(), active);
    e
}

#[test]
fn good_image_is_marked_for_the_swap() {
    for layout in [small_layout(), L475] {
        let app = app_bytes(layout.max_image() as usize - TRAILER_LEN - 5, 1);
        let image = signed(&app, BOARD_L475, &test_key());
        let mut rig = board(layout, &app_bytes(1000, 2), &image);
        let t = mark(&mut rig, image.len(), &test_key().public_key()).unwrap();
        assert_eq!(t.app_len as usize, app.len());
        assert_eq!(rig.app(|u| u.get_state().unwrap()), State::Swap);
        // The host's own view of the file agrees.
        let (a, t2) = split(&image, BOARD_L475, layout.max_image()).unwrap();
        assert_eq!((a, t2), (&app[..], t));
    }
}

fn sig_refused(e: UpdateError) {
    assert!(
        matches!(e, UpdateError::Updater(FirmwareUpdaterError::Signature(_))),
        "{e:?}"
    );
}

#[test]
fn wrong_key_is_refused() {
    let image = signed(&app_bytes(5000, 1), BOARD_L475, &other_key());
    let mut rig = board(small_layout(), &app_bytes(1000, 2), &image);
    sig_refused(refused(&mut rig, image.len(), &test_key().public_key()));
    // The right key for that image does verify: the refusal was the key's.
    mark(&mut rig, image.len(), &other_key().public_key()).unwrap();
}

#[test]
fn any_flipped_bit_in_the_signed_part_is_refused() {
    let app = app_bytes(3001, 1);
    let image = signed(&app, BOARD_L475, &test_key());
    let t = Trailer::parse(&image[image.len() - TRAILER_LEN..]).unwrap();
    let signed_len = t.signed_len().unwrap() as usize;
    // Bits in the application, in its padding, and in the header (magic and CRC-32 aside,
    // which the trailer's checks catch first).
    let mut checked = 0;
    for at in (0..signed_len)
        .step_by(97)
        .chain([0, app.len() - 1, app.len(), signed_len - 1])
    {
        for bit in [0, 7] {
            let mut bad = image.clone();
            bad[at] ^= 1 << bit;
            let mut rig = board(small_layout(), &app_bytes(1000, 2), &bad);
            let e = refused(&mut rig, bad.len(), &test_key().public_key());
            match e {
                UpdateError::Updater(FirmwareUpdaterError::Signature(_)) => {}
                // The header's fields are under the trailer's CRC-32 too.
                UpdateError::Image(ImageError::BadCrc | ImageError::BadMagic) => {
                    assert!(at >= signed_len - 24)
                }
                e => panic!("byte {at}: {e:?}"),
            }
            checked += 1;
        }
    }
    assert!(checked > 60);
}

#[test]
fn a_relabelled_board_fails_the_signature() {
    // Signed for another board, the header rewritten to the L475's with a good CRC-32: the
    // header is signed, so the signature no longer verifies.
    let app = app_bytes(4000, 1);
    let image = signed(&app, 0x0103, &test_key());
    let at = image.len() - TRAILER_LEN;
    let mut t = Trailer::parse(&image[at..]).unwrap();
    t.board = BOARD_L475;
    let mut bad = image[..at].to_vec();
    bad.extend_from_slice(&t.encode());
    let mut rig = board(small_layout(), &app_bytes(1000, 2), &bad);
    sig_refused(refused(&mut rig, bad.len(), &test_key().public_key()));
}

#[test]
fn wrong_board_is_refused() {
    let image = signed(&app_bytes(4000, 1), 0x0103, &test_key());
    let mut rig = board(small_layout(), &app_bytes(1000, 2), &image);
    let e = refused(&mut rig, image.len(), &test_key().public_key());
    assert!(
        matches!(
            e,
            UpdateError::Image(ImageError::WrongBoard { found: 0x0103 })
        ),
        "{e:?}"
    );
}

#[test]
fn truncated_image_is_refused() {
    let image = signed(&app_bytes(4000, 1), BOARD_L475, &test_key());
    for keep in [image.len() - 8, image.len() - 96, image.len() / 2, 96, 8, 0] {
        let mut rig = board(small_layout(), &app_bytes(1000, 2), &image[..keep]);
        let e = refused(&mut rig, keep, &test_key().public_key());
        assert!(
            matches!(
                e,
                UpdateError::Image(
                    ImageError::Truncated | ImageError::BadMagic | ImageError::BadCrc
                )
            ),
            "{keep}: {e:?}"
        );
    }
    // The whole image, but a length that cuts it short or runs past it.
    let mut rig = board(small_layout(), &app_bytes(1000, 2), &image);
    for len in [image.len() - 8, image.len() + 8] {
        let e = refused(&mut rig, len, &test_key().public_key());
        assert!(matches!(e, UpdateError::Image(_)), "{len}: {e:?}");
    }
}

#[test]
fn image_larger_than_active_is_refused() {
    let layout = small_layout();
    let app = app_bytes(layout.max_image() as usize, 1);
    let image = signed(&app, BOARD_L475, &test_key());
    // It fits DFU (one page larger than ACTIVE) but not ACTIVE.
    assert!(image.len() <= layout.dfu.len() as usize);
    let mut rig = board(layout, &app_bytes(1000, 2), &image);
    let e = refused(&mut rig, image.len(), &test_key().public_key());
    assert!(
        matches!(e, UpdateError::Image(ImageError::TooLarge)),
        "{e:?}"
    );
}

#[test]
fn no_new_mark_during_a_trial_boot() {
    let old = app_bytes(3000, 2);
    let image = signed(&app_bytes(4000, 1), BOARD_L475, &test_key());
    let mut rig = board(small_layout(), &old, &image);
    mark(&mut rig, image.len(), &test_key().public_key()).unwrap();
    assert_eq!(rig.boot(), Ok(State::Swap));
    // Not confirmed yet: embassy-boot refuses both a new transfer and a new mark.
    let e = mark(&mut rig, image.len(), &test_key().public_key()).unwrap_err();
    assert!(
        matches!(e, UpdateError::Updater(FirmwareUpdaterError::BadState)),
        "{e:?}"
    );
    assert!(matches!(
        rig.transfer(&image),
        Err(FirmwareUpdaterError::BadState)
    ));
}

/// The stepwise verifier reads the image back from DFU a page at a time.
fn step_verify(rig: &mut Rig, image_len: usize, key: &[u8; 32]) -> Result<(), VerifyError> {
    let raw = rig.dfu()[image_len - TRAILER_LEN..image_len].to_vec();
    let t = Trailer::parse(&raw).unwrap();
    let mut v = Verifier::new(&t).unwrap();
    let mut at = 0;
    while v.remaining() > 0 {
        let mut page = vec![0; 2048];
        rig.app(|u| u.read_dfu(at as u32, &mut page)).unwrap();
        v.update(&page);
        at += page.len();
    }
    v.finish(key)
}

#[test]
fn stepwise_verifier_agrees_with_embassy_boot() {
    let app = app_bytes(9000, 1);
    let good = signed(&app, BOARD_L475, &test_key());
    let foreign = signed(&app, BOARD_L475, &other_key());
    let mut flipped = good.clone();
    flipped[4321] ^= 0x20;
    let mut cases = 0;
    for (image, key, ok) in [
        (&good, test_key(), true),
        (&good, other_key(), false),
        (&foreign, test_key(), false),
        (&flipped, test_key(), false),
    ] {
        let pk = key.public_key();
        let mut rig = board(small_layout(), &app_bytes(1000, 2), image);
        let stepwise = step_verify(&mut rig, image.len(), &pk);
        assert_eq!(stepwise.is_ok(), ok);
        if !ok {
            assert_eq!(stepwise, Err(VerifyError::BadSignature));
        }
        let embassy = mark(&mut rig, image.len(), &pk);
        assert_eq!(embassy.is_ok(), ok, "{embassy:?}");
        cases += 1;
    }
    assert_eq!(cases, 4);
    // Fed short, it refuses.
    let t = Trailer::parse(&good[good.len() - TRAILER_LEN..]).unwrap();
    let mut v = Verifier::new(&t).unwrap();
    v.update(&good[..100]);
    assert_eq!(
        v.finish(&test_key().public_key()),
        Err(VerifyError::Incomplete)
    );
}

#[test]
fn stepwise_verified_image_marked_directly_swaps_in() {
    let app = app_bytes(7000, 3);
    let image = signed(&app, BOARD_L475, &test_key());
    let mut rig = board(small_layout(), &app_bytes(1000, 2), &image);
    step_verify(&mut rig, image.len(), &test_key().public_key()).unwrap();
    rig.mark_updated_unchecked();
    assert_eq!(rig.boot(), Ok(State::Swap));
    assert_eq!(&rig.active()[..app.len()], &app[..]);
}

/// The F429's board (its sectors, its id), running `old`, with `image` transferred into DFU.
fn f429_board(old: &[u8], image: &[u8]) -> Rig<F4> {
    let mut rig = Rig::on(F429, BOARD_F429, BOOT_BUF_LEN);
    rig.flash_active(old);
    rig.transfer(image).unwrap();
    rig
}

fn f429_mark(rig: &mut Rig<F4>, image_len: usize) -> Result<Trailer, UpdateError> {
    let key = test_key().public_key();
    rig.app(|u| verify_and_mark(u, image_len as u32, BOARD_F429, F429.max_image(), &key))
}

#[test]
fn f429_largest_image_is_marked_for_the_swap() {
    // The largest the F429 takes: 768 KiB, so DFU's six first sectors (the transfer erases
    // each as it reaches it) hold it.
    let max = F429.max_image() as usize;
    assert_eq!(max, 6 * 128 * 1024);
    let app = app_bytes(max - TRAILER_LEN - 5, 1);
    let image = signed(&app, BOARD_F429, &test_key());
    assert!(image.len() <= max && image.len() > max - 8 - TRAILER_LEN);
    let mut rig = f429_board(&app_bytes(1000, 2), &image);
    let t = f429_mark(&mut rig, image.len()).unwrap();
    assert_eq!(t.app_len as usize, app.len());
    assert_eq!(rig.app(|u| u.get_state().unwrap()), State::Swap);
    assert_eq!(rig.boot(), Ok(State::Swap));
    assert_eq!(&rig.active()[..image.len()], &image[..]);
    rig.check_outside();
}

#[test]
fn f429_refuses_another_boards_image_and_one_past_active() {
    let key = test_key().public_key();
    // The L475's image on the F429, and the F429's on the L475.
    let image = signed(&app_bytes(4000, 1), BOARD_L475, &test_key());
    let mut rig = f429_board(&app_bytes(1000, 2), &image);
    let e = f429_mark(&mut rig, image.len()).unwrap_err();
    assert!(
        matches!(
            e,
            UpdateError::Image(ImageError::WrongBoard { found: BOARD_L475 })
        ),
        "{e:?}"
    );
    let image = signed(&app_bytes(4000, 1), BOARD_F429, &test_key());
    let mut l475 = board(small_layout(), &app_bytes(1000, 2), &image);
    let e = refused(&mut l475, image.len(), &key);
    assert!(
        matches!(
            e,
            UpdateError::Image(ImageError::WrongBoard { found: BOARD_F429 })
        ),
        "{e:?}"
    );
    // One word past ACTIVE: it fits DFU (a sector larger), not ACTIVE.
    let app = app_bytes(F429.max_image() as usize - TRAILER_LEN + 8, 3);
    let image = signed(&app, BOARD_F429, &test_key());
    assert!(image.len() > F429.max_image() as usize && image.len() <= F429.dfu.len() as usize);
    let mut rig = f429_board(&app_bytes(1000, 2), &image);
    let e = f429_mark(&mut rig, image.len()).unwrap_err();
    assert!(
        matches!(e, UpdateError::Image(ImageError::TooLarge)),
        "{e:?}"
    );
    assert_eq!(rig.boot(), Ok(State::Boot));
    assert_eq!(&rig.active()[..1000], &app_bytes(1000, 2)[..]);
}
