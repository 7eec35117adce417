//! Numbers on the command line and in the JSON output.
//!
//! Millimetres, mm/s and G are parsed exactly, in integer arithmetic, into the hundredths that
//! [`protocol::units`] works in (`"56.8"` is 5680, a third decimal is an error). Raw values are
//! decimal or `0x` hex. [`ScaleArgs`] are the options that say how to convert for one axis.

use clap::{Args, ValueEnum};
use protocol::units::{Accel, Complement, Lead, Length, Scale, Speed, DEFAULT_PULSES_PER_REV};
use protocol::{Axis, HomeDirection, PositionNo, Pulses, Rtim};
use serde_json::Value;

/// A decimal with at most two fractional digits, in hundredths: `"-56.8"` is -5680.
pub fn hundredths(text: &str) -> Result<i64, String> {
    let invalid = || format!("`{text}` is not a decimal number");
    let (negative, unsigned) = match text.strip_prefix('-') {
        Some(rest) => (true, rest),
        None => (false, text.strip_prefix('+').unwrap_or(text)),
    };
    let (int, frac) = unsigned.split_once('.').unwrap_or((unsigned, ""));
    let digits = |s: &str| s.bytes().all(|b| b.is_ascii_digit());
    if (int.is_empty() && frac.is_empty()) || !digits(int) || !digits(frac) {
        return Err(invalid());
    }
    if frac.len() > 2 {
        return Err(format!(
            "`{text}` has more than 2 decimals (0.01 is the resolution)"
        ));
    }
    let whole: i64 = if int.is_empty() {
        0
    } else {
        int.parse().map_err(|_| invalid())?
    };
    let cents: i64 = format!("{frac:0<2}").parse().map_err(|_| invalid())?;
    let value = whole
        .checked_mul(100)
        .and_then(|v| v.checked_add(cents))
        .ok_or_else(|| format!("`{text}` is too large"))?;
    Ok(if negative { -value } else { value })
}

/// A length or position in mm (signed).
pub fn parse_length(text: &str) -> Result<Length, String> {
    let value = hundredths(text)?;
    i32::try_from(value)
        .map(Length)
        .map_err(|_| format!("`{text}` mm is out of range"))
}

/// A speed in mm/s.
pub fn parse_speed(text: &str) -> Result<Speed, String> {
    unsigned_hundredths(text).map(Speed)
}

/// An acceleration in G.
pub fn parse_accel(text: &str) -> Result<Accel, String> {
    unsigned_hundredths(text).map(Accel)
}

fn unsigned_hundredths(text: &str) -> Result<u32, String> {
    let value = hundredths(text)?;
    u32::try_from(value).map_err(|_| format!("`{text}` must be zero or positive"))
}

/// A screw lead in mm, not zero (e.g. `2.5`).
pub fn parse_lead(text: &str) -> Result<Lead, String> {
    let value = hundredths(text)?;
    u16::try_from(value)
        .ok()
        .and_then(Lead::from_hundredths)
        .ok_or_else(|| {
            format!("lead `{text}` must be between 0.01 and 655.35 mm (a screw's pitch, positive)")
        })
}

/// An unsigned integer, decimal or `0x` hex.
pub fn parse_raw(text: &str) -> Result<u32, String> {
    match strip_0x(text) {
        Some(digits) => parse_hex_u32(digits),
        None => text
            .parse()
            .map_err(|_| format!("`{text}` is not a number (decimal, or hex with 0x)")),
    }
}

/// A 16-bit unsigned integer, decimal or `0x` hex.
pub fn parse_raw_u16(text: &str) -> Result<u16, String> {
    let value = parse_raw(text)?;
    u16::try_from(value).map_err(|_| format!("`{text}` does not fit in 16 bits"))
}

/// A 32-bit value in hex, with or without `0x` (an address or a W4 word).
pub fn parse_hex_u32(text: &str) -> Result<u32, String> {
    let digits = strip_0x(text).unwrap_or(text);
    let valid = (1..=8).contains(&digits.len()) && digits.bytes().all(|b| b.is_ascii_hexdigit());
    if !valid {
        return Err(format!("`{text}` is not a hex number of 1 to 8 digits"));
    }
    u32::from_str_radix(digits, 16).map_err(|e| format!("`{text}`: {e}"))
}

/// Pulses: a signed decimal (`-8000`) or the 32 bits on the wire in hex (`0xFFFFE0C0`).
pub fn parse_pulses(text: &str) -> Result<Pulses, String> {
    match strip_0x(text) {
        Some(digits) => parse_hex_u32(digits).map(Pulses::from_wire),
        None => text.parse().map(Pulses).map_err(|_| {
            format!("`{text}` is not a pulse count (signed decimal, or 0x and 8 hex digits)")
        }),
    }
}

/// An axis: one hex digit (`C`) or its decimal number (`12`).
pub fn parse_axis(text: &str) -> Result<Axis, String> {
    let value = match text.as_bytes() {
        [digit] => (*digit as char).to_digit(16),
        _ => text.parse::<u32>().ok(),
    };
    value
        .and_then(|v| u8::try_from(v).ok())
        .and_then(Axis::new)
        .ok_or_else(|| format!("axis `{text}` is not 0-15 (a hex digit or a decimal number)"))
}

/// A point-table position number, 0-15.
pub fn parse_point(text: &str) -> Result<PositionNo, String> {
    parse_raw(text)
        .ok()
        .and_then(|v| u8::try_from(v).ok())
        .and_then(PositionNo::new)
        .ok_or_else(|| format!("position number `{text}` is not 0-15"))
}

/// The minimum response delay RTIM, 3-255 ms.
pub fn parse_rtim(text: &str) -> Result<Rtim, String> {
    parse_raw(text)
        .ok()
        .and_then(|v| u8::try_from(v).ok())
        .and_then(Rtim::new)
        .ok_or_else(|| format!("RTIM `{text}` is not 3-255 ms"))
}

fn strip_0x(text: &str) -> Option<&str> {
    text.strip_prefix("0x").or_else(|| text.strip_prefix("0X"))
}

/// A value in hundredths (0.01 mm, 0.01 mm/s, 0.01 G) as a JSON number: 5680 -> 56.8.
///
/// `h / 100` is correctly rounded, so the number printed is exactly the decimal.
pub fn decimal(hundredths: impl Into<f64>) -> Value {
    Value::from(hundredths.into() / 100.0)
}

/// A 32-bit word as 8 upper-case hex digits, as the frame carries it.
pub fn hex8(value: u32) -> String {
    format!("{value:08X}")
}

/// The end of the stroke an axis homes to (`o` command; it also sets the sign of positions).
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Home {
    /// Toward the motor (code 07); positions are written complemented.
    #[value(alias = "motor-end")]
    Motor,
    /// Away from the motor (code 08).
    #[value(alias = "non-motor-end")]
    NonMotor,
}

impl From<Home> for HomeDirection {
    fn from(home: Home) -> HomeDirection {
        match home {
            Home::Motor => HomeDirection::MotorEnd,
            Home::NonMotor => HomeDirection::NonMotorEnd,
        }
    }
}

/// How to convert between millimetres and pulses for one axis.
#[derive(Args, Clone, Debug)]
pub struct ScaleArgs {
    /// Screw lead in mm (e.g. 2.5)
    #[arg(long, value_parser = parse_lead, allow_negative_numbers = true)]
    pub lead: Option<Lead>,
    /// The end the axis homes to, which sets the sign of positions
    #[arg(long, value_enum)]
    pub home: Option<Home>,
    /// Negate motor-end positions exactly (-pulses) instead of FFFFFFFF - pulses (the rule)
    #[arg(long)]
    pub twos: bool,
    /// Encoder pulses per motor revolution
    #[arg(long, default_value_t = DEFAULT_PULSES_PER_REV)]
    pub ppr: std::num::NonZeroU16,
}

impl ScaleArgs {
    /// The scale for positions, when both the lead and the home end are given.
    pub fn position(&self) -> Option<Scale> {
        let (lead, home) = (self.lead?, self.home?);
        Some(self.with(lead, home.into()))
    }

    /// The scale for positions, or why there is none.
    pub fn require_position(&self) -> Result<Scale, String> {
        self.position()
            .ok_or_else(|| "a value in mm needs --lead and --home".to_owned())
    }

    /// The scale for velocity and acceleration, which only need the lead.
    pub fn velocity(&self) -> Option<Scale> {
        self.lead
            .map(|lead| self.with(lead, HomeDirection::MotorEnd))
    }

    fn with(&self, lead: Lead, home: HomeDirection) -> Scale {
        Scale {
            lead,
            pulses_per_rev: self.ppr,
            home,
            complement: if self.twos {
                Complement::Twos
            } else {
                Complement::Ones
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimals_are_exact() {
        assert_eq!(hundredths("56.8"), Ok(5680));
        assert_eq!(hundredths("0.2"), Ok(20));
        assert_eq!(hundredths("-100"), Ok(-10000));
        assert_eq!(hundredths("+.5"), Ok(50));
        assert_eq!(hundredths("32.45"), Ok(3245));
        assert!(hundredths("56.801").is_err());
        for bad in ["", ".", "-", "1.2.3", "1e3", "0x10", " 1", "1,5"] {
            assert!(hundredths(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn decimal_prints_the_hundredths() {
        assert_eq!(decimal(89672).to_string(), "896.72");
        assert_eq!(decimal(-5680).to_string(), "-56.8");
    }

    #[test]
    fn raw_numbers() {
        assert_eq!(parse_pulses("-8000"), Ok(Pulses(-8000)));
        assert_eq!(parse_pulses("0xFFFFE0C0"), Ok(Pulses(-8000)));
        assert_eq!(parse_hex_u32("7400"), Ok(0x7400));
        assert!(parse_hex_u32("123456789").is_err());
        assert_eq!(parse_axis("C").map(u8::from), Ok(12));
        assert_eq!(parse_axis("12").map(u8::from), Ok(12));
        assert!(parse_axis("G").is_err());
        assert!(parse_axis("16").is_err());
    }
}
