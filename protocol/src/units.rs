//! Millimetres, mm/s and G to and from the controller's units, in integers (no FPU needed).
//!
//! Formulas: brief edition §4-3 3) and 5), complete edition §8-2.
//! - position, distance, band: pulses = mm x pulses/rev / lead (800 pulses/rev by default);
//! - velocity: 0.2 rpm units = mm/s x 300 / lead (= mm/s x 60 / lead / 0.2);
//! - acceleration: 0.1 rpm/ms units = G x 5883.99 / lead (= G x 60 x 9.80665 x 1000 / lead / 1000 / 0.1);
//! - push: push % x lead (brief edition §4-3 4).
//!
//! Lengths are in 0.01 mm, speeds in 0.01 mm/s and accelerations in 0.01 G: the resolution IAI's
//! Modbus registers use, and enough for every worked example.
//!
//! # Rounding
//! Toward the controller, results are truncated toward zero: the complete edition's example
//! rounds 176.5197 down to 176 "(round-down)", and the brief edition's 470.7192 -> 0x1D6 (470)
//! and 7573.33 -> 0x1D95 agree. From the controller, positions are rounded to the nearest
//! 0.01 mm, halves away from zero: the brief edition reads 0xFFFF167A with a 12 mm lead as
//! 896.72 mm (exactly 896.715).
//!
//! # Sign
//! An axis that homes to the motor end has negative coordinates. The brief edition's rule writes
//! a motor-end position as FFFFFFFF - pulses (the one's complement: -pulses - 1); the complete
//! edition's examples negate exactly (two's complement, -pulses), although its text also says
//! "one's complement". The two differ by one pulse. [`Complement::Ones`], the stated rule of both
//! editions, is the default; [`Complement::Twos`] is there for controllers and tools that negate
//! exactly. Incremental moves use "the equations for the opposite homing direction" for negative
//! distances (brief edition §4-3 3).

use core::num::{NonZeroU16, NonZeroU32};

use crate::div::{div, div_rem, divisor};

use crate::types::{Acceleration, HomeDirection, Pulses, Velocity};

/// Encoder pulses per motor revolution unless configured otherwise (complete edition §8-2).
pub const DEFAULT_PULSES_PER_REV: NonZeroU16 = match NonZeroU16::new(800) {
    Some(n) => n,
    None => NonZeroU16::MIN,
};
/// The velocity factor: 0.2 rpm units per (mm/s per mm of lead), 60 / 0.2.
const VELOCITY_FACTOR: i64 = 300;
/// The acceleration factor 5883.99, in hundredths: 60 x 9.80665 x 1000 / 1000 / 0.1 x 100.
const ACCELERATION_FACTOR_X100: i64 = 588_399;
/// [`VELOCITY_FACTOR`] as a divisor.
const VELOCITY_DIVISOR: NonZeroU32 = divisor(VELOCITY_FACTOR as u32);
/// [`ACCELERATION_FACTOR_X100`] as a divisor.
const ACCELERATION_DIVISOR: NonZeroU32 = divisor(ACCELERATION_FACTOR_X100 as u32);
/// Positions the controller accepts: C0000000H-3FFFFFFFH (complete edition §7-2-2 PCMD).
const POSITION_LIMIT: i64 = 0x3FFF_FFFF;

/// A length or position in 0.01 mm.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Length(pub i32);

/// A speed in 0.01 mm/s.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Speed(pub u32);

/// An acceleration in 0.01 G.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Accel(pub u32);

/// Why a value cannot be expressed in the controller's units.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum UnitError {
    /// The result is outside the range the controller accepts.
    OutOfRange,
    /// The result rounds to zero where zero is not allowed (acceleration).
    TooSmall,
}

/// Screw lead in 0.01 mm. Never zero, by its type: every conversion divides by it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Lead(NonZeroU16);

/// A lead of `hundredths` that is known not to be zero (the chart's constants).
const fn lead(hundredths: u16) -> Lead {
    match NonZeroU16::new(hundredths) {
        Some(h) => Lead(h),
        None => Lead(NonZeroU16::MIN),
    }
}

/// Lead types of common parameter REG1, bits 0-3 (complete edition §7-2-1), in 0.01 mm.
const LEAD_TYPES: [u16; 10] = [250, 300, 400, 500, 600, 800, 1000, 1200, 1600, 2000];

impl Lead {
    /// A lead of `hundredths` x 0.01 mm, if not zero.
    pub const fn from_hundredths(hundredths: u16) -> Option<Lead> {
        match NonZeroU16::new(hundredths) {
            Some(h) => Some(Lead(h)),
            None => None,
        }
    }

    /// The lead in 0.01 mm.
    pub const fn hundredths(self) -> u16 {
        self.0.get()
    }

    /// The lead as a divisor.
    fn divisor(self) -> NonZeroU32 {
        NonZeroU32::from(self.0)
    }

    /// The lead of a REG1 lead-type code (bits 0-3; 0 = 2.5 mm ... 9 = 20 mm).
    pub fn from_lead_type(reg1: u32) -> Option<Lead> {
        let index = usize::try_from(reg1 & 0x0F).ok()?;
        LEAD_TYPES.get(index).map(|&h| lead(h))
    }

    /// The lead of an actuator model and speed type (brief edition §4-3 7, screw lead chart).
    pub const fn of(actuator: ActuatorType, speed: SpeedType) -> Lead {
        use ActuatorType::*;
        let [low, medium, high] = match actuator {
            S5 | S6 | SS | SSR => [300, 600, 1200],
            SM | SMR => [500, 1000, 2000],
            RS => [250, 500, 1000],
            RM => [400, 800, 1600],
        };
        lead(match speed {
            SpeedType::L => low,
            SpeedType::M => medium,
            SpeedType::H => high,
        })
    }
}

/// Actuator models of the brief edition's screw lead chart (§4-3 7).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[allow(missing_docs)]
pub enum ActuatorType {
    S5,
    S6,
    SS,
    SM,
    SSR,
    SMR,
    RS,
    RM,
}

impl ActuatorType {
    /// Every model of the chart.
    pub const ALL: [ActuatorType; 8] = [
        ActuatorType::S5,
        ActuatorType::S6,
        ActuatorType::SS,
        ActuatorType::SM,
        ActuatorType::SSR,
        ActuatorType::SMR,
        ActuatorType::RS,
        ActuatorType::RM,
    ];
}

/// Speed types of the screw lead chart: low, medium, high lead.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[allow(missing_docs)]
pub enum SpeedType {
    L,
    M,
    H,
}

/// How a negative position is written; see the [module documentation](self).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Complement {
    /// FFFFFFFF - pulses (brief edition's formula; both editions' wording).
    #[default]
    Ones,
    /// -pulses (the complete edition's worked examples).
    Twos,
}

impl Complement {
    const fn negate(self, pulses: i64) -> i64 {
        match self {
            Complement::Ones => -pulses - 1,
            Complement::Twos => -pulses,
        }
    }
}

/// Everything needed to convert for one axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Scale {
    /// Screw lead.
    pub lead: Lead,
    /// Encoder pulses per revolution (800 for the documented actuators); never zero.
    pub pulses_per_rev: NonZeroU16,
    /// Home end, which sets the sign of coordinates.
    pub home: HomeDirection,
    /// How negative values are written.
    pub complement: Complement,
}

/// Integer division of `n` by `d`, truncated toward zero. `d` cannot be zero and the quotient
/// of a magnitude cannot overflow, so this has no panic path. The divisions of this module
/// go through [`div`] and [`div_rem`]: 32-bit divisors, no 64-bit division routine on the MCU.
fn div_trunc(n: i64, d: NonZeroU32) -> i64 {
    let q = i64::try_from(div(n.unsigned_abs(), d)).unwrap_or(i64::MAX);
    if n < 0 {
        -q
    } else {
        q
    }
}

/// Integer division of `n` by `d`, rounded to nearest, halves away from zero. Never overflows:
/// it works on magnitudes and never forms `2 * n` (a public caller may pass any `i64`).
fn div_round(n: i64, d: NonZeroU32) -> i64 {
    let (q, r) = div_rem(n.unsigned_abs(), d);
    // r < d, so d - r cannot underflow; rounding up when r >= d - r avoids forming 2 * r.
    let q = q.saturating_add(u64::from(r >= d.get().saturating_sub(r)));
    let q = i64::try_from(q).unwrap_or(i64::MAX);
    if n < 0 {
        -q
    } else {
        q
    }
}

impl Scale {
    /// 800 pulses/rev and the one's-complement rule.
    pub const fn new(lead: Lead, home: HomeDirection) -> Scale {
        Scale {
            lead,
            pulses_per_rev: DEFAULT_PULSES_PER_REV,
            home,
            complement: Complement::Ones,
        }
    }

    /// Magnitude conversion: pulses for a length, truncated toward zero.
    pub fn pulses(&self, length: Length) -> i64 {
        div_trunc(
            i64::from(length.0) * i64::from(self.pulses_per_rev.get()),
            self.lead.divisor(),
        )
    }

    /// Magnitude conversion back: the length of `pulses`, rounded to 0.01 mm.
    pub fn length(&self, pulses: i64) -> Length {
        let ppr = NonZeroU32::from(self.pulses_per_rev);
        let value = div_round(
            pulses.saturating_mul(i64::from(self.lead.hundredths())),
            ppr,
        );
        Length(clamp_i32(value))
    }

    fn on_wire(pulses: i64) -> Result<Pulses, UnitError> {
        if (-POSITION_LIMIT - 1..=POSITION_LIMIT).contains(&pulses) {
            i32::try_from(pulses)
                .map(Pulses)
                .map_err(|_| UnitError::OutOfRange)
        } else {
            Err(UnitError::OutOfRange)
        }
    }

    /// The `a` / PCMD value for a position measured from home.
    pub fn position_to_wire(&self, position: Length) -> Result<Pulses, UnitError> {
        let pulses = self.pulses(position);
        Self::on_wire(match self.home {
            HomeDirection::NonMotorEnd => pulses,
            HomeDirection::MotorEnd => self.complement.negate(pulses),
        })
    }

    /// The position from home of an R4 PNOW or PCMD value.
    pub fn position_from_wire(&self, wire: Pulses) -> Length {
        let raw = i64::from(wire.0);
        self.length(match self.home {
            HomeDirection::NonMotorEnd => raw,
            HomeDirection::MotorEnd => self.complement.negate(raw),
        })
    }

    /// The `m` value for a signed distance: positive moves away from home.
    pub fn distance_to_wire(&self, distance: Length) -> Result<Pulses, UnitError> {
        let magnitude = self.pulses(Length(distance.0.saturating_abs()));
        // Away from home is positive for non-motor-end homing, negative for motor-end homing.
        let negative = (distance.0 < 0) != (self.home == HomeDirection::MotorEnd);
        Self::on_wire(if negative && magnitude != 0 {
            self.complement.negate(magnitude)
        } else {
            magnitude
        })
    }

    /// The signed distance of an `m` value (inverse of [`distance_to_wire`](Self::distance_to_wire)).
    pub fn distance_from_wire(&self, wire: Pulses) -> Length {
        let raw = i64::from(wire.0);
        let toward_motor_end = raw < 0;
        let magnitude = if toward_motor_end {
            self.complement.negate(raw)
        } else {
            raw
        };
        let length = self.length(magnitude);
        if toward_motor_end != (self.home == HomeDirection::MotorEnd) {
            Length(length.0.saturating_neg())
        } else {
            length
        }
    }

    /// The INP (position band) value of a band width: a magnitude, never complemented.
    pub fn band_to_wire(&self, band: Length) -> Result<u32, UnitError> {
        let pulses = self.pulses(band);
        if (0..=POSITION_LIMIT).contains(&pulses) {
            u32::try_from(pulses).map_err(|_| UnitError::OutOfRange)
        } else {
            Err(UnitError::OutOfRange)
        }
    }

    /// The velocity units of a speed, truncated.
    pub fn velocity(&self, speed: Speed) -> Result<Velocity, UnitError> {
        let units = div_trunc(i64::from(speed.0) * VELOCITY_FACTOR, self.lead.divisor());
        u16::try_from(units)
            .ok()
            .and_then(Velocity::new)
            .ok_or(UnitError::OutOfRange)
    }

    /// The speed of a velocity value, rounded to 0.01 mm/s.
    pub fn speed(&self, velocity: Velocity) -> Speed {
        let value = div_round(
            i64::from(velocity.get()) * i64::from(self.lead.hundredths()),
            VELOCITY_DIVISOR,
        );
        Speed(u32::try_from(value).unwrap_or(0))
    }

    /// The acceleration units of an acceleration in G, truncated.
    pub fn acceleration(&self, accel: Accel) -> Result<Acceleration, UnitError> {
        let units = div_trunc(
            div_trunc(i64::from(accel.0) * ACCELERATION_FACTOR_X100, divisor(100)),
            self.lead.divisor(),
        );
        if units == 0 {
            return Err(UnitError::TooSmall);
        }
        u16::try_from(units)
            .ok()
            .and_then(Acceleration::new)
            .ok_or(UnitError::OutOfRange)
    }

    /// The acceleration in 0.01 G of an acceleration value, rounded.
    pub fn accel(&self, acceleration: Acceleration) -> Accel {
        let value = div_round(
            i64::from(acceleration.get()) * 100 * i64::from(self.lead.hundredths()),
            ACCELERATION_DIVISOR,
        );
        Accel(u32::try_from(value).unwrap_or(0))
    }

    /// The brief edition's push value (address 0x406): push % x lead in mm, truncated.
    pub fn push_data(&self, percent: u8) -> u32 {
        u32::from(percent) * u32::from(self.lead.hundredths()) / 100
    }
}

fn clamp_i32(value: i64) -> i32 {
    i32::try_from(value).unwrap_or(if value < 0 { i32::MIN } else { i32::MAX })
}
