//! Every worked example of both vendor documents, encoded and decoded.
//!
//! Frames are written as the documents print them: the 14 characters between STX and ETX.
//! Where an example contradicts a stated rule, the test is named `*_contradicts_*`, follows the
//! rule, and says why in its comment.
//!
//! Lengths are in 0.01 mm and speeds in 0.01 mm/s, so `Length(56_80)` reads as 56.80 mm.
#![allow(clippy::inconsistent_digit_grouping)]

use protocol::frame::{bcc, Frame};
use protocol::memory::{self, PointField};
use protocol::units::{Accel, Complement, Lead, Length, Scale, Speed};
use protocol::*;

fn axis(n: u8) -> Axis {
    Axis::new(n).unwrap()
}
fn pos(n: u8) -> PositionNo {
    PositionNo::new(n).unwrap()
}
fn lead_mm(hundredths: u16) -> Lead {
    Lead::from_hundredths(hundredths).unwrap()
}
fn text(frame: Frame) -> String {
    String::from_utf8(frame.to_text().to_vec()).unwrap()
}

/// Encode `request`, compare with the document's text, and decode the text back.
fn both_ways(doc: &str, request: Request) {
    assert_eq!(text(request.emit()), doc, "encoding {request:?}");
    let frame = Frame::from_text(doc.as_bytes()).unwrap();
    assert_eq!(Request::parse(&frame).unwrap(), request, "decoding {doc}");
}

fn reply_both_ways(doc: &str, reply: Reply) {
    assert_eq!(text(reply.emit()), doc, "encoding {reply:?}");
    let frame = Frame::from_text(doc.as_bytes()).unwrap();
    assert_eq!(Reply::parse(&frame).unwrap(), reply, "decoding {doc}");
}

fn motor_end(lead: u16) -> Scale {
    Scale::new(lead_mm(lead), HomeDirection::MotorEnd)
}

// ---------------------------------------------------------------- brief edition §4-1, §5-1

#[test]
fn brief_4_1_bcc_example_0q3010000000_is_9b() {
    // "30H+51H+...+30H = 265H. The 2's complement of 265H is D9B ... the BCC is 9B."
    assert_eq!(bcc(b"0Q3010000000"), 0x9B);
    both_ways(
        "0Q30100000009B",
        Request::new(axis(0), Command::MoveToPoint(pos(0))),
    );
}

#[test]
fn brief_5_1_1_status_inquiry() {
    both_ways("0n000000000082", Request::new(axis(0), Command::Status));
}

#[test]
fn brief_5_1_2_position_move() {
    both_ways(
        "1Q301060000094",
        Request::new(axis(1), Command::MoveToPoint(pos(6))),
    );
}

// ---------------------------------------------------------------- brief edition §5-2

#[test]
fn brief_5_2_1_home_axis_3_motor_end() {
    both_ways(
        "3o070000000077",
        Request::new(axis(3), Command::Home(HomeDirection::MotorEnd)),
    );
}

#[test]
fn brief_5_2_2_velocity_acceleration() {
    // Lead 2.5 mm: 100 mm/s x 300 / 2.5 = 12000 = 2EE0; 0.2 G x 5883.99 / 2.5 = 470.7192 -> 1D6.
    let scale = motor_end(250);
    let velocity = scale.velocity(Speed(100_00)).unwrap();
    let acceleration = scale.acceleration(Accel(20)).unwrap();
    assert_eq!((velocity.get(), acceleration.get()), (0x2EE0, 0x1D6));
    both_ways(
        "2v22EE001D602F",
        Request::new(
            axis(2),
            Command::SetVelocityAcceleration {
                velocity,
                acceleration,
            },
        ),
    );
}

#[test]
fn brief_5_2_3_position_move_contradicts_frame_length() {
    // Printed as "0Q3010B00000089": 15 characters, one '0' too many for the 16-byte frame rule
    // (§4-1 "Data format is fixed at 16 characters"). The printed BCC 89 is right for the
    // 12-character data, so the extra '0' is a typo; the frame is "0Q3010B0000089".
    let printed = b"0Q3010B00000089";
    assert_eq!(
        Frame::from_text(printed),
        Err(Error::WrongLength { len: 17 })
    );
    both_ways(
        "0Q3010B0000089",
        Request::new(axis(0), Command::MoveToPoint(pos(11))),
    );
}

#[test]
fn brief_5_2_4_absolute_move_56_8_mm() {
    // Lead 6 mm, motor end: 56.8 x 800 / 6 = 7573.33 -> 1D95; FFFFFFFF - 1D95 = FFFFE26A.
    let position = motor_end(600).position_to_wire(Length(56_80)).unwrap();
    assert_eq!(position.to_wire(), 0xFFFF_E26A);
    both_ways(
        "CaFFFFE26A00F6",
        Request::new(axis(12), Command::MoveAbsolute(position)),
    );
    assert_eq!(motor_end(600).position_from_wire(position), Length(56_80));
}

#[test]
fn brief_5_2_5_incremental_plus_100_contradicts_formula_and_bcc() {
    // Printed "CmFFFFE26A00F6": the data is the 56.8 mm value of §5-2 4 and the BCC is that
    // example's too (right for 'a', wrong for 'm'). The rule (§4-3 3): +100 mm = 13333 pulses,
    // motor end -> FFFFFFFF - 3415 = FFFFCBEA.
    assert_eq!(
        Frame::from_text(b"CmFFFFE26A00F6"),
        Err(Error::BadBcc {
            expected: 0xEA,
            received: 0xF6
        })
    );
    let distance = motor_end(600).distance_to_wire(Length(100_00)).unwrap();
    assert_eq!(distance.to_wire(), 0xFFFF_CBEA);
    both_ways(
        "CmFFFFCBEA00CD",
        Request::new(axis(12), Command::MoveRelative(distance)),
    );
}

#[test]
fn brief_5_2_5_incremental_minus_100_contradicts_formula() {
    // Printed "Cm00001D95004D": BCC right, but 1D95 is the 56.8 mm of §5-2 4. The rule: a
    // negative move uses the other homing direction's equation: 100 x 800 / 6 = 13333 = 3415.
    let printed = Frame::from_text(b"Cm00001D95004D").unwrap();
    let decoded = Request::parse(&printed).unwrap();
    assert_eq!(decoded.command, Command::MoveRelative(Pulses(0x1D95)));
    assert_eq!(
        motor_end(600).distance_from_wire(Pulses(0x1D95)),
        Length(-56_80),
        "the printed value is -56.8 mm, not -100 mm"
    );
    let distance = motor_end(600).distance_to_wire(Length(-100_00)).unwrap();
    assert_eq!(distance, Pulses(0x3415));
    both_ways(
        "Cm000034150063",
        Request::new(axis(12), Command::MoveRelative(distance)),
    );
}

#[test]
fn brief_5_2_6_servo_on_and_off() {
    both_ways(
        "1q10000000007D",
        Request::new(axis(1), Command::Servo(true)),
    );
    both_ways(
        "1q00000000007E",
        Request::new(axis(1), Command::Servo(false)),
    );
}

#[test]
fn brief_5_2_7_position_inquiry_and_response() {
    both_ways(
        "0R40000740008F",
        Request::new(
            axis(0),
            Command::ReadMemory {
                address: memory::PNOW,
            },
        ),
    );
    let reply = Reply::Memory {
        axis: axis(0),
        code: MemoryCode::ReadMemory,
        value: 0xFFFF_167A,
    };
    reply_both_ways("U0R4FFFF167AFE", reply);
    // (FFFFFFFF - FFFF167A) x 12 / 800 = 896.715 -> 896.72 mm (rounded to nearest 0.01 mm).
    let position = reply.position().unwrap();
    assert_eq!(motor_end(1200).position_from_wire(position), Length(896_72));
    assert!(reply
        .answers(&Request::new(
            axis(0),
            Command::ReadMemory {
                address: memory::PNOW
            }
        ))
        .is_ok());
}

// ---------------------------------------------------------------- brief edition §4-3 3)

#[test]
fn brief_4_3_3_zero_mm_motor_end_is_ffffffff() {
    // "Therefore, for 0mm, the position data in the string is actually FFFFFFFF."
    let p = motor_end(600).position_to_wire(Length(0)).unwrap();
    assert_eq!(p.to_wire(), 0xFFFF_FFFF);
    // Non-motor end: pos = mm x 800 / lead.
    let non_motor = Scale::new(lead_mm(600), HomeDirection::NonMotorEnd);
    assert_eq!(
        non_motor.position_to_wire(Length(56_80)).unwrap(),
        Pulses(7573)
    );
}

#[test]
fn brief_4_3_3_incremental_plus_half_mm_contradicts_formula() {
    // "a positive move of 0.5 mm for a 2.5mm lead system that homes to the motor end would be
    // 'FFFFFF60'". 0.5 x 800 / 2.5 = 160 = A0, and the stated formula FFFFFFFF - A0 = FFFFFF5F.
    // FFFFFF60 is the two's complement (-160): the complete edition's convention. The rule is
    // the default; Complement::Twos reproduces the example.
    let scale = motor_end(250);
    assert_eq!(
        scale.distance_to_wire(Length(50)).unwrap().to_wire(),
        0xFFFF_FF5F
    );
    let twos = Scale {
        complement: Complement::Twos,
        ..scale
    };
    assert_eq!(
        twos.distance_to_wire(Length(50)).unwrap().to_wire(),
        0xFFFF_FF60
    );
    // "a negative 0.5mm move with the same system would be '000000A0'" (both conventions).
    assert_eq!(
        scale.distance_to_wire(Length(-50)).unwrap().to_wire(),
        0x0000_00A0
    );
    assert_eq!(
        twos.distance_to_wire(Length(-50)).unwrap().to_wire(),
        0x0000_00A0
    );
}

// ---------------------------------------------------------------- brief edition §5-3

/// The frames of §5-3 1) and 2) for axis 5, point 14, lead 8 mm, motor end.
fn point_14_scale() -> Scale {
    motor_end(800)
}

#[test]
fn brief_5_3_1_change_position_data() {
    // 32.45 x 800 / 8 = 3245 = CAD; FFFFFFFF - CAD = FFFFF352.
    let value = point_14_scale().position_to_wire(Length(32_45)).unwrap();
    assert_eq!(value.to_wire(), 0xFFFF_F352);
    let steps = jobs::write_field(axis(5), pos(14), PointField::Position, value.to_wire());
    let texts: Vec<String> = steps.iter().map(|s| text(s.request.emit())).collect();
    assert_eq!(
        texts,
        [
            "5Q1010E0000083",
            "5T40000040008F",
            "5W4FFFFF352018",
            "5V5010E000007A"
        ]
    );
    for (doc, step) in texts.iter().zip(steps.iter()) {
        both_ways(doc, step.request);
    }
}

#[test]
fn brief_5_3_1_w4_printed_with_fifteen_characters_contradicts_frame_length() {
    // Printed "5W4FFFFFF352018": one 'F' too many (9 data digits). The BCC 18 is right for
    // "5W4FFFFF3520", the 16-byte frame the rule allows, which the test above encodes.
    assert_eq!(
        Frame::from_text(b"5W4FFFFFF352018"),
        Err(Error::WrongLength { len: 17 })
    );
}

#[test]
fn brief_5_3_2_enter_new_point_fourteen_frames() {
    // Velocity 100 mm/s: 100 x 300 / 8 = 3750 = EA6. Acceleration 0.2 G: 0.2 x 5883.99 / 8 =
    // 147.1 -> 93. Band 0.1 mm: 0.1 x 800 / 8 = 10 = A. Max acc 0.
    let scale = point_14_scale();
    let data = jobs::PointData {
        position: scale.position_to_wire(Length(32_45)).unwrap(),
        velocity: scale.velocity(Speed(100_00)).unwrap(),
        acceleration: scale.acceleration(Accel(20)).unwrap(),
        flags: jobs::PointData::FLAGS_MOTION_AND_BAND,
        band: scale.band_to_wire(Length(10)).unwrap(),
        max_acceleration: 0,
    };
    let doc = [
        "5Q1010E0000083",
        "5T40000040008F",
        "5W4FFFFF352018",
        "5T40000040408B",
        "5W400000EA6064",
        "5T40000040508A",
        "5W400000093084",
        "5T40000040108E",
        "5W4000000C007D",
        "5T40000040308C",
        "5W40000000A07F",
        "5T400000409086",
        "5W400000000090",
        "5V5010E000007A",
    ];
    let steps = jobs::write_point(axis(5), pos(14), &data);
    for (doc, step) in doc.iter().zip(steps.iter()) {
        both_ways(doc, step.request);
    }
    assert_eq!(steps.len(), doc.len());
}

#[test]
fn brief_5_3_2_push_force_write_contradicts_address_list() {
    // The example says it sets "push force to 0", and writes C0 at 0x401, an address the
    // brief edition's own list (§4-3 4) does not have. The complete edition's memory map
    // (§7-2-2) says 0x401 is FLGP, and C0 selects the row's band (bit 7) and velocity,
    // acceleration and max-acc flag (bit 6). The job follows the memory map.
    assert_eq!(
        PointField::from_address(Address(0x401)),
        Some(PointField::Flags)
    );
    assert_eq!(jobs::PointData::FLAGS_MOTION_AND_BAND, 0xC0);
}

// ---------------------------------------------------------------- brief edition §5-4

#[test]
fn brief_5_4_1_jog_forward_then_stop() {
    both_ways(
        "0aFFFF65430025",
        Request::new(
            axis(0),
            Command::MoveAbsolute(Pulses::from_wire(0xFFFF_6543)),
        ),
    );
    both_ways(
        "0d00000000008C",
        Request::new(axis(0), Command::CancelMotion),
    );
}

#[test]
fn brief_5_4_2_jog_backward_then_stop() {
    both_ways(
        "0aFFFFFFFF00DF",
        Request::new(axis(0), Command::MoveAbsolute(Pulses(-1))),
    );
    both_ways(
        "0d00000000008C",
        Request::new(axis(0), Command::CancelMotion),
    );
}

// ---------------------------------------------------------------- complete edition

#[test]
fn complete_3_bcc_example_contradicts_ones_complement_wording() {
    // "1a1234567800": sum 296H, "[BCC] = 6A", said to be the "last 2 characters of the one's
    // complement". The one's complement of 296H ends in 69; 6A is the two's complement, which
    // is the brief edition's rule and what every other example uses. The two's complement wins.
    assert_eq!(bcc(b"1a1234567800"), 0x6A);
    both_ways(
        "1a12345678006A",
        Request::new(
            axis(1),
            Command::MoveAbsolute(Pulses::from_wire(0x1234_5678)),
        ),
    );
}

#[test]
fn complete_4_4_1_r4_example_contradicts_memory_map() {
    // The command "3R4700004000" + "8C" reads 70000400H, which the text calls "the memory address
    // for the position"; the memory map (§7-2-5) puts PNOW at 00007400H, as the brief edition's
    // example (§5-2 7) reads it. The frame is encoded as printed; PNOW stays 0x7400.
    both_ways(
        "3R47000040008C",
        Request::new(
            axis(3),
            Command::ReadMemory {
                address: Address(0x7000_0400),
            },
        ),
    );
    assert_eq!(memory::PNOW, Address(0x7400));
}

#[test]
fn complete_4_4_1_r4_response_contradicts_bcc_rule() {
    // Printed "U3R4FFFFF003" + "62": the BCC of that data is 01 (neither complement gives 62).
    // The BCC rule wins: the frame is rejected. Its data, FFFFF003, decodes as documented.
    assert_eq!(
        Frame::from_text(b"U3R4FFFFF00362"),
        Err(Error::BadBcc {
            expected: 0x01,
            received: 0x62
        })
    );
    reply_both_ways(
        "U3R4FFFFF00301",
        Reply::Memory {
            axis: axis(3),
            code: MemoryCode::ReadMemory,
            value: 0xFFFF_F003,
        },
    );
}

#[test]
fn complete_4_4_2_t4_rtim_address() {
    // "3T40000000C0", BCC not printed (the figure is lost): address 0000000CH, RTIM.
    both_ways(
        "3T40000000C082",
        Request::new(
            axis(3),
            Command::SetWriteAddress {
                address: memory::common::RTIM,
            },
        ),
    );
}

#[test]
fn complete_4_4_3_w4_rtim_3ms_and_next_address() {
    // "3W4000000030" writes 3 ms; the response "U3W40000000D" returns the next address 0DH.
    both_ways(
        "3W40000000308F",
        Request::new(axis(3), Command::WriteMemory { value: 3 }),
    );
    let reply = Reply::Memory {
        axis: axis(3),
        code: MemoryCode::WriteMemory,
        value: 0x0D,
    };
    reply_both_ways("U3W40000000D59", reply);
    let expect = jobs::Expect::NextAddress(memory::common::RTIM.next());
    assert_eq!(expect.check(&reply), Ok(Some(0x0D)));
}

#[test]
fn complete_4_4_4_q1_point_1_to_edit_area() {
    both_ways(
        "0Q10101000009C",
        Request::new(axis(0), Command::LoadToEdit(Transfer::Point(pos(1)))),
    );
}

#[test]
fn complete_4_4_5_q2_example_contradicts_command_code() {
    // The Q2 example prints 30 51 31 ... ("0Q1010000000") with BCC 9C. Those bytes are Q1 and
    // their BCC would be 9D; 9C is the BCC of "0Q2010000000". The '1' is a typo for '2'.
    assert_eq!(
        Frame::from_text(b"0Q10100000009C"),
        Err(Error::BadBcc {
            expected: 0x9D,
            received: 0x9C
        })
    );
    // The text also says Typ 01 is rejected, while the example (and §6-4) forward position
    // data with Typ 01. Both types are encodable; the controller decides.
    both_ways(
        "0Q20100000009C",
        Request::new(axis(0), Command::EditToExecution(DataType::PositionData)),
    );
    both_ways(
        "0Q20000000009D",
        Request::new(
            axis(0),
            Command::EditToExecution(DataType::CommonParameters),
        ),
    );
}

#[test]
fn complete_4_4_6_q3_move_to_point_1() {
    both_ways(
        "0Q30101000009A",
        Request::new(axis(0), Command::MoveToPoint(pos(1))),
    );
}

#[test]
fn complete_4_4_7_v5_example_contradicts_bcc_rule() {
    // Printed "0V5010100000" + "92": 92 is the one's complement of the sum (the complete
    // edition's wording), 93 the two's complement (the rule and every other example).
    assert_eq!(
        Frame::from_text(b"0V501010000092"),
        Err(Error::BadBcc {
            expected: 0x93,
            received: 0x92
        })
    );
    both_ways(
        "0V501010000093",
        Request::new(axis(0), Command::StoreFromEdit(Transfer::Point(pos(1)))),
    );
}

#[test]
fn complete_4_4_8_absolute_100_mm_contradicts_ones_complement_rule() {
    // Lead 10, 100 mm: 8000 = 1F40. The text takes "the one's complement" and gets FFFFE0C0,
    // which is the two's complement; the one's complement (the rule, brief §4-3 3) is FFFFE0BF.
    // The printed frame is valid and decodes; Complement::Twos reproduces it.
    both_ways(
        "0aFFFFE0C0000F",
        Request::new(axis(0), Command::MoveAbsolute(Pulses(-8000))),
    );
    let ones = motor_end(1000);
    assert_eq!(
        ones.position_to_wire(Length(100_00)).unwrap().to_wire(),
        0xFFFF_E0BF
    );
    let twos = Scale {
        complement: Complement::Twos,
        ..ones
    };
    assert_eq!(
        twos.position_to_wire(Length(100_00)).unwrap().to_wire(),
        0xFFFF_E0C0
    );
    assert_eq!(twos.position_from_wire(Pulses(-8000)), Length(100_00));
}

#[test]
fn complete_4_4_10_h_buffers_absolute_move() {
    // h-Cmnd = "a" + "FFFFE0C0" + "0" (the 'a' command less its last '0'); BCC not printed.
    let inner = Command::MoveAbsolute(Pulses(-8000));
    let buffered = Buffered::new(&inner).unwrap();
    assert_eq!(buffered.command(), Ok(inner));
    both_ways(
        "0haFFFFE0C00D7",
        Request::new(axis(0), Command::Buffer(buffered)),
    );
}

#[test]
fn complete_4_4_11_relative_10_mm_contradicts_rules() {
    // Printed "0m00000CE000" + "8B" for +10 mm (lead 10): 10 x 800 / 10 = 800 = 320H, whose
    // "one's complement" is given as 00000CE0, which is neither complement of 320H, and the BCC
    // of that data is 5B, not 8B. The rule: away from home on a motor-end axis is negative,
    // FFFFFFFF - 320 = FFFFFCDF (FFFFFCE0 with Complement::Twos, as §6-3 writes 10 mm).
    assert_eq!(
        Frame::from_text(b"0m00000CE0008B"),
        Err(Error::BadBcc {
            expected: 0x5B,
            received: 0x8B
        })
    );
    let distance = motor_end(1000).distance_to_wire(Length(10_00)).unwrap();
    assert_eq!(distance.to_wire(), 0xFFFF_FCDF);
    both_ways(
        "0mFFFFFCDF00D8",
        Request::new(axis(0), Command::MoveRelative(distance)),
    );
}

#[test]
fn complete_4_4_18_v_100_mm_s_0_3_g() {
    // Lead 10: Vcmd = 100 x 60 / 10 / 0.2 = 3000 = 0BB8; Acmd = 176.5197 -> 176 (round-down) = B0.
    let scale = motor_end(1000);
    let velocity = scale.velocity(Speed(100_00)).unwrap();
    let acceleration = scale.acceleration(Accel(30)).unwrap();
    assert_eq!((velocity.get(), acceleration.get()), (0x0BB8, 0x00B0));
    both_ways(
        "0v20BB800B003A",
        Request::new(
            axis(0),
            Command::SetVelocityAcceleration {
                velocity,
                acceleration,
            },
        ),
    );
    assert_eq!(scale.speed(velocity), Speed(100_00));
}

#[test]
fn complete_6_1_communication_establishment_frames() {
    // "ptrw03", "T400000009", W4 speed code, "T40000000C", "W400000003", then STX + 14 ENQ + ETX.
    let a0 = axis(0);
    let rtim3 = Rtim::new(3).unwrap();
    let frames = [
        Request::new(a0, Command::SetResponseDelay(rtim3)),
        Request::new(
            a0,
            Command::SetWriteAddress {
                address: memory::common::BRSL,
            },
        ),
        Request::new(
            a0,
            Command::WriteMemory {
                value: line::Baud::B115200.brsl().into(),
            },
        ),
        Request::new(
            a0,
            Command::SetWriteAddress {
                address: memory::common::RTIM,
            },
        ),
        Request::new(a0, Command::WriteMemory { value: 3 }),
    ];
    let texts: Vec<String> = frames.iter().map(|r| text(r.emit())).collect();
    assert_eq!(&texts[0][..8], "0ptrw030");
    assert_eq!(&texts[1][..12], "0T4000000090");
    assert_eq!(&texts[2][..12], "0W4000000140");
    assert_eq!(&texts[3][..12], "0T40000000C0");
    assert_eq!(&texts[4][..12], "0W4000000030");
    for (t, r) in texts.iter().zip(frames) {
        both_ways(t, r);
    }
    let mut deframer = Deframer::new();
    let packets: Vec<_> = frame::COMM_CHANGE
        .iter()
        .filter_map(|&b| deframer.push(b).ok())
        .collect();
    assert_eq!(packets, [Packet::CommChange]);
    assert_eq!(
        frame::COMM_CHANGE
            .iter()
            .filter(|&&b| b == frame::ENQ)
            .count(),
        14
    );
}

#[test]
fn complete_6_3_ptp_positions_fffffce0_and_zero() {
    // Continuous moves between a FFFFFCE0 and a 00000000: 10 mm and 0 mm (lead 10, motor end,
    // with the complete edition's exact negation).
    let twos = Scale {
        complement: Complement::Twos,
        ..motor_end(1000)
    };
    assert_eq!(
        twos.position_to_wire(Length(10_00)).unwrap().to_wire(),
        0xFFFF_FCE0
    );
    assert_eq!(twos.position_to_wire(Length(0)).unwrap().to_wire(), 0);
    assert_eq!(
        text(Request::new(axis(0), Command::MoveAbsolute(Pulses(-800))).emit())[..12],
        *"0aFFFFFCE000"
    );
}

#[test]
fn complete_7_2_1_brsl_codes() {
    use line::Baud::*;
    let table = [
        (B9600, 0x04),
        (B14400, 0x11),
        (B19200, 0x05),
        (B28800, 0x12),
        (B38400, 0x06),
        (B57600, 0x13),
        (B76800, 0x07),
        (B115200, 0x14),
    ];
    for (baud, code) in table {
        assert_eq!(baud.brsl(), code);
        assert_eq!(line::Baud::from_brsl(code.into()), Some(baud));
    }
}

#[test]
fn complete_7_2_1_reg1_lead_types() {
    let leads: Vec<u16> = (0..10)
        .map(|t| Lead::from_lead_type(t).unwrap().hundredths())
        .collect();
    assert_eq!(
        leads,
        [250, 300, 400, 500, 600, 800, 1000, 1200, 1600, 2000]
    );
    assert_eq!(Lead::from_lead_type(10), None);
}

#[test]
fn brief_4_3_7_screw_lead_chart() {
    use units::{ActuatorType::*, SpeedType::*};
    let chart = [
        (S5, [300, 600, 1200]),
        (S6, [300, 600, 1200]),
        (SS, [300, 600, 1200]),
        (SM, [500, 1000, 2000]),
        (SSR, [300, 600, 1200]),
        (SMR, [500, 1000, 2000]),
        (RS, [250, 500, 1000]),
        (RM, [400, 800, 1600]),
    ];
    for (actuator, leads) in chart {
        let got = [L, M, H].map(|s| Lead::of(actuator, s).hundredths());
        assert_eq!(got, leads, "{actuator:?}");
    }
}

#[test]
fn brief_4_3_4_push_data_is_percent_times_lead() {
    // "Push % data = Push percentage x screw lead (mm)": 50 % with a 2.5 mm lead = 125.
    assert_eq!(motor_end(250).push_data(50), 125);
    assert_eq!(motor_end(1200).push_data(70), 840);
}
