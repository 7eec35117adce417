//! Trapezoidal motion profiles in virtual time.
//!
//! Units (complete edition §7-2-2, §8-2; 800 encoder pulses per motor revolution):
//! - velocity VCMD in 0.2 rpm: 1 unit = 0.2 x 800 / 60_000 pulses/ms, so pulses/ms = VCMD / 375;
//! - acceleration ACMD in 0.1 rpm/ms: 1 unit = 0.1 x 800 / 60_000 pulses/ms², so
//!   pulses/ms² = ACMD / 750. Deceleration uses the same value (MXAC = 0, §7-2-1).
//!
//! A move from rest over a distance `d` at velocity `v` and acceleration `a` takes
//! `d / v + v / a` when `d >= v² / a` (trapezoid), else `2 sqrt(d / a)` (triangle):
//! [`Limits::move_time_ms`].
//!
//! Motion parameters may change "on the fly" (complete edition §6-3): a profile is planned from
//! the present position *and velocity*. If the axis cannot stop before the new target, or moves
//! away from it, it first decelerates to rest (overshooting), then approaches the target; the
//! approach is monotonic, so the instant PFIN turns on (the axis enters the position band) is
//! well defined ([`Profile::in_band_at`]).
//!
//! Internally positions are `f64` pulses and durations `f64` milliseconds; the controller reports
//! positions rounded to whole pulses.

use super::wire::US_PER_MS;

/// Pulses per ms per VCMD unit is 1/375.
const VELOCITY_UNITS_PER_PULSE_PER_MS: f64 = 375.0;
/// Pulses per ms² per ACMD unit is 1/750.
const ACCELERATION_UNITS_PER_PULSE_PER_MS2: f64 = 750.0;

/// Velocity and acceleration limits of a move, in pulses/ms and pulses/ms².
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    /// Maximum velocity, pulses/ms (> 0).
    pub velocity: f64,
    /// Acceleration and deceleration, pulses/ms² (> 0).
    pub acceleration: f64,
}

impl Limits {
    /// From VCMD (0.2 rpm) and ACMD (0.1 rpm/ms). Zero values are raised to 1 unit so that a
    /// move always ends (a real controller rejects them when they are written, §7-2-2).
    pub fn from_units(vcmd: u32, acmd: u32) -> Limits {
        Limits {
            velocity: f64::from(vcmd.max(1)) / VELOCITY_UNITS_PER_PULSE_PER_MS,
            acceleration: f64::from(acmd.max(1)) / ACCELERATION_UNITS_PER_PULSE_PER_MS2,
        }
    }

    /// The textbook move time from rest to rest over `distance` pulses, in ms.
    pub fn move_time_ms(&self, distance: f64) -> f64 {
        let (v, a) = (self.velocity, self.acceleration);
        let d = distance.abs();
        if d >= v * v / a {
            d / v + v / a
        } else {
            2.0 * (d / a).sqrt()
        }
    }

    /// A velocity in pulses/ms as VNOW units (0.2 rpm), rounded.
    pub fn velocity_units(pulses_per_ms: f64) -> i64 {
        (pulses_per_ms * VELOCITY_UNITS_PER_PULSE_PER_MS).round() as i64
    }
}

/// A phase of constant acceleration.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Segment {
    /// Duration, ms.
    duration: f64,
    /// Signed acceleration, pulses/ms².
    accel: f64,
}

/// A planned move: where the axis is at any time from `start` on.
#[derive(Clone, Debug, PartialEq)]
pub struct Profile {
    start: u64,
    x0: f64,
    v0: f64,
    segments: Vec<Segment>,
    /// Index of the first segment of the monotonic approach to the target.
    approach: usize,
    target: i64,
    end: u64,
    in_band_at: u64,
}

fn ms_to_us(ms: f64) -> u64 {
    if ms.is_finite() && ms > 0.0 {
        (ms * US_PER_MS as f64).ceil() as u64
    } else {
        0
    }
}

impl Profile {
    /// Plan a move that starts at `start` (µs) from position `x0` with velocity `v0` (pulses,
    /// pulses/ms, signed) and ends at rest on `target`. `band` is the position band (INP) in
    /// pulses: PFIN turns on when the approach comes within it.
    pub fn plan(start: u64, x0: f64, v0: f64, target: i64, limits: Limits, band: u64) -> Profile {
        let a = limits.acceleration.max(f64::MIN_POSITIVE);
        let vmax = limits.velocity.max(f64::MIN_POSITIVE);
        let xt = target as f64;
        let mut segments = Vec::new();
        let (mut x, mut v) = (x0, v0);

        // Moving away from the target, or unable to stop before it: come to rest first.
        let d = xt - x;
        if v != 0.0 && (v * d < 0.0 || v * v / (2.0 * a) > d.abs()) {
            let t = v.abs() / a;
            segments.push(Segment {
                duration: t,
                accel: -v.signum() * a,
            });
            x += v * t / 2.0;
            v = 0.0;
        }
        let approach = segments.len();

        let d = xt - x;
        let s = if d != 0.0 { d.signum() } else { v.signum() };
        let distance = d.abs();
        let u = v.abs();
        if u > vmax {
            // Slow down to the new velocity, cruise, stop; if that overruns, only stop.
            let t1 = (u - vmax) / a;
            let d1 = (u + vmax) / 2.0 * t1;
            let d3 = vmax * vmax / (2.0 * a);
            if d1 + d3 <= distance {
                segments.push(Segment {
                    duration: t1,
                    accel: -s * a,
                });
                segments.push(Segment {
                    duration: (distance - d1 - d3) / vmax,
                    accel: 0.0,
                });
                segments.push(Segment {
                    duration: vmax / a,
                    accel: -s * a,
                });
            } else {
                segments.push(Segment {
                    duration: u / a,
                    accel: -s * a,
                });
            }
        } else if distance > 0.0 || u > 0.0 {
            let peak = vmax.min((a * distance + u * u / 2.0).max(0.0).sqrt());
            let d1 = (peak * peak - u * u) / (2.0 * a);
            let d3 = peak * peak / (2.0 * a);
            segments.push(Segment {
                duration: ((peak - u) / a).max(0.0),
                accel: s * a,
            });
            segments.push(Segment {
                duration: ((distance - d1 - d3) / peak).max(0.0),
                accel: 0.0,
            });
            segments.push(Segment {
                duration: peak / a,
                accel: -s * a,
            });
        }
        segments.retain(|seg| seg.duration > 0.0);
        let approach = approach.min(segments.len());
        let total: f64 = segments.iter().map(|seg| seg.duration).sum();
        let mut profile = Profile {
            start,
            x0,
            v0,
            segments,
            approach,
            target,
            end: start.saturating_add(ms_to_us(total)),
            in_band_at: start,
        };
        profile.in_band_at = profile.find_band_entry(band as f64);
        profile
    }

    /// Position (pulses) and velocity (pulses/ms) at `t` (µs). Before `start` the start state,
    /// after [`end`](Self::end) the target at rest.
    pub fn state(&self, t: u64) -> (f64, f64) {
        if t >= self.end {
            return (self.target as f64, 0.0);
        }
        let mut tau = t.saturating_sub(self.start) as f64 / US_PER_MS as f64;
        let (mut x, mut v) = (self.x0, self.v0);
        for seg in &self.segments {
            let dt = tau.min(seg.duration);
            x += v * dt + 0.5 * seg.accel * dt * dt;
            v += seg.accel * dt;
            tau -= dt;
            if tau <= 0.0 {
                break;
            }
        }
        (x, v)
    }

    /// The earliest time of the approach at which the axis is within `band` of the target.
    fn find_band_entry(&self, band: f64) -> u64 {
        let skipped: f64 = self
            .segments
            .iter()
            .take(self.approach)
            .map(|seg| seg.duration)
            .sum();
        let mut lo = self.start.saturating_add(ms_to_us(skipped)).min(self.end);
        let mut hi = self.end;
        let inside = |t: u64| (self.target as f64 - self.state(t).0).abs() <= band;
        if inside(lo) {
            return lo;
        }
        // The approach is monotonic: bisect for the first microsecond inside the band.
        while hi - lo > 1 {
            let mid = lo + (hi - lo) / 2;
            if inside(mid) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        hi
    }

    /// When the move started (µs).
    pub fn start(&self) -> u64 {
        self.start
    }

    /// When the axis comes to rest on the target (µs).
    pub fn end(&self) -> u64 {
        self.end
    }

    /// When the axis enters the position band of the target for good (µs): PFIN turns on.
    pub fn in_band_at(&self) -> u64 {
        self.in_band_at
    }

    /// The target (pulses).
    pub fn target(&self) -> i64 {
        self.target
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> Limits {
        // 100 mm/s and 0.3 G with an 8 mm lead.
        Limits::from_units(3750, 220)
    }

    #[test]
    fn trapezoid_matches_the_formula() {
        let p = Profile::plan(0, 0.0, 0.0, -800, limits(), 10);
        let expected = limits().move_time_ms(800.0);
        assert!((p.end() as f64 / 1000.0 - expected).abs() < 0.01);
        assert_eq!(p.state(p.end()).0, -800.0);
        let (x, v) = p.state(p.end() / 2);
        assert!((x + 400.0).abs() < 0.5, "{x}");
        assert!((v + 10.0).abs() < 1e-6, "{v}");
        assert!(p.in_band_at() < p.end());
    }

    #[test]
    fn triangle_for_short_moves() {
        let p = Profile::plan(1_000, 0.0, 0.0, 100, limits(), 0);
        let expected = limits().move_time_ms(100.0);
        assert!(((p.end() - 1_000) as f64 / 1000.0 - expected).abs() < 0.01);
        assert_eq!(p.in_band_at(), p.end());
    }

    #[test]
    fn reversal_overshoots_then_returns() {
        // Moving at +10 pulses/ms, new target behind.
        let p = Profile::plan(0, 0.0, 10.0, -100, limits(), 5);
        let stop = 10.0 / limits().acceleration;
        let (x, v) = p.state((stop * 1000.0) as u64);
        assert!(x > 100.0 && v.abs() < 0.01, "{x} {v}");
        assert_eq!(p.state(p.end()).0, -100.0);
        assert!(p.in_band_at() > (stop * 1000.0) as u64);
    }

    #[test]
    fn zero_move_is_immediately_in_band() {
        let p = Profile::plan(5, 3.0, 0.0, 3, limits(), 0);
        assert_eq!((p.end(), p.in_band_at()), (5, 5));
    }
}
