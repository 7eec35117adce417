//! Pattern 1's PWRT: the axis' present position stored into a point, as every table write is.
//!
//! Three jobs, one after the other: the position is read (R4 PNOW: after a jog stopped by `d`
//! the last position the gateway polled may be from before the axis came to rest), then the
//! point's row (Q1 + R4: its speed, acceleration and band are kept; its flags are written as
//! every table write writes them, `table::point`), then the row with the new
//! position is stored with [`JobKind::StorePoint`]: compared with what the controller holds, V5
//! only if it differs, read back and verified. CMST follows the three as one command.
//!
//! A position just outside the stroke (an axis homed to 0 mm and jogged against the stop) is
//! stored as the stroke's end it is nearest: the controller clamps targets to its soft limits.
//! A point that held nothing (speed 0) gets the jog speed (PIOJOG), 0.30 G and a band of
//! 0.10 mm: PCON's default acceleration and positioning band (its parameters No. 9 and No. 10,
//! as the PCON manual gives their factory values).

use super::command::Reason;
use super::config::{AxisConfig, PIO_ACCEL};
use super::registers::split;
use super::table;
use crate::engine::{Engine, Job, JobError, JobId, JobKind, JobOutput};
use crate::memory::{PointField, PNOW};
use crate::{Axis, Command, PositionNo, Pulses};

/// The band a point that held nothing gets: 0.10 mm (0.01 mm).
const DEFAULT_BAND: u32 = 10;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// Reading the position.
    Position,
    /// Reading the row, with the position read (0.01 mm).
    Row(i32),
    /// Storing the row.
    Store,
}

/// A PWRT under way.
#[derive(Clone, Copy, Debug)]
struct Write {
    axis: Axis,
    point: PositionNo,
    id: JobId,
    phase: Phase,
}

/// What a job of a PWRT led to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Step {
    /// The next job runs (CMST follows it).
    Next(JobId),
    /// The PWRT ended: stored (`Ok`), or failed with this CMER.
    Ended(Axis, PositionNo, Result<(), u16>),
}

/// At most one PWRT at a time (the PIO drives one axis).
#[derive(Clone, Copy, Debug)]
pub(super) struct Teach {
    write: Option<Write>,
}

impl Teach {
    pub(super) const fn new() -> Teach {
        Teach { write: None }
    }

    /// Start storing the position of `axis` into `point`: the first job's id. A PWRT while
    /// another runs is refused (the queue is taken).
    pub(super) fn start(
        &mut self,
        axis: Axis,
        point: PositionNo,
        engine: &mut Engine,
    ) -> Result<JobId, Reason> {
        if self.write.is_some() {
            return Err(Reason::QueueFull);
        }
        let read = JobKind::Command(Command::ReadMemory { address: PNOW });
        let id = submit(engine, axis, read)?;
        self.write = Some(Write {
            axis,
            point,
            id,
            phase: Phase::Position,
        });
        Ok(id)
    }

    /// A job ended: what it means for the PWRT under way, if it is one of its jobs.
    pub(super) fn job_done(
        &mut self,
        id: JobId,
        result: &Result<JobOutput, JobError>,
        config: &AxisConfig,
        jog_speed: u16,
        engine: &mut Engine,
    ) -> Option<Step> {
        let write = self.write.filter(|w| w.id == id)?;
        let (axis, point) = (write.axis, write.point);
        let next = match (write.phase, result) {
            (Phase::Position, Ok(JobOutput::Value(v))) => {
                let at = config.scale.position_from_wire(Pulses::from_wire(*v)).0;
                let at = at.clamp(0, config.stroke.0);
                Ok((Phase::Row(at), JobKind::ReadPoint(point)))
            }
            (Phase::Row(at), Ok(JobOutput::Point(readback))) => {
                // The row's registers (table::registers' layout), the position replaced.
                let mut row = table::registers(readback, config);
                let mut set = |i: usize, value: u16| {
                    if let Some(r) = row.get_mut(i) {
                        *r = value;
                    }
                };
                let [p0, p1] = split(u32::try_from(at).unwrap_or(0));
                set(0, p0);
                set(1, p1);
                if readback.get(PointField::Velocity) == 0 {
                    // Nothing there: the jog speed, PCON's default acceleration and band.
                    let [b0, b1] = split(DEFAULT_BAND);
                    let [v0, v1] = split(u32::from(jog_speed));
                    for (i, value) in [(2, b0), (3, b1), (4, v0), (5, v1)] {
                        set(i, value);
                    }
                    set(10, PIO_ACCEL);
                    set(11, PIO_ACCEL);
                }
                table::point(&row, config)
                    .map(|data| (Phase::Store, JobKind::StorePoint { point, data }))
                    .map_err(|_| Reason::Unexpected.code(0))
            }
            (Phase::Store, Ok(_)) => {
                self.write = None;
                return Some(Step::Ended(axis, point, Ok(())));
            }
            (_, Err(e)) => Err(Reason::of(*e)),
            (_, Ok(_)) => Err(Reason::Unexpected.code(0)),
        };
        let step = next.and_then(|(phase, kind)| {
            let id = submit(engine, axis, kind).map_err(|r| r.code(0))?;
            self.write = Some(Write { id, phase, ..write });
            Ok(id)
        });
        Some(match step {
            Ok(id) => Step::Next(id),
            Err(cmer) => {
                self.write = None;
                Step::Ended(axis, point, Err(cmer))
            }
        })
    }
}

fn submit(engine: &mut Engine, axis: Axis, kind: JobKind) -> Result<JobId, Reason> {
    engine
        .submit(Job { axis, kind })
        .map_err(|_| Reason::QueueFull)
}
