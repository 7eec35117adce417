//! The seeded PLC workload that keeps every axis busy.

use protocol::engine::point_jobs::PointData;
use protocol::engine::JobKind;
use protocol::memory::PointField;
use protocol::{Acceleration, Axis, HomeDirection, PositionNo, Pulses, Velocity};

use crate::driver::Soak;
use crate::job_records::relative_distance;
use crate::{axis, MS};

/// The PLC's view of one axis.
#[derive(Default)]
pub(crate) struct Plc {
    pub(crate) homed: bool,
    next_at: u64,
    /// Points it believes hold data (a WritePoint or WriteField succeeded).
    pub(crate) written: u16,
    /// An alarm reset (and the servo-on after it) is outstanding.
    pub(crate) resetting: bool,
}

impl Soak {
    /// The PLC: every millisecond, each idle axis may get new work.
    pub(crate) fn plc(&mut self) {
        let now = self.now();
        while let Some(k) = self.stop_at.iter().position(|&(t, _)| t <= now) {
            let (_, a) = self.stop_at.swap_remove(k);
            if self.submitting {
                self.submit(a, JobKind::Stop);
            }
        }
        if !self.submitting || now < self.plc_check_at {
            return;
        }
        self.plc_check_at = now + MS;
        for n in 0..16 {
            if self.fifo[n].len() > 1 || now < self.plc[n].next_at {
                continue;
            }
            self.plc_act(axis(n));
        }
    }

    fn plc_act(&mut self, a: Axis) {
        let n = usize::from(a.get());
        let now = self.now();
        let think = self.rng.below(100 * MS);
        self.plc[n].next_at = now + think;
        let report = self.h.engine.axis(a).report;
        if !self.plc[n].homed {
            if self.fifo[n].is_empty() {
                self.submit(a, JobKind::Home(HomeDirection::MotorEnd));
            }
            return;
        }
        if report.is_some_and(|r| r.outputs.alarm_active()) {
            if !self.plc[n].resetting && self.fifo[n].is_empty() {
                self.plc[n].resetting = true;
                self.submit(a, JobKind::AlarmReset);
                self.submit(a, JobKind::Servo(true));
            }
            return;
        }
        let roll = self.rng.below(100);
        let position = self.h.engine.axis(a).position.map_or(-5_000, |p| p.0);
        match roll {
            0..=34 => {
                // Relative moves, often two or three in a row.
                let count = 1 + self.rng.below(3);
                let mut target = i64::from(position);
                for _ in 0..count {
                    let magnitude = 100 + self.rng.below(3_000) as i64;
                    let up = target + magnitude <= -200;
                    let down = target - magnitude >= -9_800;
                    let mut d = match (up, down) {
                        (true, true) if self.rng.chance(0.5) => magnitude,
                        (true, _) => magnitude,
                        (false, true) => -magnitude,
                        (false, false) if target < -5_000 => 100,
                        (false, false) => -100,
                    };
                    // Distinct from every outstanding `m` of the axis, so that a transmission
                    // names its job.
                    let taken = |soak: &Soak, d: i64| {
                        let d = Some(Pulses(i32::try_from(d).unwrap()));
                        soak.fifo[n]
                            .iter()
                            .any(|&id| relative_distance(&soak.jobs[id as usize].kind) == d)
                    };
                    while taken(self, d) {
                        d += 1;
                    }
                    target += d;
                    let d = Pulses(i32::try_from(d).unwrap());
                    if self.rng.chance(0.2) {
                        // IAI's direct numeric move: v2 then m.
                        let (velocity, acceleration) = self.random_motion();
                        self.submit(
                            a,
                            JobKind::DirectMove {
                                target: d,
                                relative: true,
                                velocity,
                                acceleration,
                            },
                        );
                    } else {
                        self.submit(a, JobKind::MoveRelative(d));
                    }
                }
                self.maybe_stop_soon(a);
            }
            35..=49 => {
                let x = Pulses(-(500 + self.rng.below(9_000) as i32));
                if self.rng.chance(0.3) {
                    let (velocity, acceleration) = self.random_motion();
                    self.submit(
                        a,
                        JobKind::DirectMove {
                            target: x,
                            relative: false,
                            velocity,
                            acceleration,
                        },
                    );
                } else {
                    self.submit(a, JobKind::MoveAbsolute(x));
                }
                self.maybe_stop_soon(a);
            }
            50..=57 => {
                let (velocity, acceleration) = self.random_motion();
                self.submit(
                    a,
                    JobKind::SetMotion {
                        velocity,
                        acceleration,
                    },
                );
            }
            58..=62 => {
                self.submit(a, JobKind::Servo(false));
                self.submit(a, JobKind::Servo(true));
            }
            63..=70 => {
                let point = PositionNo::new(1 + self.rng.below(15) as u8).unwrap();
                let data = PointData {
                    position: Pulses(-(500 + self.rng.below(9_000) as i32)),
                    velocity: Velocity::new(1_500 + self.rng.below(4_500) as u16).unwrap(),
                    acceleration: Acceleration::new(50 + self.rng.below(350) as u16).unwrap(),
                    flags: PointData::FLAGS_MOTION_AND_BAND,
                    band: 5 + self.rng.below(50) as u32,
                    max_acceleration: 0,
                };
                self.submit(
                    a,
                    JobKind::WritePoint {
                        point,
                        data,
                        verify: true,
                    },
                );
                self.submit(a, JobKind::MoveToPoint(point, None));
            }
            71..=75 => {
                let written = self.plc[n].written;
                if written != 0 {
                    let mut p = 1 + self.rng.below(15) as u8;
                    while written & (1 << p) == 0 {
                        p = p % 15 + 1;
                    }
                    self.submit(a, JobKind::MoveToPoint(PositionNo::new(p).unwrap(), None));
                }
            }
            76..=81 => {
                let point = PositionNo::new(1 + self.rng.below(15) as u8).unwrap();
                self.submit(a, JobKind::ReadPoint(point));
            }
            82..=87 => {
                let point = PositionNo::new(1 + self.rng.below(15) as u8).unwrap();
                let (field, value) = match self.rng.below(4) {
                    0 => (
                        PointField::Position,
                        Pulses(-(500 + self.rng.below(9_000) as i32)).to_wire(),
                    ),
                    1 => (PointField::Velocity, 1_500 + self.rng.below(4_500) as u32),
                    2 => (PointField::Acceleration, 50 + self.rng.below(350) as u32),
                    _ => (PointField::Band, 5 + self.rng.below(50) as u32),
                };
                self.submit(
                    a,
                    JobKind::WriteField {
                        point,
                        field,
                        value,
                    },
                );
            }
            _ => {
                self.submit(a, JobKind::Stop);
            }
        }
    }

    fn random_motion(&mut self) -> (Velocity, Acceleration) {
        let velocity = Velocity::new(1_500 + self.rng.below(4_500) as u16).unwrap();
        let acceleration = Acceleration::new(50 + self.rng.below(350) as u16).unwrap();
        (velocity, acceleration)
    }

    /// Sometimes stop a move just after submitting it, often while its frame is on the wire.
    fn maybe_stop_soon(&mut self, a: Axis) {
        if self.rng.chance(0.15) {
            let at = self.now() + self.rng.below(30 * MS);
            self.stop_at.push((at, a));
        }
    }
}
