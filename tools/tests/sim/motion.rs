//! Status, servo, homing, point-to-point moves and buffered commands.

use protocol::frame::Frame;
use protocol::line::Baud;
use protocol::memory::{self, common};
use protocol::{
    Acceleration, AlarmCode, Buffered, Command, DataType, HomeDirection, Pulses, Request, Velocity,
};
use rc_tools::sim::motion::Limits;
use rc_tools::sim::wire::{ms, transmit_time};
use rc_tools::sim::BusConfig;

use crate::{
    accept, axis, brief_point, controller, establish, fast_host, home, host_on, host_with, move_to,
    point, read, reject, report, send, status, wait_pfin, with_point,
};

// ----- status, servo -----

#[test]
fn status_read_at_power_up() {
    let mut host = host_on(&[0]);
    let answer = send(&mut host, 0, Command::Status);
    // Power, servo, RUN; not homed; PFIN and *ALM on (brief edition §4-2, complete §4-2).
    assert_eq!(
        answer.reply.emit(),
        Frame::from_text(b"U0n0700009004D").unwrap()
    );
    let r = report(&answer);
    assert!(r.status.power() && r.status.servo() && r.status.run() && !r.status.home());
    assert!(r.outputs.pfin() && !r.outputs.zfin() && !r.outputs.alarm_active());
    // After a break-free power-up the line is in the default state: RTIM 255 ms at 9.6 kbit/s.
    let delay = answer.first_byte_at - answer.sent_end;
    assert_eq!(delay, ms(255) + transmit_time(1, Baud::B9600));
    assert_eq!(controller(&host, 0).stats().frames_addressed, 1);
}

#[test]
fn servo_off_and_on() {
    let mut host = fast_host(&[1]);
    let off = report(&accept(&mut host, 1, Command::Servo(false)));
    assert!(!off.status.servo() && !off.status.run());
    let on = report(&accept(&mut host, 1, Command::Servo(true)));
    assert!(on.status.servo() && on.status.run() && on.outputs.pfin());
    // The brief edition's servo frames (§5-2 6) for axis 1.
    assert_eq!(
        Request::new(axis(1), Command::Servo(true)).emit().to_text(),
        *b"1q10000000007D"
    );
}

// ----- homing, PTP -----

#[test]
fn homing_procedure_6_2_takes_a_plausible_time() {
    let mut host = fast_host(&[0]);
    let distance = controller(&host, 0).physical_position();
    assert_eq!(distance, 2_000);
    let ovcm = read(&mut host, 0, common::OVCM.0);
    let oacc = read(&mut host, 0, common::OACC.0);
    let otim = read(&mut host, 0, common::OTIM.0);
    let expected_ms =
        Limits::from_units(ovcm, oacc).move_time_ms(distance as f64) + f64::from(otim) * 16.0;

    let (o, zfin) = home(&mut host, 0);
    let o_report = report(&o);
    assert!(!o_report.outputs.pfin() && !o_report.outputs.zfin());
    let measured_ms = (zfin.sent_end - o.sent_end) as f64 / 1000.0;
    // The first status showing ZFIN is at most one poll (about 7 ms) after homing ends.
    assert!(
        measured_ms >= expected_ms - 1.0 && measured_ms <= expected_ms + 10.0,
        "homing took {measured_ms} ms, expected {expected_ms} ms"
    );
    // 20 mm at 20 mm/s plus the stall: about 1.2 s.
    assert!((1_000.0..2_000.0).contains(&measured_ms));
    let r = report(&zfin);
    assert!(r.status.home() && r.outputs.pfin() && r.outputs.zfin());
    assert_eq!(read(&mut host, 0, memory::PNOW.0), 0);
    assert_eq!(controller(&host, 0).physical_position(), 0);
}

#[test]
fn moves_are_rejected_while_homing() {
    let mut host = fast_host(&[0]);
    accept(&mut host, 0, Command::Home(HomeDirection::MotorEnd));
    assert_eq!(
        reject(&mut host, 0, Command::MoveAbsolute(Pulses(-800))),
        0x75
    );
    assert_eq!(
        reject(&mut host, 0, Command::Home(HomeDirection::MotorEnd)),
        0x75
    );
    assert_eq!(reject(&mut host, 0, Command::MoveToPoint(point(0))), 0x75);
}

#[test]
fn ptp_6_3_move_time_matches_the_trapezoid() {
    let mut host = fast_host(&[0]);
    home(&mut host, 0);
    let vcmd = read(&mut host, 0, 0x7C04);
    let acmd = read(&mut host, 0, 0x7C05);
    let limits = Limits::from_units(vcmd, acmd);
    for (target, wire) in [(-800i32, 0xFFFF_FCE0u32), (0, 0)] {
        let before = controller(&host, 0).position();
        let a = move_to(&mut host, 0, Pulses::from_wire(wire).0);
        assert!(
            !report(&a).outputs.pfin(),
            "PFIN goes off on a move command"
        );
        let expected_ms = limits.move_time_ms((i64::from(target) - before) as f64);
        let profile = controller(&host, 0).profile().expect("moving").clone();
        let planned_ms = (profile.end() - profile.start()) as f64 / 1000.0;
        assert!(
            (planned_ms - expected_ms).abs() < 0.01,
            "{planned_ms} {expected_ms}"
        );
        let (done, _) = wait_pfin(&mut host, 0);
        let measured_ms = (done.sent_end - a.sent_end) as f64 / 1000.0;
        assert!(
            (measured_ms - expected_ms).abs() <= 15.0,
            "move took {measured_ms} ms, formula {expected_ms} ms"
        );
        host.wait(ms(20));
        assert_eq!(read(&mut host, 0, memory::PNOW.0), wire);
    }
}

#[test]
fn q3_move_shows_the_position_number() {
    let mut host = host_with(&[0], with_point(3, &brief_point()), BusConfig::default());
    establish(&mut host, &[0], Baud::B115200, 3);
    home(&mut host, 0);
    let q = report(&accept(&mut host, 0, Command::MoveToPoint(point(3))));
    assert_eq!(q.outputs.pm(), 0);
    assert!(!q.outputs.pfin());
    let (_, done) = wait_pfin(&mut host, 0);
    assert_eq!(done.outputs.pm(), 3);
    assert_eq!(done.outputs.completed_position(), Some(point(3)));
    host.wait(ms(20));
    assert_eq!(read(&mut host, 0, memory::PNOW.0), 0xFFFF_F352);
    // An `a` move clears PM1-PM8.
    move_to(&mut host, 0, -100);
    let (_, done) = wait_pfin(&mut host, 0);
    assert_eq!(done.outputs.pm(), 0);
}

#[test]
fn q3_before_homing_homes_first() {
    let mut host = host_with(&[0], with_point(5, &brief_point()), BusConfig::default());
    establish(&mut host, &[0], Baud::B115200, 3);
    let q = report(&accept(&mut host, 0, Command::MoveToPoint(point(5))));
    assert!(!q.status.home());
    assert!(controller(&host, 0).homing());
    let (_, zfin) = host
        .poll_until(axis(0), ms(10_000), |r| r.outputs.zfin())
        .unwrap();
    // Homed, and on its way to the point.
    assert!(zfin.status.home() && !zfin.outputs.pfin() && zfin.outputs.pm() == 0);
    let (_, done) = wait_pfin(&mut host, 0);
    assert_eq!(done.outputs.pm(), 5);
    host.wait(ms(20));
    assert_eq!(read(&mut host, 0, memory::PNOW.0), 0xFFFF_F352);
}

#[test]
fn q3_to_an_empty_point_raises_b1() {
    let mut host = fast_host(&[0]);
    let r = report(&accept(&mut host, 0, Command::MoveToPoint(point(9))));
    assert_eq!(r.alarm, AlarmCode(0xB1));
    assert!(r.outputs.alarm_active() && !r.status.run());
    assert_eq!(r.outputs.abbreviated_alarm(), Some(0x06));
}

#[test]
fn absolute_and_relative_moves_before_homing_are_rejected_71() {
    let mut host = fast_host(&[0]);
    assert_eq!(
        reject(&mut host, 0, Command::MoveAbsolute(Pulses(-800))),
        0x71
    );
    assert_eq!(
        reject(&mut host, 0, Command::MoveRelative(Pulses(-800))),
        0x71
    );
    assert_eq!(controller(&host, 0).stats().rejections.get(&0x71), Some(&2));
    assert!(!controller(&host, 0).moving());
}

#[test]
fn moves_with_the_servo_off_are_rejected_70() {
    let mut host = fast_host(&[0]);
    home(&mut host, 0);
    accept(&mut host, 0, Command::Servo(false));
    assert_eq!(
        reject(&mut host, 0, Command::MoveAbsolute(Pulses(-800))),
        0x70
    );
    assert_eq!(
        reject(&mut host, 0, Command::Home(HomeDirection::MotorEnd)),
        0x70
    );
    let r = reject(
        &mut host,
        0,
        Command::EditToExecution(DataType::PositionData),
    );
    assert_eq!(r, 0x70);
    accept(&mut host, 0, Command::Servo(true));
    move_to(&mut host, 0, -800);
}

#[test]
fn cancel_stops_a_move_and_relative_moves_add_to_the_target() {
    let mut host = fast_host(&[0]);
    home(&mut host, 0);
    move_to(&mut host, 0, -8_000);
    host.wait(ms(200));
    accept(&mut host, 0, Command::CancelMotion);
    let (_, done) = wait_pfin(&mut host, 0);
    assert!(done.outputs.pfin());
    host.wait(ms(50));
    let stopped = controller(&host, 0).position();
    assert!((-3_000..-1_000).contains(&stopped), "{stopped}");
    assert_eq!(controller(&host, 0).target(), stopped);
    accept(&mut host, 0, Command::MoveRelative(Pulses(-500)));
    wait_pfin(&mut host, 0);
    host.wait(ms(20));
    assert_eq!(controller(&host, 0).position(), stopped - 500);
}

#[test]
fn velocity_changes_on_the_fly() {
    let mut host = fast_host(&[0]);
    home(&mut host, 0);
    let a = move_to(&mut host, 0, -8_000);
    let planned = controller(&host, 0).profile().unwrap().end();
    host.wait(ms(100));
    // Halve the speed: the move ends later than planned.
    let v = Velocity::new(1875).unwrap();
    let acc = Acceleration::new(220).unwrap();
    accept(
        &mut host,
        0,
        Command::SetVelocityAcceleration {
            velocity: v,
            acceleration: acc,
        },
    );
    let replanned = controller(&host, 0).profile().unwrap().end();
    assert!(replanned > planned + ms(300), "{planned} {replanned}");
    let (done, _) = wait_pfin(&mut host, 0);
    assert!(done.sent_end >= replanned - ms(10) && done.sent_end > a.sent_end);
}

// ----- buffered commands -----

#[test]
fn h_and_t_start_two_axes_at_the_same_time() {
    let mut host = fast_host(&[1, 2]);
    home(&mut host, 1);
    home(&mut host, 2);
    for (n, target) in [(1, -1_600), (2, -2_400)] {
        let buffered = Buffered::new(&Command::MoveAbsolute(Pulses(target))).unwrap();
        let r = report(&accept(&mut host, n, Command::Buffer(buffered)));
        assert!(r.status.buffered());
        assert!(!controller(&host, n).moving());
    }
    let replies_2 = controller(&host, 2).stats().replies_sent;
    let strays = host.strays().len();
    let t = accept(&mut host, 1, Command::ExecuteBuffered);
    assert!(!report(&t).status.buffered());
    host.wait(ms(50));
    // Only the addressed axis answered.
    assert_eq!(controller(&host, 2).stats().replies_sent, replies_2);
    assert_eq!(host.strays().len(), strays);
    assert_eq!(controller(&host, 2).stats().broadcasts, 1);
    // Both started when the t frame's last byte arrived.
    let start_1 = controller(&host, 1).last_move_start().unwrap();
    let start_2 = controller(&host, 2).last_move_start().unwrap();
    assert_eq!(start_1, start_2);
    assert_eq!(start_1, t.sent_end);
    assert!(!status(&mut host, 2).status.buffered());
    wait_pfin(&mut host, 1);
    wait_pfin(&mut host, 2);
    host.wait(ms(20));
    assert_eq!(controller(&host, 1).position(), -1_600);
    assert_eq!(controller(&host, 2).position(), -2_400);
}

#[test]
fn buffering_n_cancels_a_buffered_command() {
    let mut host = fast_host(&[1]);
    home(&mut host, 1);
    let a = Buffered::new(&Command::MoveAbsolute(Pulses(-1_000))).unwrap();
    assert!(report(&accept(&mut host, 1, Command::Buffer(a)))
        .status
        .buffered());
    let n = Buffered::new(&Command::Status).unwrap();
    assert!(!report(&accept(&mut host, 1, Command::Buffer(n)))
        .status
        .buffered());
    accept(&mut host, 1, Command::ExecuteBuffered);
    host.wait(ms(100));
    assert_eq!(controller(&host, 1).position(), 0);
}
