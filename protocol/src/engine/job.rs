//! Jobs: what the PLC side asks for, as programs of frames and waits.
//!
//! A program is computed on demand from the job ([`program`]), so an active job is only its
//! description and a cursor: nothing is stored per step, nothing is allocated.

use crate::axes::AxisSet;
use crate::engine::point_jobs::{
    self as jobs, Expect, PointData, PointReadback, Step, READ_POINT_LEN, WRITE_POINT_LEN,
};
use crate::memory::PointField;
use crate::{
    Acceleration, AlarmCode, Axis, Command, HomeDirection, PositionNo, Pulses, Request, ResetKind,
    StatusReport, Velocity,
};

/// Identifies a submitted job in [`Event::JobDone`](super::Event::JobDone).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct JobId(pub u32);

/// What a move to a point goes by, from the point's row: where it ends, and how fast it gets
/// there.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PointAim {
    /// The point's position.
    pub position: Pulses,
    /// Its velocity and acceleration, if the row's own count (its flags), not the common
    /// defaults.
    pub motion: Option<(Velocity, Acceleration)>,
}

/// What to do with one axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum JobKind {
    /// Send one command and report its response.
    Command(Command),
    /// Servo on or off, then wait until the status shows it.
    Servo(bool),
    /// The homing procedure (complete edition §6-2): wait ready (PFIN), `o`, wait for ZFIN,
    /// then read the position (0), so that it is known when the job is done.
    Home(HomeDirection),
    /// Q3, then wait for positioning complete. With what the submitter knows of the point (the
    /// gateway's cached row): the Q3 does not say where the axis goes, and only a known target
    /// lets the schedule estimate the arrival.
    MoveToPoint(PositionNo, Option<PointAim>),
    /// `a`, then wait for positioning complete.
    MoveAbsolute(Pulses),
    /// `m`, then wait. Never resent on time-out: the outcome is then unknown (§5 (2)).
    MoveRelative(Pulses),
    /// `v2` then `a` (or `m` if `relative`), then wait: a move with its own velocity and
    /// acceleration as one job, so that a rejected `v` never lets the move run at a stale speed.
    DirectMove {
        /// Target position (or distance if `relative`).
        target: Pulses,
        /// `m` instead of `a`.
        relative: bool,
        /// Velocity.
        velocity: Velocity,
        /// Acceleration.
        acceleration: Acceleration,
    },
    /// Start a jog: `v2`, then `a` to the given stroke end; done when accepted (a jog ends when
    /// it is stopped, so its end is no outcome of its own). End it with [`JobKind::Stop`].
    Jog {
        /// The stroke end it runs toward.
        end: Pulses,
        /// Velocity.
        velocity: Velocity,
        /// Acceleration.
        acceleration: Acceleration,
    },
    /// `d`: cancel the remaining motion. Goes before every other frame and cancels the axis'
    /// running and queued jobs.
    Stop,
    /// Servo off, then `r03` (the document requires the servo off for an alarm reset, §4-4-16).
    AlarmReset,
    /// `v2`: velocity and acceleration of the execution area.
    SetMotion {
        /// Velocity.
        velocity: Velocity,
        /// Acceleration.
        acceleration: Acceleration,
    },
    /// Change one point-table field: Q1, T4, W4, V5.
    WriteField {
        /// Point.
        point: PositionNo,
        /// Field.
        field: PointField,
        /// Value.
        value: u32,
    },
    /// Write a whole point (14 frames), then read it back and compare if `verify`.
    WritePoint {
        /// Point.
        point: PositionNo,
        /// Data.
        data: PointData,
        /// Read back and compare after writing.
        verify: bool,
    },
    /// Read a point back (Q1 + R4 of every field).
    ReadPoint(PositionNo),
    /// Store a whole point only if the controller does not hold it already: read it back
    /// first, and if any field differs, write it (14 frames) and read it back to verify. V5
    /// wears the controller's non-volatile memory (about 100,000 writes per area), so it is never
    /// spent on data that is already there, whatever the gateway remembers.
    StorePoint {
        /// Point.
        point: PositionNo,
        /// Data.
        data: PointData,
    },
    /// Wait until the axis reports positioning complete (PFIN), then read its position: the end
    /// of a move started otherwise (by a synchronized start's `t`).
    AwaitInPosition,
    /// Synchronized start (complete edition §6-4): `t` to this job's axis, which every axis
    /// receives, then wait until each axis of the set reports its buffered bit clear. Buffer the
    /// commands first with [`JobKind::Command`]`(`[`Command::Buffer`]`)` on each axis. `t` is not
    /// resent on a time-out (§5 (3)); the polls tell which axes started.
    StartBuffered(AxisSet),
}

/// A job for an axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Job {
    /// The axis.
    pub axis: Axis,
    /// What to do.
    pub kind: JobKind,
}

/// What a finished job returns.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum JobOutput {
    /// Nothing beyond success.
    Done,
    /// The status the last response carried.
    Status(StatusReport),
    /// The 32-bit value of the last memory response (R4 data, V5 write count, ...).
    Value(u32),
    /// A point read back (after a write: the verified read-back).
    Point(PointReadback),
    /// [`JobKind::StorePoint`] found the point already stored: nothing was written.
    Unchanged(PointReadback),
}

/// Why a job failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum JobError {
    /// A frame got no valid response (none in time, or only corrupted ones) after every
    /// allowed retry.
    Timeout,
    /// An `m` got no response: it may or may not have moved. The position is re-read (before
    /// this is reported).
    OutcomeUnknown,
    /// The controller rejected a command with this warning code.
    Rejected(AlarmCode),
    /// The axis went into alarm (error code) while the job waited.
    Alarm(AlarmCode),
    /// A response did not confirm the step (wrong echoed address, wrong kind).
    Unexpected,
    /// A stop cancelled it, or its axis left the bus
    /// ([`Engine::reconfigure`](super::Engine::reconfigure)).
    Cancelled,
    /// The read-back differs from what was written.
    VerifyFailed,
    /// The awaited state did not come within the motion time-out.
    WaitTimeout,
    /// The axis does not answer (offline, or not heard from since start): the job was not run,
    /// or was given up when the axis went offline, so that it can never run late.
    Offline,
}

/// A state the job waits for, judged on status responses received after its last command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub(crate) enum Condition {
    /// PFIN on: ready to move (§6-2 step 1), or positioning complete (§6-3).
    InPosition,
    /// ZFIN and PFIN on: homing complete (§6-2 step 3).
    Homed,
    /// The servo bit equals this.
    Servo(bool),
    /// Every axis of the set reports no buffered command (judged by the engine across axes).
    Unbuffered(AxisSet),
}

impl Condition {
    /// Whether `report` satisfies the condition.
    pub(crate) fn met(self, report: &StatusReport) -> bool {
        match self {
            Condition::InPosition => report.outputs.pfin(),
            Condition::Homed => report.outputs.zfin() && report.outputs.pfin(),
            Condition::Servo(on) => report.status.servo() == on,
            Condition::Unbuffered(_) => !report.status.buffered(),
        }
    }
}

/// One operation of a program.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Op {
    /// Send a frame and check its response.
    Send(Step),
    /// Wait until a status satisfies the condition.
    Await(Condition),
}

impl JobError {
    /// Whether the axis may have moved somewhere the job did not mean: the answer to its move
    /// was lost, it went into alarm, or it did not arrive in time. A move or a home that fails
    /// so reads its position before the failure is reported, as a completed one does.
    pub(crate) fn position_unknown(self) -> bool {
        matches!(
            self,
            JobError::OutcomeUnknown | JobError::Alarm(_) | JobError::WaitTimeout
        )
    }
}

/// Whether op `index` of `job` is its read of the position ([`read_position`]).
pub(crate) fn reads_position(job: &Job, index: usize) -> bool {
    matches!(
        program(job, index),
        Some(Op::Send(step)) if matches!(
            step.request.command,
            Command::ReadMemory { address } if address == crate::memory::PNOW
        )
    )
}

/// The last op of every move and of homing: read where it stopped, so that the job finishes
/// with the final position already known (a PLC reads PNOW when PEND comes on), and so does a
/// move that fails with the position unknown ([`JobError::position_unknown`]).
fn read_position(axis: Axis) -> Op {
    Op::Send(Step {
        request: Request::new(
            axis,
            Command::ReadMemory {
                address: crate::memory::PNOW,
            },
        ),
        expect: Expect::Data,
    })
}

/// A direct command whose status response must not be a rejection.
fn send(axis: Axis, command: Command) -> Op {
    Op::Send(Step {
        request: Request::new(axis, command),
        expect: Expect::Accepted,
    })
}

/// The `index`-th operation of `job`'s program, or `None` past its end.
///
/// Matched on the job and the index together: only the op asked for is built (an array of a
/// program's ops, indexed, built all of them each time, in more code).
pub(crate) fn program(job: &Job, index: usize) -> Option<Op> {
    let axis = job.axis;
    let send = |command| Some(send(axis, command));
    Some(match (job.kind, index) {
        (JobKind::Command(command), 0) => Op::Send(Step {
            request: Request::new(axis, command),
            expect: Expect::Reply,
        }),
        (JobKind::Servo(on), 0) => return send(Command::Servo(on)),
        (JobKind::Servo(on), 1) => Op::Await(Condition::Servo(on)),
        (JobKind::Home(_), 0) => Op::Await(Condition::InPosition),
        (JobKind::Home(direction), 1) => return send(Command::Home(direction)),
        (JobKind::Home(_), 2) => Op::Await(Condition::Homed),
        (JobKind::Home(_), 3) => read_position(axis),
        (JobKind::Jog { end, .. }, 1) => return send(Command::MoveAbsolute(end)),
        (JobKind::Stop, 0) => return send(Command::CancelMotion),
        (JobKind::AlarmReset, 0) => return send(Command::Servo(false)),
        (JobKind::AlarmReset, 1) => return send(Command::Reset(ResetKind::AlarmReset)),
        (
            JobKind::SetMotion {
                velocity,
                acceleration,
            }
            | JobKind::DirectMove {
                velocity,
                acceleration,
                ..
            }
            | JobKind::Jog {
                velocity,
                acceleration,
                ..
            },
            0,
        ) => {
            return send(Command::SetVelocityAcceleration {
                velocity,
                acceleration,
            })
        }
        (JobKind::StartBuffered(_), 0) => return send(Command::ExecuteBuffered),
        (JobKind::StartBuffered(axes), 1) => Op::Await(Condition::Unbuffered(axes.with(axis))),
        (
            JobKind::WriteField {
                point,
                field,
                value,
            },
            _,
        ) => return jobs::write_field_step(axis, point, field, value, index).map(Op::Send),
        (
            JobKind::WritePoint {
                point,
                data,
                verify,
            },
            _,
        ) => {
            return match index.checked_sub(WRITE_POINT_LEN) {
                None => jobs::write_point_step(axis, point, &data, index),
                Some(_) if !verify => None,
                Some(i) => jobs::read_point_step(axis, point, i),
            }
            .map(Op::Send)
        }
        (JobKind::ReadPoint(point), _) => {
            return jobs::read_point_step(axis, point, index).map(Op::Send)
        }
        (JobKind::StorePoint { point, data }, _) => {
            // Read, compare (the engine decides there), write, read back.
            return match index.checked_sub(READ_POINT_LEN) {
                None => jobs::read_point_step(axis, point, index),
                Some(i) => match i.checked_sub(WRITE_POINT_LEN) {
                    None => jobs::write_point_step(axis, point, &data, i),
                    Some(j) => jobs::read_point_step(axis, point, j),
                },
            }
            .map(Op::Send);
        }
        (kind, _) => return move_program(axis, kind, index),
    })
}

/// The ops of a move: its command (a [`JobKind::DirectMove`]'s `v2` before it is op 0 of
/// [`program`]), then the wait until it is in position, then the read of where it stopped.
/// [`JobKind::AwaitInPosition`] is the same without a command.
fn move_program(axis: Axis, kind: JobKind, index: usize) -> Option<Op> {
    let (command, commands) = match kind {
        JobKind::MoveToPoint(point, _) => (Command::MoveToPoint(point), 1),
        JobKind::MoveAbsolute(position) => (Command::MoveAbsolute(position), 1),
        JobKind::MoveRelative(distance) => (Command::MoveRelative(distance), 1),
        JobKind::DirectMove {
            target, relative, ..
        } => (
            if relative {
                Command::MoveRelative(target)
            } else {
                Command::MoveAbsolute(target)
            },
            2,
        ),
        JobKind::AwaitInPosition => (Command::Status, 0),
        _ => return None,
    };
    match index.checked_sub(commands) {
        None => Some(send(axis, command)),
        Some(0) => Some(Op::Await(Condition::InPosition)),
        Some(1) => Some(read_position(axis)),
        _ => None,
    }
}

/// Where a [`JobKind::StorePoint`] has read the stored point and decides whether to write.
pub(crate) const STORE_COMPARED: usize = READ_POINT_LEN;

/// Where in the program an R4 of a read-back lands in the [`PointReadback`]: the read-back
/// program is Q1 then one R4 per [`PointField::ALL`] entry.
pub(crate) fn readback_slot(job: &Job, index: usize) -> Option<usize> {
    let start = match job.kind {
        JobKind::ReadPoint(_) => 0,
        JobKind::WritePoint { verify: true, .. } => WRITE_POINT_LEN,
        // The comparing read first, then (after the write) the verifying read.
        JobKind::StorePoint { .. } if index < READ_POINT_LEN => 0,
        JobKind::StorePoint { .. } => READ_POINT_LEN + WRITE_POINT_LEN,
        _ => return None,
    };
    index
        .checked_sub(start + 1)
        .filter(|&i| i < PointField::ALL.len())
}

/// The data a verified `WritePoint` or a `StorePoint` writes, to compare with its read-back.
pub(crate) fn written(job: &Job) -> Option<&PointData> {
    match &job.kind {
        JobKind::WritePoint {
            data, verify: true, ..
        }
        | JobKind::StorePoint { data, .. } => Some(data),
        _ => None,
    }
}
