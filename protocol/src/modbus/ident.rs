//! Who the slave is: FC2B/0E Read Device Identification (Application Protocol §6.21, Annex A
//! of the MEI) and FC11 Report Server ID (Serial Line §6.2 / Application Protocol §6.13).
//!
//! The objects answered are the basic ones (0x00 VendorName, 0x01 ProductCode, 0x02
//! MajorMinorRevision) and the regular ones the gateway has (0x03 VendorUrl, 0x04 ProductName,
//! 0x05 ModelName), by stream (ReadDevId 01 basic, 02 regular, 03 extended: there are no
//! extended objects, so it is the regular stream) and one at a time (04). Conformity level
//! 0x82: regular identification, stream and individual access. Every object fits in one
//! reply, so More Follows is always 0x00.

use super::adu::Writer;
use super::Exception;

/// FC2B's MEI type for Read Device Identification.
pub const MEI_READ_DEVICE_ID: u8 = 0x0E;
/// The conformity level: regular identification, stream and individual access.
pub const CONFORMITY: u8 = 0x82;
/// FC11's run indicator status when the device runs.
pub const RUN_ON: u8 = 0xFF;
/// ... and when it does not.
pub const RUN_OFF: u8 = 0x00;

/// What a unit answers about itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Identity {
    /// Object 0x00.
    pub vendor_name: &'static str,
    /// Object 0x01.
    pub product_code: &'static str,
    /// Object 0x02, "major.minor" and more (e.g. "0.1.0").
    pub revision: &'static str,
    /// Object 0x03.
    pub vendor_url: &'static str,
    /// Object 0x04.
    pub product_name: &'static str,
    /// Object 0x05.
    pub model_name: &'static str,
}

impl Identity {
    /// The revision's first three numbers ("1.2.3" and "1.2.3-rc1" give (1, 2, 3)); missing or
    /// unreadable parts read 0.
    // A byte loop rather than `split` and `str::parse`, whose code took 350 B of the F103's
    // flash for the VERSION register.
    pub fn version(&self) -> (u8, u8, u16) {
        version_of(self.revision)
    }

    /// Object `id`'s value, if it is one of the six.
    pub fn object(&self, id: u8) -> Option<&'static str> {
        Some(match id {
            0x00 => self.vendor_name,
            0x01 => self.product_code,
            0x02 => self.revision,
            0x03 => self.vendor_url,
            0x04 => self.product_name,
            0x05 => self.model_name,
            _ => return None,
        })
    }
}

/// See [`Identity::version`].
fn version_of(revision: &str) -> (u8, u8, u16) {
    let mut numbers = [0u16; 3];
    let mut parts = revision
        .as_bytes()
        .split(|b| matches!(b, b'.' | b'-' | b'+'));
    for slot in numbers.iter_mut() {
        *slot = parts.next().and_then(decimal).unwrap_or(0);
    }
    let [major, minor, patch] = numbers;
    (
        u8::try_from(major).unwrap_or(u8::MAX),
        u8::try_from(minor).unwrap_or(u8::MAX),
        patch,
    )
}

/// A decimal `u16` of one or more digits (what `str::parse::<u16>` accepts without a sign).
fn decimal(digits: &[u8]) -> Option<u16> {
    if digits.is_empty() {
        return None;
    }
    digits.iter().try_fold(0u16, |value, &b| {
        let digit = char::from(b).to_digit(10)?;
        value
            .checked_mul(10)?
            .checked_add(u16::try_from(digit).ok()?)
    })
}

/// ReadDevId codes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ReadDevId {
    /// 01: the basic objects, as a stream.
    Basic,
    /// 02: the regular objects, as a stream.
    Regular,
    /// 03: the extended objects, as a stream.
    Extended,
    /// 04: one object.
    Individual,
}

impl ReadDevId {
    /// The code on the wire.
    pub const fn code(self) -> u8 {
        match self {
            ReadDevId::Basic => 0x01,
            ReadDevId::Regular => 0x02,
            ReadDevId::Extended => 0x03,
            ReadDevId::Individual => 0x04,
        }
    }

    /// The code's meaning, if it is one.
    pub const fn from_code(code: u8) -> Option<ReadDevId> {
        match code {
            0x01 => Some(ReadDevId::Basic),
            0x02 => Some(ReadDevId::Regular),
            0x03 => Some(ReadDevId::Extended),
            0x04 => Some(ReadDevId::Individual),
            _ => None,
        }
    }

    /// The last object of its stream.
    const fn last(self) -> u8 {
        match self {
            ReadDevId::Basic => 0x02,
            _ => 0x05,
        }
    }
}

/// Writes the body of the FC2B/0E reply after the function code: MEI type, ReadDevId code,
/// conformity level, More Follows, Next Object Id, number of objects, then the objects. A stream
/// that names an object it does not have starts at object 0 (§6.21); an individual request for
/// an unknown object is exception 02.
pub(super) fn write_device_id(
    w: &mut Writer<'_>,
    identity: &Identity,
    code: ReadDevId,
    object: u8,
) -> Result<(), Exception> {
    let (first, last) = match code {
        ReadDevId::Individual => {
            identity
                .object(object)
                .ok_or(Exception::IllegalDataAddress)?;
            (object, object)
        }
        _ if object <= code.last() => (object, code.last()),
        _ => (0, code.last()),
    };
    w.byte(MEI_READ_DEVICE_ID);
    w.byte(code.code());
    w.byte(CONFORMITY);
    w.byte(0x00); // More Follows: everything fits.
    w.byte(0x00); // Next Object Id: none.
    w.byte(last - first + 1);
    for id in first..=last {
        let value = identity.object(id).unwrap_or("").as_bytes();
        w.byte(id);
        w.len8(value.len());
        w.bytes(value);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rule as first written, with `split` and `str::parse`: the byte loop must agree.
    fn reference(revision: &str) -> (u8, u8, u16) {
        let mut parts = revision.split(['.', '-', '+']);
        let mut next = || {
            parts
                .next()
                .and_then(|p| p.parse::<u16>().ok())
                .unwrap_or(0)
        };
        let (major, minor, patch) = (next(), next(), next());
        (
            u8::try_from(major).unwrap_or(u8::MAX),
            u8::try_from(minor).unwrap_or(u8::MAX),
            patch,
        )
    }

    #[test]
    fn version_reads_like_split_and_parse() {
        let pieces = [
            "", "0", "1", "12", "255", "256", "65535", "65536", "x", "1x", "+", "-", ".", "rc1",
            "٣",
        ];
        let separators = [".", "-", "+", ""];
        let mut count = 0;
        for a in pieces {
            for s in separators {
                for b in pieces {
                    for t in separators {
                        for c in pieces {
                            let mut buf = [0u8; 64];
                            let mut len = 0;
                            for piece in [a, s, b, t, c, "-rc1"] {
                                for &byte in piece.as_bytes() {
                                    buf[len] = byte;
                                    len += 1;
                                }
                            }
                            let revision = core::str::from_utf8(&buf[..len]).unwrap();
                            assert_eq!(version_of(revision), reference(revision), "{revision:?}");
                            count += 1;
                        }
                    }
                }
            }
        }
        assert!(count > 10_000);
        assert_eq!(
            crate::plc::IDENTITY.version(),
            reference(env!("CARGO_PKG_VERSION"))
        );
    }
}
