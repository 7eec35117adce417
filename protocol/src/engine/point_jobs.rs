//! Point-table jobs as fixed sequences of frames (brief edition §4-2, §5-3; complete edition
//! §7-3-1), each step with the response that confirms it.
//!
//! Writing goes through the edit area: Q1 loads the row, T4 sets the address, W4 writes (the
//! address then increments), V5 stores the row to non-volatile memory. V5 wears that memory
//! (about 100,000 writes per area), so a caller should compare before it writes.

use crate::command::{Command, Request};
use crate::memory::{flgp, PointField};
use crate::reply::{MemoryCode, Reply};
use crate::types::{Acceleration, Address, Axis, PositionNo, Pulses, Transfer, Velocity};

/// The response that confirms a step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Expect {
    /// A direct-format response that is not a rejection (Q1).
    Accepted,
    /// A T4 response echoing this address.
    AddressEcho(Address),
    /// A W4 response with this next address (the write address + 1).
    NextAddress(Address),
    /// A V5 response (the value is the write count).
    WriteCount,
    /// An R4 response (the value is the data read).
    Data,
    /// Any response that is not a rejection (the value, for a memory response).
    Reply,
}

/// Why a response does not confirm a step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StepError {
    /// The controller rejected the command, for this reason (a warning code).
    Rejected(crate::alarm::AlarmCode),
    /// The response is of another kind or echoes another address.
    Unexpected,
}

impl Expect {
    /// Check `reply` (already matched to the request by [`Reply::answers`]). Returns the
    /// response's value (data, count, address) when it has one.
    pub fn check(self, reply: &Reply) -> Result<Option<u32>, StepError> {
        if let Some(reason) = reply.rejection() {
            return Err(StepError::Rejected(reason));
        }
        match (self, *reply) {
            (Expect::Reply, _) => Ok(reply.memory_value()),
            (Expect::Accepted, Reply::Status { .. }) => Ok(None),
            (
                Expect::AddressEcho(want),
                Reply::Memory {
                    code: MemoryCode::SetWriteAddress,
                    value,
                    ..
                },
            )
            | (
                Expect::NextAddress(want),
                Reply::Memory {
                    code: MemoryCode::WriteMemory,
                    value,
                    ..
                },
            ) if value == want.0 => Ok(Some(value)),
            (
                Expect::WriteCount,
                Reply::Memory {
                    code: MemoryCode::Store,
                    value,
                    ..
                },
            )
            | (
                Expect::Data,
                Reply::Memory {
                    code: MemoryCode::ReadMemory,
                    value,
                    ..
                },
            ) => Ok(Some(value)),
            _ => Err(StepError::Unexpected),
        }
    }
}

/// One frame of a job and the response that confirms it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Step {
    /// What to send.
    pub request: Request,
    /// What must come back.
    pub expect: Expect,
}

fn step(axis: Axis, command: Command, expect: Expect) -> Step {
    Step {
        request: Request::new(axis, command),
        expect,
    }
}

fn load(axis: Axis, point: PositionNo) -> Step {
    step(
        axis,
        Command::LoadToEdit(Transfer::Point(point)),
        Expect::Accepted,
    )
}

fn store(axis: Axis, point: PositionNo) -> Step {
    step(
        axis,
        Command::StoreFromEdit(Transfer::Point(point)),
        Expect::WriteCount,
    )
}

fn address(axis: Axis, field: PointField) -> Step {
    let address = field.address();
    step(
        axis,
        Command::SetWriteAddress { address },
        Expect::AddressEcho(address),
    )
}

fn write(axis: Axis, field: PointField, value: u32) -> Step {
    step(
        axis,
        Command::WriteMemory { value },
        Expect::NextAddress(field.address().next()),
    )
}

/// Frames of [`write_field`]: Q1, T4, W4, V5.
pub const WRITE_FIELD_LEN: usize = 4;

/// Change one field of an existing point: Q1, T4, W4, V5 (brief edition §5-3 1).
pub fn write_field(
    axis: Axis,
    point: PositionNo,
    field: PointField,
    value: u32,
) -> [Step; WRITE_FIELD_LEN] {
    steps(|i| write_field_step(axis, point, field, value, i))
}

/// Frame `index` of [`write_field`], without building the others (the engine asks for one
/// frame at a time), or `None` past the end.
pub fn write_field_step(
    axis: Axis,
    point: PositionNo,
    field: PointField,
    value: u32,
    index: usize,
) -> Option<Step> {
    match index {
        0 => Some(load(axis, point)),
        1 => Some(address(axis, field)),
        2 => Some(write(axis, field, value)),
        3 => Some(store(axis, point)),
        _ => None,
    }
}

/// The frames of a sequence as an array, from the function that gives them one by one (the
/// one place each sequence is written down).
fn steps<const N: usize>(step: impl Fn(usize) -> Option<Step>) -> [Step; N] {
    // Every index below N has a frame; the fallback only satisfies the types.
    let fallback = Step {
        request: Request::new(Axis::MIN, Command::Status),
        expect: Expect::Reply,
    };
    core::array::from_fn(|i| step(i).unwrap_or(fallback))
}

/// A whole point as the brief edition writes one (§5-3 2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PointData {
    /// 0x400 PCMD.
    pub position: Pulses,
    /// 0x404 VCMD.
    pub velocity: Velocity,
    /// 0x405 ACMD.
    pub acceleration: Acceleration,
    /// 0x401 FLGP: which fields override the common defaults (the example writes 0xC0).
    pub flags: u32,
    /// 0x403 INP, pulses.
    pub band: u32,
    /// 0x409 MXAC.
    pub max_acceleration: u32,
}

impl PointData {
    /// FLGP making the row's band, velocity, acceleration and MXAC count: 0xC0, as the brief
    /// edition's example writes (it labels this write "push force 0"; the complete edition's
    /// memory map shows 0x401 is FLGP).
    pub const FLAGS_MOTION_AND_BAND: u32 = flgp::BAND | flgp::MOTION;

    /// The fields in the order the brief edition writes them, with their values.
    pub fn fields(&self) -> [(PointField, u32); 6] {
        core::array::from_fn(|i| self.field(i).unwrap_or((PointField::Position, 0)))
    }

    /// Field `index` of [`fields`](Self::fields), without building the others (a write job
    /// asks for one frame at a time), or `None` past the last.
    fn field(&self, index: usize) -> Option<(PointField, u32)> {
        Some(match index {
            0 => (PointField::Position, self.position.to_wire()),
            1 => (PointField::Velocity, self.velocity.get().into()),
            2 => (PointField::Acceleration, self.acceleration.get().into()),
            3 => (PointField::Flags, self.flags),
            4 => (PointField::Band, self.band),
            5 => (PointField::MaxAcceleration, self.max_acceleration),
            _ => return None,
        })
    }
}

/// Frames of [`write_point`]: Q1, six T4 + W4 pairs, V5.
pub const WRITE_POINT_LEN: usize = 14;
/// Frames of [`read_point`]: Q1, then one R4 per [`PointField::ALL`] entry.
pub const READ_POINT_LEN: usize = 1 + PointField::ALL.len();

/// Write a whole new point: Q1, six T4 + W4 pairs, V5 (the 14 frames of brief edition §5-3 2).
pub fn write_point(axis: Axis, point: PositionNo, data: &PointData) -> [Step; WRITE_POINT_LEN] {
    steps(|i| write_point_step(axis, point, data, i))
}

/// Frame `index` of [`write_point`], without building the others, or `None` past the end.
pub fn write_point_step(
    axis: Axis,
    point: PositionNo,
    data: &PointData,
    index: usize,
) -> Option<Step> {
    match index {
        0 => Some(load(axis, point)),
        WRITE_POINT_STORE => Some(store(axis, point)),
        i => {
            // Frames 1..=12: the T4 + W4 pair of each field in turn.
            let pair = i.checked_sub(1)?;
            let (field, value) = data.field(pair / 2)?;
            Some(if pair % 2 == 0 {
                address(axis, field)
            } else {
                write(axis, field, value)
            })
        }
    }
}

/// Where V5 is in [`write_point`]: its last frame.
const WRITE_POINT_STORE: usize = WRITE_POINT_LEN - 1;

/// Read a point back: Q1, then R4 of every documented field ([`PointField::ALL`]).
pub fn read_point(axis: Axis, point: PositionNo) -> [Step; READ_POINT_LEN] {
    steps(|i| read_point_step(axis, point, i))
}

/// Frame `index` of [`read_point`], without building the others, or `None` past the end.
pub fn read_point_step(axis: Axis, point: PositionNo, index: usize) -> Option<Step> {
    match index.checked_sub(1) {
        None => Some(load(axis, point)),
        Some(i) => PointField::ALL.get(i).map(|field| {
            step(
                axis,
                Command::ReadMemory {
                    address: field.address(),
                },
                Expect::Data,
            )
        }),
    }
}

/// The values of a read-back, in [`PointField::ALL`] order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PointReadback(pub [u32; 9]);

impl PointReadback {
    /// The value of one field.
    pub fn get(&self, field: PointField) -> u32 {
        PointField::ALL
            .iter()
            .zip(self.0.iter())
            .find(|(f, _)| **f == field)
            .map_or(0, |(_, v)| *v)
    }

    /// Whether writing `data` would change nothing (so V5, which wears the memory, can be
    /// skipped).
    pub fn matches(&self, data: &PointData) -> bool {
        (0..)
            .map_while(|i| data.field(i))
            .all(|(field, value)| self.get(field) == value)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The engine asks for frames one at a time until `None`: each sequence must give exactly
    /// its length of frames, and its first and last are Q1 and V5 (or the last R4).
    #[test]
    fn each_sequence_gives_its_frames_then_ends() {
        let axis = Axis::MAX;
        let point = PositionNo::MAX;
        let data = PointData {
            position: Pulses(1234),
            velocity: Velocity::MAX,
            acceleration: Acceleration::MIN,
            flags: PointData::FLAGS_MOTION_AND_BAND,
            band: 10,
            max_acceleration: 30,
        };
        let field = PointField::Velocity;
        let count =
            |step: &dyn Fn(usize) -> Option<Step>| (0..).take_while(|&i| step(i).is_some()).count();
        assert_eq!(
            count(&|i| write_field_step(axis, point, field, 7, i)),
            WRITE_FIELD_LEN
        );
        assert_eq!(
            count(&|i| write_point_step(axis, point, &data, i)),
            WRITE_POINT_LEN
        );
        assert_eq!(count(&|i| read_point_step(axis, point, i)), READ_POINT_LEN);
        for i in WRITE_POINT_LEN..WRITE_POINT_LEN + 4 {
            assert_eq!(write_point_step(axis, point, &data, i), None);
        }
        let frames = write_point(axis, point, &data);
        assert_eq!(frames.first(), Some(&load(axis, point)));
        assert_eq!(frames.last(), Some(&store(axis, point)));
        // Every field's T4 comes right before its W4, in the order of `fields`.
        for (n, (f, value)) in data.fields().into_iter().enumerate() {
            assert_eq!(frames.get(1 + 2 * n), Some(&address(axis, f)));
            assert_eq!(frames.get(2 + 2 * n), Some(&write(axis, f, value)));
        }
        assert!(read_point(axis, point)
            .iter()
            .all(|s| s.request.axis == axis));
    }
}
