//! The one error type of the codec.
//!
//! Every way a frame can be wrong has its own variant, with the data a person debugging a bus
//! needs (the byte found, the BCC expected). Errors are `Copy` and small so that a bus master can
//! count and log them without allocating.

use core::fmt;

/// A field of a command or response whose value is outside what the vendor documents allow.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Field {
    /// Position number (`00`-`0F`, complete edition §4-4-4).
    PositionNo,
    /// Transfer type `Typ` of Q1/Q2/Q3/V5 (`00` or `01`).
    TransferType,
    /// Home direction of `o` (`07` or `08`, complete edition §4-4-13).
    HomeDirection,
    /// Reset type of `r` (`02` or `03`, complete edition §4-4-16).
    ResetKind,
    /// Minimum response delay RTIM of `p` (`03`-`FF` ms, complete edition §4-4-14).
    Rtim,
    /// Servo flag of `q` (`0` or `1`).
    Servo,
    /// The velocity type of `v` (only `2` is documented).
    VelocityType,
    /// Velocity (`0000`-`57E4` in 0.2 rpm, complete edition §7-2-2).
    Velocity,
    /// Acceleration (`0001`-`07FF` in 0.1 rpm/ms, complete edition §7-2-2).
    Acceleration,
    /// The command inside `h`: Q2, Q3 or a direct command other than `h` (§4-4-10).
    BufferedCommand,
    /// The function number of a memory response (`4` for R4/T4/W4, `5` for V5, `8`-`F` if rejected).
    FunctionNumber,
}

/// Why a sequence of bytes is not a valid frame, command or response.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Error {
    /// A frame is exactly 16 bytes; this one had `len`.
    WrongLength {
        /// Bytes received.
        len: usize,
    },
    /// The first byte is not STX (0x02).
    MissingStx {
        /// The byte found instead.
        found: u8,
    },
    /// The 16th byte is not ETX (0x03).
    MissingEtx {
        /// The byte found instead.
        found: u8,
    },
    /// The block check characters do not match the 12 data characters.
    BadBcc {
        /// The BCC computed from the data.
        expected: u8,
        /// The BCC the frame carried.
        received: u8,
    },
    /// A character that must be an upper-case hexadecimal digit is not.
    NonHexDigit {
        /// Index of the byte in the 16-byte frame (STX is 0).
        index: u8,
        /// The byte found.
        found: u8,
    },
    /// A fixed character (filler `0`, the `trw` of `p`, the `U` of a response) is wrong.
    UnexpectedChar {
        /// Index of the byte in the 16-byte frame (STX is 0).
        index: u8,
        /// The byte found.
        found: u8,
    },
    /// The command (or echoed response) character is not one the documents define.
    UnknownCommand {
        /// The command character(s): the Func-CHAR, then the Func-Num or 0.
        code: [u8; 2],
    },
    /// The axis character is not `0`-`9`/`A`-`F`.
    BadAxis {
        /// The byte found.
        found: u8,
    },
    /// A field decoded to a value the documents do not allow.
    FieldOutOfRange {
        /// Which field.
        field: Field,
        /// The value decoded.
        value: u32,
    },
    /// A frame was cut short: a new STX arrived after only `len` bytes.
    Truncated {
        /// Bytes of the abandoned frame, STX included.
        len: u8,
    },
}

impl Field {
    /// The error for this field holding `value`.
    pub(crate) fn out_of_range(self, value: impl Into<u32>) -> Error {
        Error::FieldOutOfRange {
            field: self,
            value: value.into(),
        }
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Error::WrongLength { len } => write!(f, "frame is {len} bytes, expected 16"),
            Error::MissingStx { found } => write!(f, "expected STX (0x02), found 0x{found:02X}"),
            Error::MissingEtx { found } => write!(f, "expected ETX (0x03), found 0x{found:02X}"),
            Error::BadBcc { expected, received } => {
                write!(
                    f,
                    "bad BCC: expected {expected:02X}, received {received:02X}"
                )
            }
            Error::NonHexDigit { index, found } => {
                write!(
                    f,
                    "byte {index} (0x{found:02X}) is not an upper-case hex digit"
                )
            }
            Error::UnexpectedChar { index, found } => {
                write!(f, "unexpected byte 0x{found:02X} at index {index}")
            }
            Error::UnknownCommand { code } => {
                write!(f, "unknown command 0x{:02X} 0x{:02X}", code[0], code[1])
            }
            Error::BadAxis { found } => write!(f, "bad axis character 0x{found:02X}"),
            Error::FieldOutOfRange { field, value } => {
                write!(f, "{field:?} out of range: 0x{value:X}")
            }
            Error::Truncated { len } => write!(f, "frame cut short after {len} bytes"),
        }
    }
}

impl core::error::Error for Error {}
