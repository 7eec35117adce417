//! The complete edition's worked examples: the BCC (§3), every command of §4-4, the
//! procedures of §6, and the §7-2-1 codes.

use protocol::engine::point_jobs as jobs;
use protocol::frame::{bcc, Frame};
use protocol::memory;
use protocol::units::{Accel, Complement, Lead, Length, Scale, Speed};
use protocol::*;

use crate::{axis, both_ways, motor_end, pos, reply_both_ways, text};

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
