//! Alarms and rejections: alarm injection and reset, operand errors, bad BCC, motor
//! initialisation, replies between controllers, data initialisation.

use protocol::frame::{Frame, Packet};
use protocol::line::Baud;
use protocol::memory::{self, common};
use protocol::{
    Acceleration, AlarmCode, Command, HomeDirection, Pulses, Request, ResetKind, Transfer, Velocity,
};
use rc_tools::sim::wire::ms;
use rc_tools::sim::{BadBccPolicy, BusConfig, ControllerConfig};

use crate::{
    accept, axis, controller, establish, fast_host, home, host_with, move_to, point, read, reject,
    report, rtim, status, wait_pfin,
};

// ----- alarms, rejections -----

#[test]
fn alarm_injection_and_reset() {
    let mut host = fast_host(&[0]);
    home(&mut host, 0);
    move_to(&mut host, 0, -8_000);
    host.wait(ms(100));
    host.bus_mut()
        .inject_alarm(axis(0), AlarmCode(0xD8))
        .expect("D8 is an error");
    let stopped = controller(&host, 0).position();
    let r = status(&mut host, 0);
    assert_eq!(r.alarm, AlarmCode(0xD8));
    assert!(!r.status.run() && r.status.servo());
    assert!(r.outputs.alarm_active());
    assert_eq!(r.outputs.abbreviated_alarm(), Some(0x0B), "deviation error");
    host.wait(ms(200));
    assert_eq!(controller(&host, 0).position(), stopped, "motion stopped");
    assert_eq!(reject(&mut host, 0, Command::MoveAbsolute(Pulses(0))), 0x70);
    // r03 with the servo on is refused (73); after q0 it clears the alarm.
    assert_eq!(
        reject(&mut host, 0, Command::Reset(ResetKind::AlarmReset)),
        0x73
    );
    accept(&mut host, 0, Command::Servo(false));
    let reset = report(&accept(&mut host, 0, Command::Reset(ResetKind::AlarmReset)));
    assert_eq!(reset.alarm, AlarmCode::NONE);
    assert!(!reset.outputs.alarm_active());
    accept(&mut host, 0, Command::Servo(true));
    let r = status(&mut host, 0);
    assert!(r.status.run() && r.status.home(), "ZFIN survives the alarm");
    move_to(&mut host, 0, 0);
    wait_pfin(&mut host, 0);
    // Warnings are not alarms.
    assert!(host
        .bus_mut()
        .inject_alarm(axis(0), AlarmCode(0x70))
        .is_err());
}

#[test]
fn operand_errors_and_unknown_commands() {
    let mut host = fast_host(&[0]);
    // Built by hand: the codec refuses to emit these.
    let frames: [(&[u8; 12], u8); 6] = [
        (b"0q2000000000", 0x62), // servo flag
        (b"0o0900000000", 0x62), // home direction
        (b"0v2FFFF00010", 0x63), // velocity
        (b"0v2000008000", 0x64), // acceleration
        (b"0Q3011000000", 0x63), // position number
        (b"0ptrw0200000", 0x62), // RTIM below 3
    ];
    for (data, code) in frames {
        let frame = Frame::from_data(*data);
        let request_code = protocol::Code::from_char(data[1]).unwrap();
        let (sent_at, end) = host.send_bytes(&frame.to_bytes());
        let probe = Request::new(
            axis(0),
            match request_code {
                protocol::Code::Servo => Command::Servo(true),
                protocol::Code::Home => Command::Home(HomeDirection::MotorEnd),
                protocol::Code::SetVelocityAcceleration => Command::SetVelocityAcceleration {
                    velocity: Velocity::MAX,
                    acceleration: Acceleration::MIN,
                },
                protocol::Code::Transfer => Command::MoveToPoint(point(0)),
                _ => Command::SetResponseDelay(rtim(3)),
            },
        );
        let answer = host
            .await_reply(&probe, sent_at, end, end + ms(30))
            .unwrap_or_else(|| panic!("no answer to {:?}", frame));
        assert_eq!(answer.reply.rejection(), Some(AlarmCode(code)), "{frame:?}");
    }
    // An unknown command character is echoed with 61.
    let frame = Frame::from_data(*b"0z0000000000");
    host.send_bytes(&frame.to_bytes());
    host.wait(ms(30));
    let (_, last) = *host.strays().last().unwrap();
    let Packet::Frame(reply) = last else {
        panic!("{last:?}")
    };
    assert_eq!(&reply.data()[..9], b"U0z876100");
}

#[test]
fn bad_bcc_is_ignored_by_default_and_rejected_with_5f_if_configured() {
    let mut bytes = Request::new(axis(0), Command::Status).emit().to_bytes();
    bytes[14] = if bytes[14] == b'0' { b'1' } else { b'0' };

    let mut host = fast_host(&[0]);
    let heard = host.log().len();
    host.send_bytes(&bytes);
    host.wait(ms(30));
    assert_eq!(host.log().len(), heard, "silence");
    assert_eq!(controller(&host, 0).stats().bad_bcc, 1);

    let config = ControllerConfig {
        bad_bcc: BadBccPolicy::RejectIfAddressed,
        ..ControllerConfig::default()
    };
    let mut host = host_with(&[0, 1], config, BusConfig::default());
    establish(&mut host, &[0, 1], Baud::B115200, 3);
    let (sent_at, end) = host.send_bytes(&bytes);
    let probe = Request::new(axis(0), Command::Status);
    let answer = host
        .await_reply(&probe, sent_at, end, end + ms(30))
        .unwrap();
    assert_eq!(answer.reply.rejection(), Some(AlarmCode(0x5F)));
    assert_eq!(controller(&host, 1).stats().bad_bcc, 1);
    assert_eq!(
        controller(&host, 1).stats().replies_sent,
        5,
        "only §6-1's five replies"
    );
}

#[test]
fn motor_initialization_rejects_moves_with_74() {
    let config = ControllerConfig {
        init_time_us: ms(2_000),
        ..ControllerConfig::default()
    };
    let mut host = host_with(&[0], config, BusConfig::default());
    host.set_rtim_belief(255);
    let r = status(&mut host, 0);
    assert!(!r.outputs.pfin() && !r.status.run());
    assert_eq!(
        reject(&mut host, 0, Command::Home(HomeDirection::MotorEnd)),
        0x74
    );
    assert_eq!(
        reject(&mut host, 0, Command::SetResponseDelay(rtim(3))),
        0x74
    );
    accept(
        &mut host,
        0,
        Command::ReadMemory {
            address: memory::PNOW,
        },
    );
    accept(
        &mut host,
        0,
        Command::LoadToEdit(Transfer::CommonParameters),
    );
    let (answer, _) = host
        .poll_until(axis(0), ms(5_000), |r| r.outputs.pfin())
        .unwrap();
    assert!(answer.sent_end >= ms(2_000));
    accept(&mut host, 0, Command::Home(HomeDirection::MotorEnd));
}

#[test]
fn controllers_ignore_each_others_replies() {
    let mut host = fast_host(&[0, 1, 2]);
    for _ in 0..5 {
        status(&mut host, 0);
    }
    for n in [1, 2] {
        let stats = controller(&host, n).stats();
        // 5 replies of axis 0 here, plus the other axes' replies during §6-1.
        assert!(stats.foreign_replies >= 5, "{stats:?}");
        assert_eq!(stats.replies_sent, 5);
    }
}

#[test]
fn initialize_data_restores_factory_parameters() {
    let mut host = fast_host(&[0]);
    accept(
        &mut host,
        0,
        Command::SetWriteAddress {
            address: common::VCMD,
        },
    );
    accept(&mut host, 0, Command::WriteMemory { value: 1 });
    assert_eq!(read(&mut host, 0, common::VCMD.0), 1);
    accept(&mut host, 0, Command::Reset(ResetKind::InitializeData));
    assert_eq!(read(&mut host, 0, common::VCMD.0), 0xEA6);
    assert_eq!(read(&mut host, 0, 0x7C04), 0xEA6);
    // The line settings stay.
    assert_eq!(controller(&host, 0).baud(), Baud::B115200);
}
