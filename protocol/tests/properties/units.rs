//! (g) The unit conversions round-trip within their resolution and never panic.

use std::num::NonZeroU16;

use proptest::prelude::*;
use proptest::sample::select;
use protocol::units::{Accel, Complement, Lead, Length, Scale, Speed};
use protocol::*;

use crate::strategies::{acceleration, home_direction, velocity};

// ---------------------------------------------------------------- (g): units

fn scale() -> impl Strategy<Value = Scale> {
    (
        1u16..=5000,
        select(vec![400u16, 800, 1600]),
        home_direction(),
        prop_oneof![Just(Complement::Ones), Just(Complement::Twos)],
    )
        .prop_map(|(lead, pulses_per_rev, home, complement)| Scale {
            lead: Lead::from_hundredths(lead).unwrap(),
            pulses_per_rev: NonZeroU16::new(pulses_per_rev).unwrap(),
            home,
            complement,
        })
}

/// Any scale a caller can build: any lead, any pulses/rev (neither can be 0: their types say
/// so, and every conversion divides by one of them).
fn any_scale() -> impl Strategy<Value = Scale> {
    (
        1u16..,
        1u16..,
        home_direction(),
        prop_oneof![Just(Complement::Ones), Just(Complement::Twos)],
    )
        .prop_map(|(lead, pulses_per_rev, home, complement)| Scale {
            lead: Lead::from_hundredths(lead).unwrap(),
            pulses_per_rev: NonZeroU16::new(pulses_per_rev).unwrap(),
            home,
            complement,
        })
}

/// `n / d` rounded up, for positive `n` and `d`.
fn ceil_div(n: i64, d: i64) -> i64 {
    (n + d - 1) / d
}

/// Lengths within ±10 m, in 0.01 mm.
const LENGTH_RANGE: core::ops::RangeInclusive<i32> = -1_000_000..=1_000_000;

/// Check that `back`, the round trip of `x` through a unit of `num / den` hundredths (one
/// pulse: lead / ppr; one velocity unit: lead / 300; one acceleration unit:
/// 100 lead / 588399), is as close as the conversions allow.
///
/// Toward the controller the value is truncated toward zero: x = (k + f) units with
/// 0 <= f < 1 (in magnitude). Back from the controller, k units are rounded to the nearest
/// hundredth, halves away from zero. So:
/// - `back` never overshoots: |back| <= |x|, with the sign of x (or 0), because rounding is
///   monotonic and x is already a whole number of hundredths;
/// - it undershoots by less than one unit plus half a hundredth:
///   |x| - |back| < num/den + 1/2, i.e. 2 den (|x| - |back|) < 2 num + den;
/// - hence, both sides being integers, |x| - |back| <= ceil(num / den): "within one unit,
///   rounded up".
fn check_round_trip(x: i64, back: i64, num: i64, den: i64) -> Result<(), TestCaseError> {
    prop_assert!(
        back == 0 || back.signum() == x.signum(),
        "{} came back as {}: sign changed",
        x,
        back
    );
    prop_assert!(
        back.abs() <= x.abs(),
        "{} came back as {}: overshoot",
        x,
        back
    );
    let error = x.abs() - back.abs();
    prop_assert!(
        error <= ceil_div(num, den),
        "{} came back as {}: error {} > ceil({}/{})",
        x,
        back,
        error,
        num,
        den
    );
    prop_assert!(
        2 * den * error < 2 * num + den,
        "{} came back as {}: error {} >= {}/{} + 1/2",
        x,
        back,
        error,
        num,
        den
    );
    Ok(())
}

/// Magnitude in pulses of `x`, truncated, as the controller is sent it.
fn magnitude(scale: &Scale, x: i32) -> i64 {
    i64::from(x).abs() * i64::from(scale.pulses_per_rev.get()) / i64::from(scale.lead.hundredths())
}

fn with_home(scale: Scale, home: HomeDirection) -> Scale {
    Scale { home, ..scale }
}

proptest! {
    /// (g) Positions round-trip within one pulse; positions that fit are accepted; the wire
    /// value moves with the position (toward larger pulses away from a non-motor-end home).
    #[test]
    fn position_round_trips_within_one_pulse(
        scale in scale(),
        x in LENGTH_RANGE,
        y in LENGTH_RANGE,
    ) {
        let wire = scale.position_to_wire(Length(x));
        if magnitude(&scale, x) < 0x3FFF_FFFF {
            prop_assert!(wire.is_ok(), "{:?} of {:?}", wire, x);
        }
        if let Ok(wire) = wire {
            let back = scale.position_from_wire(wire);
            check_round_trip(
                x.into(),
                back.0.into(),
                scale.lead.hundredths().into(),
                scale.pulses_per_rev.get().into(),
            )?;
            if let Ok(other) = scale.position_to_wire(Length(y)) {
                let ordered = match scale.home {
                    HomeDirection::NonMotorEnd => (x <= y) == (wire.0 <= other.0) || wire == other,
                    HomeDirection::MotorEnd => (x <= y) == (wire.0 >= other.0) || wire == other,
                };
                prop_assert!(ordered, "{:?} -> {:?}, {:?} -> {:?}", x, wire, y, other);
            }
        }
    }

    /// (g) A motor-end home mirrors the non-motor-end coordinates with the chosen complement:
    /// FFFFFFFF - pulses (bitwise not) for `Ones`, -pulses for `Twos`; positions and distances.
    #[test]
    fn motor_end_is_the_complement_of_non_motor_end(scale in scale(), x in LENGTH_RANGE) {
        let mirror = |w: Pulses| match scale.complement {
            Complement::Ones => Pulses(!w.0),
            Complement::Twos => Pulses(w.0.wrapping_neg()),
        };
        let motor = with_home(scale, HomeDirection::MotorEnd);
        let non_motor = with_home(scale, HomeDirection::NonMotorEnd);
        if let (Ok(m), Ok(n)) = (motor.position_to_wire(Length(x)), non_motor.position_to_wire(Length(x))) {
            prop_assert_eq!(m, mirror(n), "position {:?}", x);
            // Non-motor-end coordinates are the pulses themselves.
            prop_assert_eq!(i64::from(n.0), i64::from(x.signum()) * magnitude(&scale, x));
        }
        // A distance: + moves away from home, so a motor-end home mirrors it, except that 0
        // stays 0 (there is no direction to complement).
        if let (Ok(m), Ok(n)) = (motor.distance_to_wire(Length(x)), non_motor.distance_to_wire(Length(x))) {
            if n == Pulses(0) {
                prop_assert_eq!(m, Pulses(0));
            } else if x > 0 {
                prop_assert_eq!(m, mirror(n), "distance {:?}", x);
            } else {
                prop_assert_eq!(n, mirror(m), "distance {:?}", x);
            }
        }
    }

    /// (g) Distances round-trip within one pulse, keep their sign (or become 0), and point
    /// away from home for positive distances.
    #[test]
    fn distance_round_trips_within_one_pulse(scale in scale(), x in LENGTH_RANGE) {
        let magnitude = magnitude(&scale, x);
        let wire = scale.distance_to_wire(Length(x));
        if magnitude < 0x3FFF_FFFF {
            prop_assert!(wire.is_ok(), "{:?} of {:?}", wire, x);
        }
        if let Ok(wire) = wire {
            let back = scale.distance_from_wire(wire);
            check_round_trip(
                x.into(),
                back.0.into(),
                scale.lead.hundredths().into(),
                scale.pulses_per_rev.get().into(),
            )?;
            // Away from home is + for a non-motor-end home, - for a motor-end home.
            if magnitude != 0 {
                let away = (x > 0) == (scale.home == HomeDirection::NonMotorEnd);
                prop_assert_eq!(wire.0 > 0, away, "{:?} -> {:?}", x, wire);
            } else {
                prop_assert_eq!(wire, Pulses(0));
            }
        }
    }

    /// (g) Speeds round-trip within one velocity unit, lead / 300 hundredths of mm/s (see
    /// [`check_round_trip`]).
    #[test]
    fn speed_round_trips_within_one_velocity_unit(scale in scale(), s in 0u32..=400_000) {
        let lead = i64::from(scale.lead.hundredths());
        let units = i64::from(s) * 300 / lead;
        let velocity = scale.velocity(Speed(s));
        prop_assert_eq!(velocity.is_ok(), units <= 0x57E4, "{:?} of {:?}", velocity, s);
        if let Ok(velocity) = velocity {
            prop_assert_eq!(i64::from(velocity.get()), units);
            let back = scale.speed(velocity);
            check_round_trip(s.into(), back.0.into(), lead, 300)?;
        }
    }

    /// (g) Accelerations round-trip within one acceleration unit, 100 lead / 588399
    /// hundredths of G (see [`check_round_trip`]).
    #[test]
    fn accel_round_trips_within_one_acceleration_unit(scale in scale(), a in 0u32..=2_000) {
        let lead = i64::from(scale.lead.hundredths());
        let units = i64::from(a) * 588_399 / (100 * lead);
        let acceleration = scale.acceleration(Accel(a));
        prop_assert_eq!(acceleration.is_ok(), (1..=0x7FF).contains(&units));
        if let Ok(acceleration) = acceleration {
            prop_assert_eq!(i64::from(acceleration.get()), units);
            let back = scale.accel(acceleration);
            check_round_trip(a.into(), back.0.into(), 100 * lead, 588_399)?;
        }
    }

    /// (g) No conversion panics, whatever the scale (pulses/rev 0 included) and the value.
    #[test]
    fn units_never_panic(
        scale in any_scale(),
        length in any::<i32>(),
        wire in any::<i32>(),
        speed in any::<u32>(),
        accel in any::<u32>(),
        velocity in velocity(),
        acceleration in acceleration(),
        percent in any::<u8>(),
    ) {
        let _ = scale.pulses(Length(length));
        let _ = scale.length(i64::from(wire));
        let _ = scale.position_to_wire(Length(length));
        let _ = scale.position_from_wire(Pulses(wire));
        let _ = scale.distance_to_wire(Length(length));
        let _ = scale.distance_from_wire(Pulses(wire));
        let _ = scale.band_to_wire(Length(length));
        let _ = scale.velocity(Speed(speed));
        let _ = scale.speed(velocity);
        let _ = scale.acceleration(Accel(accel));
        let _ = scale.accel(acceleration);
        let _ = scale.push_data(percent);
    }

    /// (g) `Scale::length` is public and takes any i64 pulse count: it must not panic either.
    /// (`div_round` computed `2 * n`, which overflows for |n| > i64::MAX / 2.)
    #[test]
    fn length_of_any_pulse_count_never_panics(scale in any_scale(), pulses in any::<i64>()) {
        let _ = scale.length(pulses);
    }
}

/// The extremes of `Scale::length`, which `length_of_any_pulse_count_never_panics` may miss:
/// a pulse count beyond i32 saturates the length instead of overflowing in the rounding.
#[test]
fn length_of_extreme_pulse_counts_saturates() {
    let scale = Scale {
        lead: Lead::from_hundredths(1).unwrap(),
        pulses_per_rev: NonZeroU16::MIN,
        home: HomeDirection::NonMotorEnd,
        complement: Complement::Ones,
    };
    assert_eq!(scale.length(i64::MAX), Length(i32::MAX));
    assert_eq!(scale.length(i64::MIN), Length(i32::MIN));
    assert_eq!(scale.length(i64::MAX / 2), Length(i32::MAX));
    assert_eq!(scale.length(-(i64::MAX / 2)), Length(i32::MIN));
}
