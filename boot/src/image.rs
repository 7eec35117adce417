//! The signed image: the file sent over the PLC link into DFU.
//!
//! ```text
//! | application (n bytes) | 0xFF to a multiple of 8 | trailer (96 bytes)                            |
//! |<------------------ signed: SHA-512, then Ed25519 ------------>|                               |
//!                                                  | header (24) | signature (64) | CRC-32 | 0 0 0 0 |
//! ```
//!
//! The trailer, little-endian:
//!
//! | Offset | Size | Field |
//! |---|---|---|
//! | 0 | 8 | magic [`MAGIC`], `b"RCGWIMG1"` |
//! | 8 | 2 | board id (the L475: `0x0475`) |
//! | 10 | 2 | reserved, 0 |
//! | 12 | 4 | firmware version ([`Version`]: major, minor, patch as `major << 24 \| minor << 16 \| patch`) |
//! | 16 | 4 | the application's length *n* in bytes |
//! | 20 | 4 | reserved, 0 |
//! | 24 | 64 | Ed25519 signature |
//! | 88 | 4 | CRC-32 (IEEE, as zip) of the trailer's bytes 0..88 |
//! | 92 | 4 | reserved, 0 |
//!
//! **What is signed** is what embassy-boot's `verify_and_mark_updated(key, signature, len)`
//! checks: it reads the first `len` bytes of DFU, hashes them with SHA-512 and verifies the
//! signature over the 64-byte digest with plain Ed25519 (RFC 8032's Ed25519, the digest as the
//! message; not Ed25519ph). Here `len` is [`Trailer::signed_len`]: the padded application *and
//! the trailer's 24-byte header*, so the board id, the version and the length are signed with
//! the code: an image signed for one board cannot be relabelled for another. The signature
//! cannot sign itself, hence the header before it; the CRC-32 after it lets the application
//! tell a damaged or foreign trailer from a bad signature without the Ed25519 work.
//!
//! The whole file lands in DFU from offset 0; the swap moves ACTIVE's size of DFU into ACTIVE,
//! so the file must not be larger than ACTIVE ([`Layout::max_image`](crate::layout::Layout::max_image)).
//! The application finds the trailer from the file's length (the transfer's BEGIN declares it):
//! its last [`TRAILER_LEN`] bytes.

/// The trailer's first eight bytes.
pub const MAGIC: [u8; 8] = *b"RCGWIMG1";
/// The trailer's size in bytes (a multiple of the flash's 8-byte word).
pub const TRAILER_LEN: usize = 96;
/// The signed part of the trailer: everything before the signature.
pub const HEADER_LEN: usize = 24;
/// The application's padding unit (the flash's write unit) and its padding byte.
pub const ALIGN: usize = 8;
/// The padding byte: the erased value, so padding costs no flash write.
pub const PAD: u8 = 0xFF;

const SIG_AT: usize = HEADER_LEN;
const CRC_AT: usize = SIG_AT + 64;

const _: () = assert!(
    CRC_AT + 8 == TRAILER_LEN
        && TRAILER_LEN.is_multiple_of(ALIGN)
        && HEADER_LEN.is_multiple_of(ALIGN)
);

/// The CRC-32 of the trailer (IEEE 802.3, reflected: zip's, and the transfer's).
const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// A firmware version, signed with the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Version {
    /// Major.
    pub major: u8,
    /// Minor.
    pub minor: u8,
    /// Patch.
    pub patch: u16,
}

impl Version {
    /// As stored: `major << 24 | minor << 16 | patch`, so a later version is a larger number.
    pub const fn to_u32(self) -> u32 {
        (self.major as u32) << 24 | (self.minor as u32) << 16 | self.patch as u32
    }

    /// From the stored number.
    pub const fn from_u32(v: u32) -> Self {
        Self {
            major: (v >> 24) as u8,
            minor: (v >> 16) as u8,
            patch: v as u16,
        }
    }
}

/// Why an image or its trailer is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageError {
    /// Fewer bytes than a trailer (or than the trailer says the image has).
    Truncated,
    /// More bytes than a trailer, or than the trailer says the image has.
    TooLong,
    /// The trailer does not start with [`MAGIC`]: not an image of ours, or not its end.
    BadMagic,
    /// The trailer's CRC-32 does not match: damaged.
    BadCrc,
    /// A reserved field is not 0: a format this code does not know.
    UnknownFormat,
    /// The image is for another board.
    WrongBoard {
        /// The board id in the trailer.
        found: u16,
    },
    /// The image is larger than the partition it must fit.
    TooLarge,
    /// The bytes between the application and the trailer are not [`PAD`].
    BadPadding,
}

/// The trailer's fields.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Trailer {
    /// The board the image is for.
    pub board: u16,
    /// The firmware's version.
    pub version: Version,
    /// The application's length in bytes (before padding).
    pub app_len: u32,
    /// The Ed25519 signature over the SHA-512 of the first [`Trailer::signed_len`] bytes.
    pub signature: [u8; 64],
}

fn u16_at(b: &[u8; TRAILER_LEN], at: usize) -> u16 {
    let mut w = [0; 2];
    if let Some(s) = b.get(at..at + 2) {
        w.copy_from_slice(s);
    }
    u16::from_le_bytes(w)
}

fn u32_at(b: &[u8; TRAILER_LEN], at: usize) -> u32 {
    let mut w = [0; 4];
    if let Some(s) = b.get(at..at + 4) {
        w.copy_from_slice(s);
    }
    u32::from_le_bytes(w)
}

/// `n` rounded up to [`ALIGN`], `None` on overflow.
const fn padded(n: u32) -> Option<u32> {
    match n.checked_add(ALIGN as u32 - 1) {
        Some(v) => Some(v / ALIGN as u32 * ALIGN as u32),
        None => None,
    }
}

impl Trailer {
    /// Reads a trailer: `bytes` must be exactly [`TRAILER_LEN`] bytes. Checks the magic, the
    /// CRC-32 and the reserved fields, not the board nor the signature.
    pub fn parse(bytes: &[u8]) -> Result<Trailer, ImageError> {
        let b: &[u8; TRAILER_LEN] = match bytes.len() {
            n if n < TRAILER_LEN => return Err(ImageError::Truncated),
            n if n > TRAILER_LEN => return Err(ImageError::TooLong),
            _ => bytes.try_into().map_err(|_| ImageError::Truncated)?,
        };
        if b.get(..MAGIC.len()) != Some(&MAGIC[..]) {
            return Err(ImageError::BadMagic);
        }
        let body = b.get(..CRC_AT).ok_or(ImageError::Truncated)?;
        if CRC.checksum(body) != u32_at(b, CRC_AT) {
            return Err(ImageError::BadCrc);
        }
        if u16_at(b, 10) != 0 || u32_at(b, 20) != 0 || u32_at(b, CRC_AT + 4) != 0 {
            return Err(ImageError::UnknownFormat);
        }
        let mut signature = [0; 64];
        signature.copy_from_slice(b.get(SIG_AT..CRC_AT).ok_or(ImageError::Truncated)?);
        let t = Trailer {
            board: u16_at(b, 8),
            version: Version::from_u32(u32_at(b, 12)),
            app_len: u32_at(b, 16),
            signature,
        };
        // A length whose image would not fit in a u32 is no image.
        t.image_len().ok_or(ImageError::TooLarge)?;
        Ok(t)
    }

    /// The header: the trailer's signed first [`HEADER_LEN`] bytes.
    pub fn header(&self) -> [u8; HEADER_LEN] {
        let mut h = [0; HEADER_LEN];
        let (magic, rest) = h.split_at_mut(8);
        magic.copy_from_slice(&MAGIC);
        let (board, rest) = rest.split_at_mut(2);
        board.copy_from_slice(&self.board.to_le_bytes());
        let (_reserved, rest) = rest.split_at_mut(2);
        let (version, rest) = rest.split_at_mut(4);
        version.copy_from_slice(&self.version.to_u32().to_le_bytes());
        let (len, _reserved) = rest.split_at_mut(4);
        len.copy_from_slice(&self.app_len.to_le_bytes());
        h
    }

    /// The trailer's bytes (the header, the signature, the CRC-32).
    pub fn encode(&self) -> [u8; TRAILER_LEN] {
        let mut b = [0; TRAILER_LEN];
        let (header, rest) = b.split_at_mut(HEADER_LEN);
        header.copy_from_slice(&self.header());
        let (sig, _) = rest.split_at_mut(64);
        sig.copy_from_slice(&self.signature);
        let (body, tail) = b.split_at_mut(CRC_AT);
        let (crc, _reserved) = tail.split_at_mut(4);
        crc.copy_from_slice(&CRC.checksum(body).to_le_bytes());
        b
    }

    /// Where the trailer starts in the image: the application padded to [`ALIGN`].
    pub fn offset(&self) -> Option<u32> {
        padded(self.app_len)
    }

    /// The bytes the signature covers, from the image's start: the padded application and the
    /// trailer's header. The `update_len` to give `verify_and_mark_updated`.
    pub fn signed_len(&self) -> Option<u32> {
        self.offset()?.checked_add(HEADER_LEN as u32)
    }

    /// The whole file's length.
    pub fn image_len(&self) -> Option<u32> {
        self.offset()?.checked_add(TRAILER_LEN as u32)
    }

    /// Checks the trailer against the board and the image as received: `image_len` bytes, at
    /// most `max_image` (ACTIVE's size).
    pub fn check(&self, board: u16, image_len: u32, max_image: u32) -> Result<(), ImageError> {
        if self.board != board {
            return Err(ImageError::WrongBoard { found: self.board });
        }
        let want = self.image_len().ok_or(ImageError::TooLarge)?;
        if image_len < want {
            return Err(ImageError::Truncated);
        }
        if image_len > want {
            return Err(ImageError::TooLong);
        }
        if image_len > max_image {
            return Err(ImageError::TooLarge);
        }
        Ok(())
    }
}

/// Where the trailer of an image of `image_len` bytes starts, if it can hold one.
pub fn trailer_offset(image_len: u32) -> Result<u32, ImageError> {
    image_len
        .checked_sub(TRAILER_LEN as u32)
        .ok_or(ImageError::Truncated)
}

/// Splits a whole image file into its application and its trailer and checks them (the board,
/// the length, the padding; not the signature): for the host tools, and for tests.
pub fn split(image: &[u8], board: u16, max_image: u32) -> Result<(&[u8], Trailer), ImageError> {
    let len = u32::try_from(image.len()).map_err(|_| ImageError::TooLarge)?;
    let at = trailer_offset(len)? as usize;
    let trailer = Trailer::parse(image.get(at..).ok_or(ImageError::Truncated)?)?;
    trailer.check(board, len, max_image)?;
    let app_end = trailer.app_len as usize;
    let app = image.get(..app_end).ok_or(ImageError::Truncated)?;
    let pad = image.get(app_end..at).ok_or(ImageError::Truncated)?;
    if pad.iter().any(|&b| b != PAD) {
        return Err(ImageError::BadPadding);
    }
    Ok((app, trailer))
}

/// The SHA-512 embassy-boot signs over: of the first [`Trailer::signed_len`] bytes of the image.
pub fn digest(signed: &[u8]) -> [u8; 64] {
    let mut h = salty::Sha512::new();
    h.update(signed);
    h.finalize()
}

#[cfg(feature = "sign")]
mod signing {
    extern crate std;
    use std::vec::Vec;

    use super::*;

    /// An Ed25519 secret key (its 32-byte seed). Keep the real one offline: see the README.
    #[derive(Clone)]
    pub struct SecretKey(pub [u8; 32]);

    impl core::fmt::Debug for SecretKey {
        fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
            f.write_str("SecretKey(..)")
        }
    }

    impl SecretKey {
        /// A new key from the operating system's random source.
        pub fn generate() -> Result<SecretKey, getrandom::Error> {
            let mut seed = [0; 32];
            getrandom::fill(&mut seed)?;
            Ok(SecretKey(seed))
        }

        /// The public key the firmware verifies with (32 bytes).
        pub fn public_key(&self) -> [u8; 32] {
            salty::Keypair::from(&self.0).public.to_bytes()
        }

        /// The Ed25519 signature of `message`.
        pub fn sign_raw(&self, message: &[u8]) -> [u8; 64] {
            salty::Keypair::from(&self.0).sign(message).to_bytes()
        }
    }

    /// The whole image file: `app`, padding to [`ALIGN`] and the signed trailer.
    pub fn sign(
        app: &[u8],
        board: u16,
        version: Version,
        key: &SecretKey,
    ) -> Result<Vec<u8>, ImageError> {
        let app_len = u32::try_from(app.len()).map_err(|_| ImageError::TooLarge)?;
        let mut t = Trailer {
            board,
            version,
            app_len,
            signature: [0; 64],
        };
        let at = t.offset().ok_or(ImageError::TooLarge)? as usize;
        t.image_len().ok_or(ImageError::TooLarge)?;
        let mut file = Vec::with_capacity(at + TRAILER_LEN);
        file.extend_from_slice(app);
        file.resize(at, PAD);
        file.extend_from_slice(&t.header());
        t.signature = key.sign_raw(&digest(&file));
        file.truncate(at);
        file.extend_from_slice(&t.encode());
        Ok(file)
    }
}

#[cfg(feature = "sign")]
pub use signing::{sign, SecretKey};

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Trailer {
        let mut signature = [0; 64];
        for (i, b) in signature.iter_mut().enumerate() {
            *b = i as u8 ^ 0x5A;
        }
        Trailer {
            board: 0x0475,
            version: Version {
                major: 1,
                minor: 2,
                patch: 300,
            },
            app_len: 12_345,
            signature,
        }
    }

    #[test]
    fn round_trip() {
        let t = sample();
        let b = t.encode();
        assert_eq!(&b[..8], b"RCGWIMG1");
        assert_eq!(&b[8..10], &[0x75, 0x04]);
        assert_eq!(Trailer::parse(&b), Ok(t));
        assert_eq!(t.offset(), Some(12_352));
        assert_eq!(t.signed_len(), Some(12_352 + 24));
        assert_eq!(t.image_len(), Some(12_352 + 96));
    }

    #[test]
    fn version_orders_as_its_number() {
        let a = Version {
            major: 1,
            minor: 255,
            patch: 65535,
        };
        let b = Version {
            major: 2,
            minor: 0,
            patch: 0,
        };
        assert!(a < b && a.to_u32() < b.to_u32());
        assert_eq!(Version::from_u32(a.to_u32()), a);
    }

    #[test]
    fn typed_refusals() {
        let b = sample().encode();
        assert_eq!(Trailer::parse(&b[..95]), Err(ImageError::Truncated));
        assert_eq!(Trailer::parse(&[]), Err(ImageError::Truncated));
        let mut long = b.to_vec();
        long.push(0);
        assert_eq!(Trailer::parse(&long), Err(ImageError::TooLong));
        let mut m = b;
        m[0] ^= 1;
        assert_eq!(Trailer::parse(&m), Err(ImageError::BadMagic));
        for at in 8..TRAILER_LEN {
            let mut m = b;
            m[at] ^= 0x10;
            let r = Trailer::parse(&m);
            if at >= CRC_AT + 4 {
                assert_eq!(r, Err(ImageError::UnknownFormat), "byte {at}");
            } else {
                assert_eq!(r, Err(ImageError::BadCrc), "byte {at}");
            }
        }
        // A reserved field set, the CRC-32 made good: a format we do not know.
        let mut m = b;
        m[10] = 1;
        let crc = CRC.checksum(&m[..CRC_AT]);
        m[CRC_AT..CRC_AT + 4].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(Trailer::parse(&m), Err(ImageError::UnknownFormat));
    }

    #[test]
    fn check_board_and_length() {
        let t = sample();
        let len = t.image_len().unwrap();
        assert_eq!(t.check(0x0475, len, len), Ok(()));
        assert_eq!(
            t.check(0x0103, len, len),
            Err(ImageError::WrongBoard { found: 0x0475 })
        );
        assert_eq!(t.check(0x0475, len - 8, len), Err(ImageError::Truncated));
        assert_eq!(t.check(0x0475, len + 8, len + 8), Err(ImageError::TooLong));
        assert_eq!(t.check(0x0475, len, len - 1), Err(ImageError::TooLarge));
    }

    #[test]
    fn huge_length_is_refused_not_wrapped() {
        let mut t = sample();
        t.app_len = u32::MAX - 10;
        assert_eq!(Trailer::parse(&t.encode()), Err(ImageError::TooLarge));
    }

    #[test]
    fn sha512_known_answer() {
        // FIPS 180-2, "abc".
        let d = digest(b"abc");
        assert_eq!(d[..8], [0xdd, 0xaf, 0x35, 0xa1, 0x93, 0x61, 0x7a, 0xba]);
        assert_eq!(d[56..], [0x2a, 0x9a, 0xc9, 0x4f, 0xa5, 0x4c, 0xa4, 0x9f]);
    }

    proptest::proptest! {
        #[test]
        fn parse_never_panics(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..200)) {
            let _ = Trailer::parse(&bytes);
            let _ = split(&bytes, 0x0475, 1 << 20);
        }

        #[test]
        fn parse_never_panics_near_valid(at in 0usize..TRAILER_LEN, x in 1u8..=255, cut in 0usize..=TRAILER_LEN) {
            let mut b = sample().encode();
            b[at] ^= x;
            let r = Trailer::parse(&b);
            proptest::prop_assert!(r.is_err());
            let _ = Trailer::parse(&b[..cut]);
        }
    }
}
