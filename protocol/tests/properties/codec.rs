//! The codec: (a)-(c) round trips, (d) no panics and canonical decoding, (e) the BCC, (f) the
//! §5 rules of `Reply::answers`.

use proptest::prelude::*;
use protocol::frame::{bcc, Frame, DATA_LEN, ETX, FRAME_LEN, STX};
use protocol::*;

use crate::check_parses;
use crate::strategies::{
    command, mutated_frame, plausible_data, reply, report, request, status_reply_for, valid_frame,
};

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
