//! Strategies: every field over its full range, every command, every valid reply, valid and
//! mutated frames.

use proptest::prelude::*;
use proptest::sample::select;
use protocol::frame::{Frame, DATA_LEN};
use protocol::{
    Acceleration, Address, AlarmCode, Axis, Buffered, Code, Command, DataType, HomeDirection,
    Inputs, MemoryCode, Outputs, PositionNo, Pulses, Reply, Request, ResetKind, Rtim, Status,
    StatusReport, Transfer, Velocity,
};

// ---------------------------------------------------------------- strategies: fields

fn axis() -> impl Strategy<Value = Axis> {
    (0u8..=15).prop_map(|n| Axis::new(n).unwrap())
}

fn position_no() -> impl Strategy<Value = PositionNo> {
    (0u8..=15).prop_map(|n| PositionNo::new(n).unwrap())
}

fn transfer() -> impl Strategy<Value = Transfer> {
    prop_oneof![
        Just(Transfer::CommonParameters),
        position_no().prop_map(Transfer::Point),
    ]
}

fn data_type() -> impl Strategy<Value = DataType> {
    prop_oneof![
        Just(DataType::CommonParameters),
        Just(DataType::PositionData)
    ]
}

pub(crate) fn home_direction() -> impl Strategy<Value = HomeDirection> {
    prop_oneof![
        Just(HomeDirection::MotorEnd),
        Just(HomeDirection::NonMotorEnd)
    ]
}

fn reset_kind() -> impl Strategy<Value = ResetKind> {
    prop_oneof![Just(ResetKind::InitializeData), Just(ResetKind::AlarmReset)]
}

fn pulses() -> impl Strategy<Value = Pulses> {
    any::<i32>().prop_map(Pulses)
}

fn address() -> impl Strategy<Value = Address> {
    any::<u32>().prop_map(Address)
}

fn rtim() -> impl Strategy<Value = Rtim> {
    (3u8..=255).prop_map(|n| Rtim::new(n).unwrap())
}

pub(crate) fn velocity() -> impl Strategy<Value = Velocity> {
    (0u16..=0x57E4).prop_map(|n| Velocity::new(n).unwrap())
}

pub(crate) fn acceleration() -> impl Strategy<Value = Acceleration> {
    (1u16..=0x7FF).prop_map(|n| Acceleration::new(n).unwrap())
}

// ---------------------------------------------------------------- strategies: commands

/// Every command `h` may carry: Q2, Q3 and every direct command but `h` (§4-4-10).
fn bufferable_command() -> BoxedStrategy<Command> {
    let ten = prop_oneof![
        data_type().prop_map(Command::EditToExecution),
        position_no().prop_map(Command::MoveToPoint),
        pulses().prop_map(Command::MoveAbsolute),
        Just(Command::CancelMotion),
        pulses().prop_map(Command::MoveRelative),
        Just(Command::Status),
        home_direction().prop_map(Command::Home),
        rtim().prop_map(Command::SetResponseDelay),
        any::<bool>().prop_map(Command::Servo),
        reset_kind().prop_map(Command::Reset),
    ];
    let two = prop_oneof![
        Just(Command::ExecuteBuffered),
        (velocity(), acceleration()).prop_map(|(velocity, acceleration)| {
            Command::SetVelocityAcceleration {
                velocity,
                acceleration,
            }
        }),
    ];
    // Weighted by arm count, so that every variant is equally likely.
    prop_oneof![10 => ten, 2 => two].boxed()
}

/// The commands `h` may not carry: the memory commands R4, T4, W4, Q1 and V5.
fn unbufferable_command() -> BoxedStrategy<Command> {
    prop_oneof![
        address().prop_map(|address| Command::ReadMemory { address }),
        address().prop_map(|address| Command::SetWriteAddress { address }),
        any::<u32>().prop_map(|value| Command::WriteMemory { value }),
        transfer().prop_map(Command::LoadToEdit),
        transfer().prop_map(Command::StoreFromEdit),
    ]
    .boxed()
}

/// `h` wrapping any bufferable command.
fn buffer_command() -> impl Strategy<Value = Command> {
    bufferable_command().prop_map(|inner| Command::Buffer(Buffered::new(&inner).unwrap()))
}

/// Every command variant, every field over its full valid range.
pub(crate) fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        12 => bufferable_command(),
        5 => unbufferable_command(),
        2 => buffer_command(),
    ]
}

pub(crate) fn request() -> impl Strategy<Value = Request> {
    (axis(), command()).prop_map(|(axis, command)| Request::new(axis, command))
}

// ---------------------------------------------------------------- strategies: replies

fn code() -> impl Strategy<Value = Code> {
    select(Code::ALL.to_vec())
}

fn memory_code() -> impl Strategy<Value = MemoryCode> {
    select(vec![
        MemoryCode::ReadMemory,
        MemoryCode::SetWriteAddress,
        MemoryCode::WriteMemory,
        MemoryCode::Store,
    ])
}

pub(crate) fn report() -> impl Strategy<Value = StatusReport> {
    any::<[u8; 4]>().prop_map(|[status, alarm, inputs, outputs]| StatusReport {
        status: Status::from_bits(status),
        alarm: AlarmCode(alarm),
        inputs: Inputs::from_bits(inputs),
        outputs: Outputs::from_bits(outputs),
    })
}

/// A direct-format reply. A memory code (R/T/W/V) answers in the direct format only when the
/// command was rejected (§4-3), so the REJECTED bit is forced on for those.
pub(crate) fn status_reply_for(axis: Axis, code: Code, mut report: StatusReport) -> Reply {
    if code.memory_function_number().is_some() {
        report.status = report.status | Status::REJECTED;
    }
    Reply::Status { axis, code, report }
}

fn status_reply() -> impl Strategy<Value = Reply> {
    (axis(), code(), report()).prop_map(|(axis, code, report)| status_reply_for(axis, code, report))
}

fn memory_reply() -> impl Strategy<Value = Reply> {
    (axis(), memory_code(), any::<u32>()).prop_map(|(axis, code, value)| Reply::Memory {
        axis,
        code,
        value,
    })
}

/// Every valid reply.
pub(crate) fn reply() -> impl Strategy<Value = Reply> {
    prop_oneof![3 => status_reply(), 1 => memory_reply()]
}

/// A valid frame: a request's or a reply's.
pub(crate) fn valid_frame() -> impl Strategy<Value = Frame> {
    prop_oneof![
        request().prop_map(|r| r.emit()),
        reply().prop_map(|r| r.emit()),
    ]
}

/// Characters that get a parser far: hex digits, every command character, `U`, the `trw` of
/// `p`, and a few near misses (lower-case hex, other letters, controls, high bytes).
const ALPHABET: &[u8] =
    b"0123456789ABCDEF0000RTWQVadhmnoprtvUUUUuwabcefGZ \x00\x02\x03\x05\x7F\x80\xFF";

/// Twelve data characters, mostly from [`ALPHABET`], so that many of them parse.
pub(crate) fn plausible_data() -> impl Strategy<Value = [u8; DATA_LEN]> {
    prop::array::uniform12(select(ALPHABET))
}

/// A valid frame with one to three data characters replaced by characters of [`ALPHABET`]
/// (BCC fixed).
pub(crate) fn mutated_frame() -> impl Strategy<Value = Frame> {
    (
        valid_frame(),
        prop::collection::vec((0..DATA_LEN, select(ALPHABET)), 1..=3),
    )
        .prop_map(|(frame, changes)| {
            let mut data = *frame.data();
            for (index, byte) in changes {
                data[index] = byte;
            }
            Frame::from_data(data)
        })
}
