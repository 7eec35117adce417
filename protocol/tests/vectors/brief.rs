//! The brief edition's worked examples: the BCC, status and moves (§4-1, §5-1, §5-2), the
//! position conversions (§4-3), the point table (§5-3), jog (§5-4), and the §4-3 charts.

use protocol::engine::point_jobs as jobs;
use protocol::frame::{bcc, Frame};
use protocol::memory::{self, PointField};
use protocol::units::{Accel, Complement, Lead, Length, Scale, Speed};
use protocol::*;

use crate::{axis, both_ways, lead_mm, motor_end, pos, reply_both_ways, text};

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

// ---------------------------------------------------------------- brief edition §4-3 7), 4)
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
