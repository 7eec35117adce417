//! Small values that appear in frames, each a type whose constructor enforces the range the
//! vendor documents give, so that a frame built from them is always one the controller accepts.

use crate::error::{Error, Field};
use crate::hex;

macro_rules! ranged_u8 {
    ($(#[$meta:meta])* $name:ident, $min:expr, $max:expr) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        pub struct $name(u8);

        impl $name {
            /// Smallest allowed value.
            pub const MIN: $name = $name($min);
            /// Largest allowed value.
            pub const MAX: $name = $name($max);

            /// The value, if it is in range.
            #[allow(unused_comparisons)]
            pub const fn new(value: u8) -> Option<$name> {
                if value >= $min && value <= $max {
                    Some($name(value))
                } else {
                    None
                }
            }

            /// The value as a number.
            pub const fn get(self) -> u8 {
                self.0
            }
        }

        impl TryFrom<u8> for $name {
            type Error = u8;
            fn try_from(value: u8) -> Result<Self, u8> {
                $name::new(value).ok_or(value)
            }
        }

        impl From<$name> for u8 {
            fn from(value: $name) -> u8 {
                value.0
            }
        }
    };
}

ranged_u8!(
    /// An axis (controller) address on the bus, 0-15, written as one hex digit
    /// (brief edition §4-1, set on the controller's DIP switches).
    Axis,
    0,
    15
);

ranged_u8!(
    /// A position (point-table row) number, 0-15 (brief edition §4-1), written as two hex digits.
    PositionNo,
    0,
    15
);

ranged_u8!(
    /// Minimum response delay RTIM in milliseconds, 3-255 (complete edition §4-4-14, §7-2-1).
    ///
    /// The controller waits at least this long after receiving a command before it answers.
    Rtim,
    3,
    255
);

impl Axis {
    /// Every axis, 0 to 15.
    pub fn all() -> impl Iterator<Item = Axis> {
        (0..16).map(Axis)
    }

    /// The hex digit that addresses this axis.
    pub const fn to_char(self) -> u8 {
        hex::digit(self.0 as u32)
    }

    /// The axis addressed by a hex digit.
    pub const fn from_char(c: u8) -> Result<Axis, Error> {
        match hex::value(c) {
            Some(v) => Ok(Axis(v)),
            None => Err(Error::BadAxis { found: c }),
        }
    }
}

impl PositionNo {
    /// Every position number, 0 to 15.
    pub fn all() -> impl Iterator<Item = PositionNo> {
        (0..=15).map(PositionNo)
    }

    pub(crate) fn decode(value: u8) -> Result<PositionNo, Error> {
        PositionNo::new(value).ok_or(Field::PositionNo.out_of_range(value))
    }
}

/// Rtim after a break: 255 ms (complete edition §7-2-1, BRSL note).
pub const RTIM_AFTER_BREAK: Rtim = Rtim::MAX;

/// An address in the controller's virtual memory (complete edition §7), 32 bits on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Address(pub u32);

impl Address {
    /// The address after this one; W4 answers with it (complete edition §4-4-3).
    pub const fn next(self) -> Address {
        Address(self.0.wrapping_add(1))
    }
}

/// A position or distance in encoder pulses, as the controller stores it: a signed 32-bit value,
/// written on the wire as 8 hex digits of its two's-complement bits.
///
/// Use [`units`](crate::units) to convert from millimetres.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Pulses(pub i32);

impl Pulses {
    /// The 32 bits on the wire.
    pub const fn to_wire(self) -> u32 {
        self.0 as u32
    }

    /// From the 32 bits on the wire.
    pub const fn from_wire(bits: u32) -> Pulses {
        Pulses(bits as i32)
    }
}

/// Velocity in units of 0.2 rpm, 0 to 0x57E4 (complete edition §7-2-2 VCMD).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Velocity(u16);

impl Velocity {
    /// Largest velocity the controller accepts: 0x57E4 x 0.2 rpm = 4500 rpm.
    pub const MAX: Velocity = Velocity(0x57E4);

    /// The velocity, if in range.
    pub const fn new(units: u16) -> Option<Velocity> {
        if units <= Self::MAX.0 {
            Some(Velocity(units))
        } else {
            None
        }
    }

    /// The value in 0.2 rpm.
    pub const fn get(self) -> u16 {
        self.0
    }
}

/// Acceleration in units of 0.1 rpm/ms, 1 to 0x07FF (complete edition §7-2-2 ACMD).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Acceleration(u16);

impl Acceleration {
    /// Smallest acceleration the controller accepts.
    pub const MIN: Acceleration = Acceleration(1);
    /// Largest acceleration the controller accepts.
    pub const MAX: Acceleration = Acceleration(0x07FF);

    /// The acceleration, if in range.
    pub const fn new(units: u16) -> Option<Acceleration> {
        if units >= Self::MIN.0 && units <= Self::MAX.0 {
            Some(Acceleration(units))
        } else {
            None
        }
    }

    /// The value in 0.1 rpm/ms.
    pub const fn get(self) -> u16 {
        self.0
    }
}

/// Which end of the stroke the axis homes to (`o` command, complete edition §4-4-13).
///
/// It also fixes the sign of positions: homing to the motor end makes the coordinates negative
/// (brief edition §4-3 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HomeDirection {
    /// `07`: normal rotation, toward the motor. The documents' default; required for rod types.
    MotorEnd,
    /// `08`: reverse rotation, away from the motor.
    NonMotorEnd,
}

impl HomeDirection {
    /// The code in the `o` command.
    pub const fn code(self) -> u8 {
        match self {
            HomeDirection::MotorEnd => 0x07,
            HomeDirection::NonMotorEnd => 0x08,
        }
    }

    pub(crate) fn from_code(code: u8) -> Result<HomeDirection, Error> {
        match code {
            0x07 => Ok(HomeDirection::MotorEnd),
            0x08 => Ok(HomeDirection::NonMotorEnd),
            _ => Err(Field::HomeDirection.out_of_range(code)),
        }
    }
}

/// What the `r` command resets (complete edition §4-4-16).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetKind {
    /// `02`: load the shipped defaults into the edit and execution areas.
    InitializeData,
    /// `03`: clear the alarm (the servo must be off, else warning 0x73).
    AlarmReset,
}

impl ResetKind {
    /// The code in the `r` command.
    pub const fn code(self) -> u8 {
        match self {
            ResetKind::InitializeData => 0x02,
            ResetKind::AlarmReset => 0x03,
        }
    }

    pub(crate) fn from_code(code: u8) -> Result<ResetKind, Error> {
        match code {
            0x02 => Ok(ResetKind::InitializeData),
            0x03 => Ok(ResetKind::AlarmReset),
            _ => Err(Field::ResetKind.out_of_range(code)),
        }
    }
}

/// What a batch transfer (Q1, V5) moves: the common parameters, or one point-table row
/// (`Typ` `00` or `01` + position number, complete edition §4-4-4, §4-4-7).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Transfer {
    /// `Typ 00`: the common parameters (position number field `00`).
    CommonParameters,
    /// `Typ 01`: the point-table row.
    Point(PositionNo),
}

/// What Q2 forwards from the edit area to the execution area (complete edition §4-4-5).
///
/// The section says `01` is rejected, yet its own example and §6-4 use `01` to forward position
/// data (which starts a move). Both are encodable; which one a controller accepts is its own.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DataType {
    /// `00`: common parameters.
    CommonParameters,
    /// `01`: position data (the axis moves to the edit area's point).
    PositionData,
}

impl DataType {
    pub(crate) const fn code(self) -> u8 {
        match self {
            DataType::CommonParameters => 0x00,
            DataType::PositionData => 0x01,
        }
    }

    pub(crate) fn from_code(code: u8) -> Result<DataType, Error> {
        match code {
            0x00 => Ok(DataType::CommonParameters),
            0x01 => Ok(DataType::PositionData),
            _ => Err(Field::TransferType.out_of_range(code)),
        }
    }
}
