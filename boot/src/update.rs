//! The application's side: check the image in DFU and mark it for the bootloader.
//!
//! The transfer (`protocol::plc::update`, `src/dfu.rs`) writes the image file into DFU from
//! offset 0. At FINISH the application calls [`verify_and_mark`]: it reads the trailer at the
//! file's end, checks it ([`Trailer::parse`], [`Trailer::check`]), then hands the signature and
//! [`Trailer::signed_len`] to embassy-boot's `verify_and_mark_updated`, which hashes DFU's first
//! `signed_len` bytes with SHA-512, verifies the Ed25519 signature over the digest and only
//! then writes the swap mark. Nothing else may mark an image: with a verifying feature on,
//! embassy-boot's updater has no unchecked `mark_updated`.
//!
//! After the next reset the bootloader swaps the image in (a trial boot). The new application
//! confirms itself with embassy-boot's `mark_booted` once it runs well; a reset before that
//! makes the bootloader put the old application back.

use embassy_boot::{BlockingFirmwareUpdater, FirmwareUpdaterError, State};
use embedded_storage::nor_flash::NorFlash;

use crate::image::{trailer_offset, ImageError, Trailer, TRAILER_LEN};

/// Why an image was not marked.
#[derive(Debug)]
pub enum UpdateError {
    /// The trailer or the image's length is refused (the mark is untouched).
    Image(ImageError),
    /// embassy-boot refused: a flash error, a bad signature, or a state in which no image may
    /// be marked (a trial boot not yet confirmed).
    Updater(FirmwareUpdaterError),
}

impl From<ImageError> for UpdateError {
    fn from(e: ImageError) -> Self {
        UpdateError::Image(e)
    }
}

impl From<FirmwareUpdaterError> for UpdateError {
    fn from(e: FirmwareUpdaterError) -> Self {
        UpdateError::Updater(e)
    }
}

/// Checks the image of `image_len` bytes in DFU for `board` and, if its signature verifies with
/// `public_key`, marks it for the bootloader's swap. `max_image` is ACTIVE's size
/// ([`Layout::max_image`](crate::layout::Layout::max_image)), which is also below DFU's, so
/// embassy-boot's own length assertion cannot fire.
///
/// Refuses with `BadState` during a trial boot (the swap mark still set: the new application
/// has not confirmed itself with `mark_booted`), before reading DFU.
pub fn verify_and_mark<DFU: NorFlash, STATE: NorFlash>(
    updater: &mut BlockingFirmwareUpdater<'_, DFU, STATE>,
    image_len: u32,
    board: u16,
    max_image: u32,
    public_key: &[u8; 32],
) -> Result<Trailer, UpdateError> {
    // During a trial boot DFU holds the previous application, not an image: say so first.
    if updater.get_state()? == State::Swap {
        return Err(FirmwareUpdaterError::BadState.into());
    }
    if image_len > max_image {
        return Err(ImageError::TooLarge.into());
    }
    let mut raw = [0; TRAILER_LEN];
    updater.read_dfu(trailer_offset(image_len)?, &mut raw)?;
    let trailer = Trailer::parse(&raw)?;
    trailer.check(board, image_len, max_image)?;
    let signed = trailer.signed_len().ok_or(ImageError::TooLarge)?;
    updater.verify_and_mark_updated(public_key, &trailer.signature, signed)?;
    Ok(trailer)
}
