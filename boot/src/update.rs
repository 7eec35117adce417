//! The application's side: check the image in DFU and mark it for the bootloader.
//!
//! The transfer (`protocol::plc::update`, `src/dfu/`) writes the image file into DFU from
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

use embassy_boot::BlockingFirmwareUpdater;
/// embassy-boot's state partition and its states, for the application's marks (`mark_updated`
/// after a [`Verifier`], `mark_booted` to confirm a trial): re-exported so that the application
/// uses the same embassy-boot as this crate.
pub use embassy_boot::{BlockingFirmwareState, FirmwareUpdaterError, State};
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

/// Why [`Verifier::finish`] refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VerifyError {
    /// Fewer bytes were fed than the signature covers.
    Incomplete,
    /// The public key is not a valid Ed25519 point.
    BadKey,
    /// The signature does not verify.
    BadSignature,
}

/// The same check as embassy-boot's `verify_and_mark_updated`, in steps: for an application
/// that must not stop for the whole image's SHA-512 in one call (`src/dfu/` reads the image
/// back a page per pass of its loop). Feed the image's first [`Trailer::signed_len`] bytes in
/// order with [`Verifier::update`], then [`Verifier::finish`]; on `Ok`, mark the image with
/// embassy-boot's `BlockingFirmwareState::mark_updated`. The scheme is the one
/// `verify_and_mark_updated` checks (the tests hold the two to the same answers). Unlike
/// `verify_and_mark_updated`, `BlockingFirmwareState::mark_updated` does not refuse during a
/// trial boot: check that the state is not `Swap` before starting.
pub struct Verifier {
    hash: salty::Sha512,
    fed: u32,
    signed_len: u32,
    signature: [u8; 64],
}

impl Verifier {
    /// A verifier for the image `trailer` describes (already parsed and checked).
    pub fn new(trailer: &Trailer) -> Result<Self, ImageError> {
        Ok(Verifier {
            hash: salty::Sha512::new(),
            fed: 0,
            signed_len: trailer.signed_len().ok_or(ImageError::TooLarge)?,
            signature: trailer.signature,
        })
    }

    /// The next bytes of the image, from its start. Bytes past the signed part are ignored.
    pub fn update(&mut self, bytes: &[u8]) {
        let room = (self.signed_len - self.fed) as usize;
        let take = bytes.get(..room.min(bytes.len())).unwrap_or_default();
        self.hash.update(take);
        // `take` is at most `room`, a u32.
        self.fed += take.len() as u32;
    }

    /// The signed bytes still to feed.
    pub fn remaining(&self) -> u32 {
        self.signed_len - self.fed
    }

    /// Verifies the signature with `public_key`.
    pub fn finish(self, public_key: &[u8; 32]) -> Result<(), VerifyError> {
        if self.fed != self.signed_len {
            return Err(VerifyError::Incomplete);
        }
        let key = salty::PublicKey::try_from(public_key).map_err(|_| VerifyError::BadKey)?;
        let sig = salty::Signature::from(&self.signature);
        let digest = self.hash.finalize();
        key.verify(&digest, &sig)
            .map_err(|_| VerifyError::BadSignature)
    }
}
