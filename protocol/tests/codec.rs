//! Behaviour of the codec beyond the documents' worked examples: every typed error, response
//! kinds and rejections (complete edition §4-2, §4-3), §5 matching, status bits, alarm codes, jobs.

use protocol::alarm::{self, Level};
use protocol::engine::point_jobs::{self as jobs, Expect, StepError};
use protocol::frame::{bcc, Frame, ETX, STX};
use protocol::memory::PointField;
use protocol::*;

fn axis(n: u8) -> Axis {
    Axis::new(n).unwrap()
}

/// A frame from 12 data characters, BCC computed (so only the content is under test).
fn data(text: &str) -> Frame {
    Frame::from_data(text.as_bytes().try_into().unwrap())
}

fn request_error(text: &str) -> Error {
    Request::parse(&data(text)).unwrap_err()
}

fn reply_error(text: &str) -> Error {
    Reply::parse(&data(text)).unwrap_err()
}

// ------------------------------------------------------------------------------ frame layer

#[test]
fn frame_errors_are_typed() {
    let good = data("0n0000000000").to_bytes();
    assert_eq!(
        Frame::new_checked(&good[..15]),
        Err(Error::WrongLength { len: 15 })
    );
    let mut bytes = good;
    bytes[0] = b'0';
    assert_eq!(
        Frame::new_checked(&bytes),
        Err(Error::MissingStx { found: b'0' })
    );
    let mut bytes = good;
    bytes[15] = 0x04;
    assert_eq!(
        Frame::new_checked(&bytes),
        Err(Error::MissingEtx { found: 0x04 })
    );
    let mut bytes = good;
    bytes[14] = b'g';
    assert_eq!(
        Frame::new_checked(&bytes),
        Err(Error::NonHexDigit {
            index: 14,
            found: b'g'
        })
    );
    let mut bytes = good;
    bytes[13] = b'7';
    assert_eq!(
        Frame::new_checked(&bytes),
        Err(Error::BadBcc {
            expected: 0x82,
            received: 0x72
        })
    );
    assert_eq!((good[0], good[15]), (STX, ETX));
}

#[test]
fn bcc_of_a_sum_with_zero_low_byte_is_00() {
    // scn_adapter.c computed "100" here; the BCC is always two digits.
    let data: [u8; 12] = *b"0000000000PP"; // 10 x 0x30 + 2 x 0x50 = 0x280
    assert_eq!(bcc(&data), 0x80);
    let zero: [u8; 12] = *b"@@@@@@@@@@@@"; // 12 x 0x40 = 0x300
    assert_eq!(bcc(&zero), 0x00);
    assert_eq!(&Frame::from_data(zero).to_text()[12..], b"00");
}

// ------------------------------------------------------------------------------ requests

#[test]
fn request_field_errors_name_the_field() {
    use Field::*;
    let out_of_range = |text: &str| match request_error(text) {
        Error::FieldOutOfRange { field, value } => (field, value),
        other => panic!("{text}: {other:?}"),
    };
    assert_eq!(out_of_range("0Q3011000000"), (PositionNo, 0x10));
    assert_eq!(out_of_range("0Q3000100000"), (TransferType, 0x00));
    assert_eq!(out_of_range("0Q1020100000"), (TransferType, 0x02));
    assert_eq!(out_of_range("0Q1000100000"), (PositionNo, 0x01));
    assert_eq!(out_of_range("0o0900000000"), (HomeDirection, 0x09));
    assert_eq!(out_of_range("0r0400000000"), (ResetKind, 0x04));
    assert_eq!(out_of_range("0ptrw0200000"), (Rtim, 0x02));
    assert_eq!(out_of_range("0q2000000000"), (Servo, u32::from(b'2')));
    assert_eq!(
        out_of_range("0v157E400010"),
        (VelocityType, u32::from(b'1'))
    );
    assert_eq!(out_of_range("0v257E500010"), (Velocity, 0x57E5));
    assert_eq!(out_of_range("0v257E400000"), (Acceleration, 0));
    assert_eq!(out_of_range("0v257E408000"), (Acceleration, 0x800));
    // 'h' holding R4, a memory command that cannot be buffered (§4-4-10).
    assert_eq!(
        out_of_range("0hR400007400"),
        (BufferedCommand, u32::from(b'R'))
    );
}

#[test]
fn request_structural_errors() {
    assert_eq!(
        request_error("Gn0000000000"),
        Error::BadAxis { found: b'G' }
    );
    assert_eq!(
        request_error("an0000000000"),
        Error::BadAxis { found: b'a' }
    );
    assert_eq!(
        request_error("0x0000000000"),
        Error::UnknownCommand { code: [b'x', 0] }
    );
    assert_eq!(
        request_error("0R5000074000"),
        Error::UnknownCommand { code: [b'R', b'5'] }
    );
    assert_eq!(
        request_error("0Q4010000000"),
        Error::UnknownCommand { code: [b'Q', b'4'] }
    );
    // Filler must be '0': index is in the 16-byte frame (STX = 0).
    assert_eq!(
        request_error("0n0000000001"),
        Error::UnexpectedChar {
            index: 12,
            found: b'1'
        }
    );
    assert_eq!(
        request_error("0pTRW0300000"),
        Error::UnexpectedChar {
            index: 3,
            found: b'T'
        }
    );
    // Lower-case hex is not hex here.
    assert_eq!(
        request_error("0affffe0c000"),
        Error::NonHexDigit {
            index: 3,
            found: b'f'
        }
    );
}

#[test]
fn h_carries_bufferable_commands_only() {
    assert!(Buffered::new(&Command::ReadMemory {
        address: Address(0x7400)
    })
    .is_none());
    assert!(Buffered::new(&Command::LoadToEdit(Transfer::CommonParameters)).is_none());
    let inner = Buffered::new(&Command::Status).unwrap();
    assert!(Buffered::new(&Command::Buffer(inner)).is_none());
    // Q3 is bufferable (§4-4-10, §6-4): "h" + "Q3010B0000".
    let q3 = Command::MoveToPoint(PositionNo::new(11).unwrap());
    let req = Request::new(axis(2), Command::Buffer(Buffered::new(&q3).unwrap()));
    assert_eq!(&req.emit().data()[..], b"2hQ3010B0000");
    assert_eq!(Request::parse(&req.emit()).unwrap(), req);
    // "h" holding "h..." is rejected as a buffered command.
    assert!(matches!(
        request_error("0hhn00000000"),
        Error::FieldOutOfRange {
            field: Field::BufferedCommand,
            ..
        }
    ));
}

#[test]
fn resend_and_motion_rules() {
    let m = Command::MoveRelative(Pulses(10));
    assert!(!m.resendable(), "m is never resent (§5 (2))");
    assert!(
        !Command::ExecuteBuffered.resendable(),
        "t is confirmed by n (§5 (3))"
    );
    assert!(!Command::Buffer(Buffered::new(&m).unwrap()).resendable());
    assert!(
        Command::Buffer(Buffered::new(&Command::MoveAbsolute(Pulses(1))).unwrap()).resendable()
    );
    assert!(Command::WriteMemory { value: 1 }.resendable());
    assert!(Command::Home(HomeDirection::MotorEnd).moves());
    assert!(Command::MoveToPoint(PositionNo::MIN).moves());
    assert!(Command::EditToExecution(DataType::PositionData).moves());
    assert!(!Command::EditToExecution(DataType::CommonParameters).moves());
    assert!(!Command::Status.moves() && !Command::CancelMotion.moves());
}

// ------------------------------------------------------------------------------ responses

#[test]
fn direct_response_decodes_every_byte() {
    // Status 0F (power, servo, run, home), alarm 00, IN 91 (hold, start, PC1), OUT F5.
    let reply = Reply::parse(&data("U7n0F0091F50")).unwrap();
    let Reply::Status {
        axis: a,
        code,
        report,
    } = reply
    else {
        panic!("{reply:?}")
    };
    assert_eq!((a, code), (axis(7), Code::Status));
    assert!(report.status.power() && report.status.servo() && report.status.run());
    assert!(report.status.home() && !report.status.buffered() && !report.rejected());
    assert!(report.inputs.hold() && report.inputs.start() && report.inputs.pc1());
    assert_eq!(report.inputs.pc(), 1);
    assert_eq!(report.outputs.pm(), 5);
    assert!(report.outputs.pfin() && report.outputs.zfin() && report.outputs.zone());
    assert!(!report.outputs.alarm_active());
    assert_eq!(report.outputs.completed_position(), PositionNo::new(5));
    assert_eq!(reply.rejection(), None);
    assert_eq!(Reply::parse(&reply.emit()).unwrap(), reply);
}

#[test]
fn status_bit_names_follow_the_complete_edition() {
    let all: Vec<&str> = Status::from_bits(0xFF).set_names().collect();
    assert_eq!(
        all,
        [
            "power",
            "servo",
            "run",
            "home",
            "buffered",
            "plus_interlock",
            "minus_interlock",
            "rejected"
        ]
    );
    let outs: Vec<&str> = Outputs::from_bits(0xFF).set_names().collect();
    assert_eq!(
        outs,
        ["PM1", "PM2", "PM4", "PM8", "PFIN", "ZFIN", "ZONE", "*ALM"]
    );
    let ins: Vec<&str> = Inputs::from_bits(0xFF).set_names().collect();
    assert_eq!(ins, ["PC1", "PC2", "PC4", "PC8", "START", "HOLD"]);
}

#[test]
fn alarm_shows_abbreviated_code_on_pm_while_alm_is_off() {
    // *ALM off (bit 7 = 0), PM = 0B: deviation error (complete edition §8-1-1).
    let out = Outputs::from_bits(0x0B);
    assert!(out.alarm_active());
    assert_eq!(out.abbreviated_alarm(), Some(0x0B));
    assert_eq!(out.completed_position(), None);
    assert_eq!(alarm::abbreviated_text(0x0B), Some("Deviation error"));
    assert_eq!(AlarmCode(0xD8).info().unwrap().abbreviated, Some(0x0B));
}

#[test]
fn direct_rejection_carries_the_warning_code() {
    // 'a' before homing: status 87 (rejected, run, servo, power), alarm 71.
    let reply = Reply::parse(&data("U0a877100800")).unwrap();
    assert_eq!(reply.rejection(), Some(AlarmCode(0x71)));
    assert_eq!(AlarmCode(0x71).level(), Level::Warning);
    assert!(AlarmCode(0x71).text().contains("before homing"));
    // Q1/Q2/Q3 answer 'Q' in the direct format; rejected when the Func-Num slot is 8-F.
    let q = Reply::parse(&data("U0QC57000800")).unwrap();
    assert_eq!(q.code(), Code::Transfer);
    assert_eq!(q.rejection(), Some(AlarmCode(0x70)));
}

#[test]
fn memory_rejection_uses_function_number_8_to_f() {
    // R4 rejected (§4-3): "U0R" + Status 81 + Alarm 61 + IN 00 + OUT 80 + "0".
    let reply = Reply::parse(&data("U0R816100800")).unwrap();
    assert_eq!(reply.code(), Code::ReadMemory);
    assert_eq!(reply.rejection(), Some(AlarmCode(0x61)));
    assert_eq!(reply.memory_value(), None);
    let read = Request::new(
        axis(0),
        Command::ReadMemory {
            address: Address(0x9999),
        },
    );
    assert_eq!(reply.answers(&read), Ok(()));
    assert_eq!(Reply::parse(&reply.emit()).unwrap(), reply);
    // V5 rejected likewise; a success has Func-Num 5.
    assert!(Reply::parse(&data("U0VF57300800"))
        .unwrap()
        .rejection()
        .is_some());
    let v5 = Reply::parse(&data("U0V50000002A")).unwrap();
    assert_eq!(v5.memory_value(), Some(0x2A));
    // Func-Num 0-7 other than the command's own is malformed.
    assert_eq!(
        reply_error("U0R300007400"),
        Error::FieldOutOfRange {
            field: Field::FunctionNumber,
            value: u32::from(b'3')
        }
    );
    assert_eq!(
        reply_error("U0T500007400"),
        Error::FieldOutOfRange {
            field: Field::FunctionNumber,
            value: u32::from(b'5')
        }
    );
}

#[test]
fn response_structural_errors() {
    assert_eq!(
        reply_error("X0n000000000"),
        Error::UnexpectedChar {
            index: 1,
            found: b'X'
        }
    );
    assert_eq!(reply_error("UGn000000000"), Error::BadAxis { found: b'G' });
    assert_eq!(
        reply_error("U0z000000000"),
        Error::UnknownCommand { code: [b'z', 0] }
    );
    assert_eq!(
        reply_error("U0n000000001"),
        Error::UnexpectedChar {
            index: 12,
            found: b'1'
        }
    );
    // A command frame is not a response.
    assert!(Reply::parse(&data("0n0000000000")).is_err());
}

#[test]
fn matching_follows_section_5() {
    let request = Request::new(axis(3), Command::Status);
    let ok = Reply::parse(&data("U3n0F0000B00")).unwrap();
    assert_eq!(ok.answers(&request), Ok(()));
    let other_axis = Reply::parse(&data("U4n0F0000B00")).unwrap();
    assert_eq!(
        other_axis.answers(&request),
        Err(Mismatch::Axis {
            expected: axis(3),
            received: axis(4)
        })
    );
    let other_code = Reply::parse(&data("U3q0F0000B00")).unwrap();
    assert_eq!(
        other_code.answers(&request),
        Err(Mismatch::Code {
            expected: Code::Status,
            received: Code::Servo
        })
    );
    // Q1, Q2 and Q3 all answer 'Q'.
    let q = Reply::parse(&data("U3Q0F0000B00")).unwrap();
    for command in [
        Command::LoadToEdit(Transfer::CommonParameters),
        Command::EditToExecution(DataType::PositionData),
        Command::MoveToPoint(PositionNo::MAX),
    ] {
        assert_eq!(q.answers(&Request::new(axis(3), command)), Ok(()));
    }
}

// ------------------------------------------------------------------------------ alarm table

#[test]
fn alarm_table_is_ordered_and_covers_both_editions() {
    let rows = alarm::TABLE;
    for pair in rows.windows(2) {
        assert!(
            pair[0].last < pair[1].first,
            "{:?} overlaps {:?}",
            pair[0],
            pair[1]
        );
    }
    for row in rows {
        assert!(row.first <= row.last);
        for code in row.first..=row.last {
            assert_eq!(AlarmCode(code).info(), Some(row));
            let expected = if code == 0 {
                Level::Normal
            } else if code < 0x80 {
                Level::Warning
            } else {
                Level::Error
            };
            assert_eq!(AlarmCode(code).level(), expected);
            if code >= 0x80 && row.source != alarm::Source::Brief {
                assert!(
                    row.abbreviated.is_some(),
                    "{code:02X} has a PM code in §8-1-4"
                );
            }
        }
    }
    // Brief-only, complete-only and shared codes.
    assert_eq!(AlarmCode(0x5F).info().unwrap().source, alarm::Source::Brief);
    assert_eq!(
        AlarmCode(0x73).info().unwrap().source,
        alarm::Source::Complete
    );
    assert_eq!(
        AlarmCode(0xB1).info().unwrap().brief_text,
        Some("Position data error")
    );
    assert_eq!(AlarmCode(0xEC).text(), "Encoder disconnect");
    // Undocumented codes still get a level and a text.
    assert_eq!(AlarmCode(0x5C).info(), None);
    assert_eq!(
        AlarmCode(0x5C).text(),
        "Undocumented warning (command rejected)"
    );
    assert_eq!(AlarmCode(0x90).text(), "Undocumented error");
}

// ------------------------------------------------------------------------------ jobs

#[test]
fn read_point_reads_every_documented_field() {
    let steps = jobs::read_point(axis(1), PositionNo::new(3).unwrap());
    assert_eq!(
        steps[0].request.command,
        Command::LoadToEdit(Transfer::Point(PositionNo::new(3).unwrap()))
    );
    let addresses: Vec<u32> = steps[1..]
        .iter()
        .map(|s| match s.request.command {
            Command::ReadMemory { address } => address.0,
            other => panic!("{other:?}"),
        })
        .collect();
    assert_eq!(
        addresses,
        [0x400, 0x401, 0x403, 0x404, 0x405, 0x406, 0x407, 0x408, 0x409]
    );
    assert!(steps[1..].iter().all(|s| s.expect == Expect::Data));
}

#[test]
fn expect_checks_echoes_and_rejections() {
    let t4 = Reply::Memory {
        axis: axis(0),
        code: MemoryCode::SetWriteAddress,
        value: 0x404,
    };
    assert_eq!(
        Expect::AddressEcho(Address(0x404)).check(&t4),
        Ok(Some(0x404))
    );
    assert_eq!(
        Expect::AddressEcho(Address(0x405)).check(&t4),
        Err(StepError::Unexpected)
    );
    let w4 = Reply::Memory {
        axis: axis(0),
        code: MemoryCode::WriteMemory,
        value: 0x405,
    };
    assert_eq!(
        Expect::NextAddress(Address(0x405)).check(&w4),
        Ok(Some(0x405))
    );
    assert_eq!(
        Expect::NextAddress(Address(0x404)).check(&w4),
        Err(StepError::Unexpected)
    );
    assert_eq!(Expect::Data.check(&w4), Err(StepError::Unexpected));
    let rejected = Reply::parse(&data("U0W816100800")).unwrap();
    assert_eq!(
        Expect::NextAddress(Address(0x405)).check(&rejected),
        Err(StepError::Rejected(AlarmCode(0x61)))
    );
}

#[test]
fn readback_matching_avoids_needless_v5() {
    let data = jobs::PointData {
        position: Pulses(-3246),
        velocity: Velocity::new(0xEA6).unwrap(),
        acceleration: Acceleration::new(0x93).unwrap(),
        flags: 0xC0,
        band: 10,
        max_acceleration: 0,
    };
    let mut values = [0u32; 9];
    for (i, field) in PointField::ALL.iter().enumerate() {
        values[i] = data
            .fields()
            .iter()
            .find(|(f, _)| f == field)
            .map_or(0x55, |(_, v)| *v);
    }
    let readback = jobs::PointReadback(values);
    assert!(readback.matches(&data));
    assert_eq!(readback.get(PointField::Position), (-3246i32) as u32);
    let changed = jobs::PointData { band: 11, ..data };
    assert!(!readback.matches(&changed));
}
