//! Properties of the codec over every valid value and over arbitrary bytes.
//!
//! Strategies generate every [`Command`] variant and every valid [`Reply`] over the full range of
//! each field; the properties check that encoding and decoding are inverse, that decoding is
//! canonical (a frame that parses is exactly the frame its value emits), that nothing panics on
//! arbitrary input, that the BCC catches every single-byte substitution, that
//! [`Reply::answers`] follows the §5 rules, and that the unit conversions round-trip within
//! their resolution.
//!
//! Lengths are in 0.01 mm and speeds in 0.01 mm/s, so `Length(56_80)` reads as 56.80 mm.
#![allow(clippy::inconsistent_digit_grouping)]

use proptest::prelude::*;
use proptest::sample::select;
use protocol::frame::{bcc, Frame, DATA_LEN, ETX, FRAME_LEN, STX};
use protocol::units::{Accel, Complement, Lead, Length, Scale, Speed};
use protocol::*;
use std::num::NonZeroU16;

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

fn home_direction() -> impl Strategy<Value = HomeDirection> {
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

fn velocity() -> impl Strategy<Value = Velocity> {
    (0u16..=0x57E4).prop_map(|n| Velocity::new(n).unwrap())
}

fn acceleration() -> impl Strategy<Value = Acceleration> {
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
fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        12 => bufferable_command(),
        5 => unbufferable_command(),
        2 => buffer_command(),
    ]
}

fn request() -> impl Strategy<Value = Request> {
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

fn report() -> impl Strategy<Value = StatusReport> {
    any::<[u8; 4]>().prop_map(|[status, alarm, inputs, outputs]| StatusReport {
        status: Status::from_bits(status),
        alarm: AlarmCode(alarm),
        inputs: Inputs::from_bits(inputs),
        outputs: Outputs::from_bits(outputs),
    })
}

/// A direct-format reply. A memory code (R/T/W/V) answers in the direct format only when the
/// command was rejected (§4-3), so the REJECTED bit is forced on for those.
fn status_reply_for(axis: Axis, code: Code, mut report: StatusReport) -> Reply {
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
fn reply() -> impl Strategy<Value = Reply> {
    prop_oneof![3 => status_reply(), 1 => memory_reply()]
}

/// A valid frame: a request's or a reply's.
fn valid_frame() -> impl Strategy<Value = Frame> {
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
fn plausible_data() -> impl Strategy<Value = [u8; DATA_LEN]> {
    prop::array::uniform12(select(ALPHABET))
}

/// A valid frame with one to three data characters replaced by characters of [`ALPHABET`]
/// (BCC fixed).
fn mutated_frame() -> impl Strategy<Value = Frame> {
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

// ---------------------------------------------------------------- helpers

/// Exercise everything a caller does with a parsed reply; must never panic.
fn use_reply(reply: &Reply) {
    // A memory code answers in the direct format only when rejected (§4-3).
    if let Reply::Status { code, report, .. } = reply {
        if code.memory_function_number().is_some() {
            assert!(
                report.rejected(),
                "{reply:?} is a memory reply in the direct format"
            );
        }
    }
    let _ = reply.axis();
    let _ = reply.code();
    let _ = reply.rejection().map(|a| (a.text(), a.level(), a.info()));
    let _ = reply.memory_value();
    let _ = reply.position();
    let _ = format!("{reply:?}");
    if let Some(report) = reply.report() {
        let _ = report.outputs.completed_position();
        let _ = report.outputs.abbreviated_alarm();
        let _ = report.status.set_names().count();
    }
}

/// Exercise everything a caller does with a parsed request; must never panic.
fn use_request(request: &Request) {
    let _ = request.command.moves();
    let _ = request.command.resendable();
    let _ = request.command.code();
    let _ = format!("{request:?}");
    if let Command::Buffer(b) = request.command {
        let inner = b
            .command()
            .expect("a parsed Buffered holds a valid command");
        assert!(inner.bufferable(), "a parsed h carries {inner:?}");
    }
}

/// Parse `frame` both ways; whatever parses must be canonical and round-trip.
fn check_parses(frame: &Frame) {
    if let Ok(request) = Request::parse(frame) {
        use_request(&request);
        assert_eq!(request.emit(), *frame, "{request:?} is not canonical");
        assert_eq!(Request::parse(&request.emit()), Ok(request));
    }
    if let Ok(reply) = Reply::parse(frame) {
        use_reply(&reply);
        assert_eq!(reply.emit(), *frame, "{reply:?} is not canonical");
        assert_eq!(Reply::parse(&reply.emit()), Ok(reply));
    }
}

// ---------------------------------------------------------------- (a), (b), (c): round trips

proptest! {
    /// (a) Every request survives emit then parse, through bytes and through text.
    #[test]
    fn request_round_trips(request in request()) {
        let frame = request.emit();
        prop_assert_eq!(Request::parse(&frame), Ok(request));
        let again = Frame::new_checked(&frame.to_bytes()).unwrap();
        prop_assert_eq!(Request::parse(&again), Ok(request));
        // A request is never mistaken for a reply: replies start with `U`, axes are hex digits.
        prop_assert!(Reply::parse(&frame).is_err());
    }

    /// Every bufferable command is carried by `h` and comes back out; the others are refused.
    #[test]
    fn buffered_carries_exactly_the_bufferable_commands(command in command()) {
        match Buffered::new(&command) {
            Some(buffered) => {
                prop_assert!(command.bufferable());
                prop_assert_eq!(buffered.command(), Ok(command));
                prop_assert_eq!(Command::Buffer(buffered).moves(), command.moves());
                prop_assert_eq!(Command::Buffer(buffered).resendable(), command.resendable());
            }
            None => prop_assert!(!command.bufferable()),
        }
    }

    /// (b) Every valid reply survives emit then parse.
    #[test]
    fn reply_round_trips(reply in reply()) {
        let frame = reply.emit();
        prop_assert_eq!(Reply::parse(&frame), Ok(reply));
        prop_assert!(Request::parse(&frame).is_err());
        // A rejection is reported exactly when the REJECTED bit is set.
        let rejected = matches!(reply, Reply::Status { report, .. } if report.rejected());
        prop_assert_eq!(reply.rejection().is_some(), rejected);
    }

    /// (c) A frame survives its 16 bytes and its 14 characters of text.
    #[test]
    fn frame_round_trips(data in any::<[u8; DATA_LEN]>()) {
        let frame = Frame::from_data(data);
        let bytes = frame.to_bytes();
        prop_assert_eq!(bytes[0], STX);
        prop_assert_eq!(bytes[FRAME_LEN - 1], ETX);
        prop_assert_eq!(&bytes[1..=DATA_LEN], &data[..]);
        prop_assert_eq!(Frame::new_checked(&bytes), Ok(frame));
        let text = frame.to_text();
        prop_assert_eq!(&text[..], &bytes[1..FRAME_LEN - 1]);
        prop_assert_eq!(Frame::from_text(&text), Ok(frame));
        // The BCC makes the 12 data characters and the BCC byte sum to zero.
        let sum = data.iter().fold(frame.bcc(), |s, &b| s.wrapping_add(b));
        prop_assert_eq!(sum, 0);
        prop_assert_eq!(frame.bcc(), bcc(&data));
    }
}

// ---------------------------------------------------------------- (d): no panics, canonical

proptest! {
    /// (d) Arbitrary bytes of any length never panic any entry point; what parses is canonical.
    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..40)) {
        match Frame::new_checked(&bytes) {
            Ok(frame) => {
                prop_assert_eq!(&frame.to_bytes()[..], &bytes[..]);
                check_parses(&frame);
            }
            Err(Error::WrongLength { len }) => {
                prop_assert_eq!(len, bytes.len());
                prop_assert_ne!(bytes.len(), FRAME_LEN);
            }
            Err(e) => {
                prop_assert_eq!(bytes.len(), FRAME_LEN, "{}", e);
                let _ = format!("{e} {e:?}");
            }
        }
        match Frame::from_text(&bytes) {
            Ok(frame) => {
                prop_assert_eq!(&frame.to_text()[..], &bytes[..]);
                check_parses(&frame);
            }
            Err(Error::WrongLength { len }) => {
                prop_assert_eq!(len, bytes.len() + 2);
                prop_assert_ne!(bytes.len(), DATA_LEN + 2);
            }
            Err(e) => prop_assert_eq!(bytes.len(), DATA_LEN + 2, "{}", e),
        }
    }

    /// (d) Any 12 data bytes never panic either parser; whatever parses is canonical.
    #[test]
    fn arbitrary_data_never_panics(data in any::<[u8; DATA_LEN]>()) {
        let frame = Frame::from_data(data);
        let _ = format!("{frame:?}");
        check_parses(&frame);
    }

    /// (d) Data from an alphabet of protocol characters reaches deep into the parsers; whatever
    /// parses is canonical and round-trips.
    #[test]
    fn plausible_data_parses_canonically(data in plausible_data()) {
        check_parses(&Frame::from_data(data));
    }

    /// (d) A valid frame with one character changed (and its BCC fixed) is either rejected or
    /// parses canonically: no two encodings of one value.
    #[test]
    fn mutated_frames_parse_canonically(frame in mutated_frame()) {
        check_parses(&frame);
    }
}

/// One valid frame of every layout: each command variant (and `h` around a few), and replies.
fn templates() -> Vec<Frame> {
    let a = Axis::new(0xA).unwrap();
    let p = PositionNo::new(0xC).unwrap();
    let commands = [
        Command::ReadMemory {
            address: Address(0x0000_0400),
        },
        Command::SetWriteAddress {
            address: Address(0x0000_0400),
        },
        Command::WriteMemory { value: 0x0000_0003 },
        Command::LoadToEdit(Transfer::Point(p)),
        Command::LoadToEdit(Transfer::CommonParameters),
        Command::EditToExecution(DataType::PositionData),
        Command::MoveToPoint(p),
        Command::StoreFromEdit(Transfer::Point(p)),
        Command::MoveAbsolute(Pulses(0x1234)),
        Command::CancelMotion,
        Command::MoveRelative(Pulses(-1)),
        Command::Status,
        Command::Home(HomeDirection::MotorEnd),
        Command::SetResponseDelay(Rtim::new(0x03).unwrap()),
        Command::Servo(true),
        Command::Reset(ResetKind::AlarmReset),
        Command::ExecuteBuffered,
        Command::SetVelocityAcceleration {
            velocity: Velocity::new(0x0123).unwrap(),
            acceleration: Acceleration::new(0x0001).unwrap(),
        },
    ];
    let buffered = [
        Command::MoveAbsolute(Pulses(0x1234)),
        Command::MoveToPoint(p),
        Command::SetResponseDelay(Rtim::new(0x03).unwrap()),
        Command::Status,
    ]
    .map(|c| Command::Buffer(Buffered::new(&c).unwrap()));
    let mut frames: Vec<Frame> = commands
        .iter()
        .chain(buffered.iter())
        .map(|&c| Request::new(a, c).emit())
        .collect();
    let report = StatusReport {
        status: Status::from_bits(0x8F),
        alarm: AlarmCode(0x70),
        inputs: Inputs::from_bits(0),
        outputs: Outputs::from_bits(0x30),
    };
    frames.extend([
        Reply::Status {
            axis: a,
            code: Code::Status,
            report,
        }
        .emit(),
        Reply::Status {
            axis: a,
            code: Code::Store,
            report,
        }
        .emit(),
        Reply::Memory {
            axis: a,
            code: MemoryCode::ReadMemory,
            value: 0x0000_0400,
        }
        .emit(),
        Reply::Memory {
            axis: a,
            code: MemoryCode::Store,
            value: 0x0000_0400,
        }
        .emit(),
    ]);
    frames
}

/// (d) Every frame one or two characters away from a valid frame of any layout (characters
/// from the hex digits and the command characters) is rejected or parses canonically to a
/// valid value. Exhaustive, so that rare near misses (`p` with RTIM 00, `h` around `R4`, a
/// memory reply with Func-Num 0-7) are always tried.
#[test]
fn two_character_substitutions_parse_canonically() {
    const CHARS: &[u8] = b"0123456789ABCDEFRTWQVadhmnoprtvUu";
    for template in templates() {
        check_parses(&template);
        for i in 1..DATA_LEN {
            for j in i..DATA_LEN {
                for &ci in CHARS {
                    for &cj in CHARS {
                        let mut data = *template.data();
                        data[i] = ci;
                        data[j] = cj;
                        check_parses(&Frame::from_data(data));
                    }
                }
            }
        }
    }
}

// ---------------------------------------------------------------- (e): the BCC

proptest! {
    /// (e) Substituting any one of the 16 bytes of a valid frame is always an error.
    ///
    /// The BCC is the negated byte sum of the data, so changing one data byte by `delta`
    /// (1..=255 modulo 256) changes the sum by `delta`, never by 0 modulo 256: the BCC no
    /// longer matches. Changing a BCC digit either leaves upper-case hex (another BCC value,
    /// since the two digits encode it uniquely) or not (a non-hex digit). STX and ETX are
    /// checked literally. So no single substitution can yield any frame, let alone the same one.
    #[test]
    fn single_byte_substitution_is_always_detected(
        frame in prop_oneof![valid_frame(), any::<[u8; DATA_LEN]>().prop_map(Frame::from_data)],
        index in 0..FRAME_LEN,
        new in any::<u8>(),
    ) {
        let mut bytes = frame.to_bytes();
        prop_assume!(bytes[index] != new);
        bytes[index] = new;
        let result = Frame::new_checked(&bytes);
        match index {
            0 => prop_assert_eq!(result, Err(Error::MissingStx { found: new })),
            15 => prop_assert_eq!(result, Err(Error::MissingEtx { found: new })),
            13 | 14 => prop_assert!(
                matches!(result, Err(Error::BadBcc { .. } | Error::NonHexDigit { .. })),
                "{:?}", result
            ),
            _ => prop_assert_eq!(
                result,
                Err(Error::BadBcc {
                    expected: bcc(bytes[1..=DATA_LEN].try_into().unwrap()),
                    received: frame.bcc(),
                })
            ),
        }
    }
}

// ---------------------------------------------------------------- (f): §5 rules

/// A request and a reply, with the reply's axis and code made equal to the request's half the
/// time each, so that every combination of match and mismatch is common.
fn request_and_reply() -> impl Strategy<Value = (Request, Reply)> {
    (
        request(),
        reply(),
        any::<bool>(),
        any::<bool>(),
        any::<u32>(),
        report(),
    )
        .prop_map(|(request, reply, same_axis, same_code, value, report)| {
            let axis = if same_axis {
                request.axis
            } else {
                reply.axis()
            };
            let code = if same_code {
                request.command.code()
            } else {
                reply.code()
            };
            let memory = [
                MemoryCode::ReadMemory,
                MemoryCode::SetWriteAddress,
                MemoryCode::WriteMemory,
                MemoryCode::Store,
            ]
            .into_iter()
            .find(|m| m.code() == code);
            let reply = match memory {
                // A memory command answered: successfully or, with `report`, rejected.
                Some(code) if value % 2 == 0 => Reply::Memory { axis, code, value },
                _ => status_reply_for(axis, code, report),
            };
            (request, reply)
        })
}

proptest! {
    /// (f) `answers` is Ok exactly when the axis and the command character match, and the error
    /// says which one did not (the axis first).
    #[test]
    fn answers_iff_axis_and_code_match((request, reply) in request_and_reply()) {
        let expected = if reply.axis() != request.axis {
            Err(Mismatch::Axis { expected: request.axis, received: reply.axis() })
        } else if reply.code() != request.command.code() {
            Err(Mismatch::Code { expected: request.command.code(), received: reply.code() })
        } else {
            Ok(())
        };
        prop_assert_eq!(reply.answers(&request), expected);
        // And what is sent on the wire says the same.
        let parsed = Reply::parse(&reply.emit()).unwrap();
        prop_assert_eq!(parsed.answers(&request), expected);
    }
}

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
