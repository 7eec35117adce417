//! The simulator against the vendor documents' procedures, in virtual time.
//!
//! A small scripted host ([`ScriptedHost`]) writes frames with `Request::emit` and reads them
//! with `Deframer` + `Reply::parse`. Sections are the complete edition's unless the brief edition
//! is named. Everything is deterministic: the same seed gives the same bytes at the same times.

use protocol::frame::{Frame, Packet, COMM_CHANGE};
use protocol::jobs::{self, PointData};
use protocol::line::Baud;
use protocol::memory::{self, common, PointField};
use protocol::{
    Acceleration, Address, AlarmCode, Axis, Buffered, Command, DataType, HomeDirection, PositionNo,
    Pulses, Request, ResetKind, Rtim, StatusReport, Transfer, Velocity,
};
use rc_host::sim::host::Answer;
use rc_host::sim::motion::Limits;
use rc_host::sim::wire::{ms, transmit_time};
use rc_host::sim::{
    BadBccPolicy, Bus, BusConfig, Controller, ControllerConfig, Faults, ScriptedHost,
};

// ----- helpers -----

fn axis(n: u8) -> Axis {
    Axis::new(n).unwrap()
}

fn point(n: u8) -> PositionNo {
    PositionNo::new(n).unwrap()
}

fn rtim(ms: u8) -> Rtim {
    Rtim::new(ms).unwrap()
}

fn host_with(axes: &[u8], config: ControllerConfig, bus: BusConfig) -> ScriptedHost {
    let mut b = Bus::new(bus);
    for &n in axes {
        b.add_controller(axis(n), config.clone());
    }
    ScriptedHost::new(b)
}

/// Factory controllers (9.6 kbit/s, RTIM 255 ms) and a host at 9.6 kbit/s.
fn host_on(axes: &[u8]) -> ScriptedHost {
    host_with(axes, ControllerConfig::default(), BusConfig::default())
}

fn controller(host: &ScriptedHost, n: u8) -> &Controller {
    host.bus().controller(axis(n)).unwrap()
}

fn send(host: &mut ScriptedHost, n: u8, command: Command) -> Answer {
    host.transact(&Request::new(axis(n), command))
        .unwrap_or_else(|| panic!("axis {n} did not answer {command:?}"))
}

/// Send and expect acceptance; returns the status (direct format) or the memory value.
fn accept(host: &mut ScriptedHost, n: u8, command: Command) -> Answer {
    let answer = send(host, n, command);
    assert_eq!(
        answer.reply.rejection(),
        None,
        "{command:?} rejected: {answer:?}"
    );
    answer
}

fn report(answer: &Answer) -> StatusReport {
    *answer.reply.report().expect("direct-format reply")
}

/// Send and expect a rejection; returns the warning code.
fn reject(host: &mut ScriptedHost, n: u8, command: Command) -> u8 {
    let answer = send(host, n, command);
    answer
        .reply
        .rejection()
        .unwrap_or_else(|| panic!("{command:?} accepted: {answer:?}"))
        .0
}

fn read(host: &mut ScriptedHost, n: u8, address: u32) -> u32 {
    let answer = accept(
        host,
        n,
        Command::ReadMemory {
            address: Address(address),
        },
    );
    answer.reply.memory_value().expect("R4 value")
}

fn status(host: &mut ScriptedHost, n: u8) -> StatusReport {
    host.status(axis(n)).expect("status")
}

/// The communication establishment procedure of §6-1, for `axes`, ending at `baud` and `rtim`.
fn establish(host: &mut ScriptedHost, axes: &[u8], baud: Baud, rtim_ms: u8) {
    host.set_baud(Baud::B9600);
    host.break_line(ms(200));
    for &n in axes {
        // p: RTIM 3 ms, effective from its own reply.
        accept(host, n, Command::SetResponseDelay(rtim(3)));
        host.set_rtim_belief(3);
        let t4 = accept(
            host,
            n,
            Command::SetWriteAddress {
                address: common::BRSL,
            },
        );
        assert_eq!(t4.reply.memory_value(), Some(0x09));
        let w4 = accept(
            host,
            n,
            Command::WriteMemory {
                value: baud.brsl().into(),
            },
        );
        assert_eq!(w4.reply.memory_value(), Some(0x0A));
        accept(
            host,
            n,
            Command::SetWriteAddress {
                address: common::RTIM,
            },
        );
        let w4 = accept(
            host,
            n,
            Command::WriteMemory {
                value: rtim_ms.into(),
            },
        );
        assert_eq!(w4.reply.memory_value(), Some(0x0D));
    }
    // Three communication-change broadcasts within 100 ms, then 150 ms.
    for i in 0..3 {
        host.comm_change();
        if i < 2 {
            host.wait(ms(30));
        }
    }
    host.wait(ms(150));
    host.set_baud(baud);
    host.set_rtim_belief(rtim_ms);
}

/// Factory controllers brought to 115.2 kbit/s and RTIM 3 ms by §6-1.
fn fast_host(axes: &[u8]) -> ScriptedHost {
    let mut host = host_on(axes);
    establish(&mut host, axes, Baud::B115200, 3);
    host
}

/// §6-2: wait for PFIN, `o`, wait for ZFIN. Returns the `o` answer and the first ZFIN status.
fn home(host: &mut ScriptedHost, n: u8) -> (Answer, Answer) {
    host.poll_until(axis(n), ms(5_000), |r| r.outputs.pfin())
        .expect("ready (PFIN)");
    let o = accept(host, n, Command::Home(HomeDirection::MotorEnd));
    let (zfin, _) = host
        .poll_until(axis(n), ms(10_000), |r| r.outputs.zfin())
        .expect("homing completes");
    (o, zfin)
}

fn move_to(host: &mut ScriptedHost, n: u8, pulses: i32) -> Answer {
    accept(host, n, Command::MoveAbsolute(Pulses(pulses)))
}

fn wait_pfin(host: &mut ScriptedHost, n: u8) -> (Answer, StatusReport) {
    host.poll_until(axis(n), ms(10_000), |r| r.outputs.pfin())
        .expect("positioning completes")
}

/// The brief edition's §5-3 2 point: 32.45 mm, 100 mm/s, 0.2 G, band 0.1 mm (lead 8).
fn brief_point() -> PointData {
    PointData {
        position: Pulses::from_wire(0xFFFF_F352),
        velocity: Velocity::new(0xEA6).unwrap(),
        acceleration: Acceleration::new(0x93).unwrap(),
        flags: PointData::FLAGS_MOTION_AND_BAND,
        band: 0xA,
        max_acceleration: 0,
    }
}

fn point_row(data: &PointData) -> rc_host::sim::memory::PointRow {
    let mut row = [0u32; rc_host::sim::memory::POINT_LEN];
    for (field, value) in data.fields() {
        row[rc_host::sim::memory::pi(field)] = value;
    }
    row
}

fn with_point(n: u8, data: &PointData) -> ControllerConfig {
    ControllerConfig {
        points: vec![(point(n), point_row(data))],
        ..ControllerConfig::default()
    }
}

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

// ----- point table -----

#[test]
fn point_table_write_5_3_then_q3_and_read_back() {
    let mut host = fast_host(&[5]);
    let data = brief_point();
    let steps = jobs::write_point(axis(5), point(14), &data);
    // The brief edition's fourteen frames (§5-3 2; its W4 position frame has one F too many).
    let brief = [
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
    for (step, text) in steps.iter().zip(brief) {
        assert_eq!(
            step.request.emit(),
            Frame::from_text(text.as_bytes()).unwrap()
        );
    }
    let values = host.run_job(&steps).expect("write job");
    assert_eq!(values[13], Some(1), "first V5 of point 14");
    assert_eq!(controller(&host, 5).memory().nv.point_writes[14], 1);

    home(&mut host, 5);
    accept(&mut host, 5, Command::MoveToPoint(point(14)));
    let (_, done) = wait_pfin(&mut host, 5);
    assert_eq!(done.outputs.pm(), 14);
    host.wait(ms(20));
    assert_eq!(read(&mut host, 5, memory::PNOW.0), 0xFFFF_F352);
    // The move used the row's velocity and acceleration (FLGP 0xC0).
    assert_eq!(read(&mut host, 5, 0x7C04), 0xEA6);
    assert_eq!(read(&mut host, 5, 0x7C05), 0x93);

    let values = host
        .run_job(&jobs::read_point(axis(5), point(14)))
        .expect("read job");
    let readback = jobs::PointReadback(core::array::from_fn(|i| values[i + 1].unwrap()));
    assert!(readback.matches(&data), "{readback:?}");

    // Each V5 counts exactly once.
    let again = host.run_job(&jobs::write_field(axis(5), point(14), PointField::Band, 12));
    assert_eq!(again.expect("write field")[3], Some(2));
    let common_v5 = accept(
        &mut host,
        5,
        Command::StoreFromEdit(Transfer::CommonParameters),
    );
    assert_eq!(common_v5.reply.memory_value(), Some(1));
    // V5 answers later than other commands (the non-volatile write).
    assert!(common_v5.first_byte_at - common_v5.sent_end >= ms(3) + ms(20));
}

#[test]
fn w4_auto_increments_the_write_address() {
    let mut host = fast_host(&[2]);
    accept(&mut host, 2, Command::LoadToEdit(Transfer::Point(point(1))));
    let t4 = accept(
        &mut host,
        2,
        Command::SetWriteAddress {
            address: Address(0x404),
        },
    );
    assert_eq!(t4.reply.memory_value(), Some(0x404));
    let w1 = accept(&mut host, 2, Command::WriteMemory { value: 1_000 });
    assert_eq!(w1.reply.memory_value(), Some(0x405));
    let w2 = accept(&mut host, 2, Command::WriteMemory { value: 50 });
    assert_eq!(w2.reply.memory_value(), Some(0x406));
    assert_eq!(read(&mut host, 2, 0x404), 1_000);
    assert_eq!(read(&mut host, 2, 0x405), 50);
    // Past the row: illegal address.
    accept(
        &mut host,
        2,
        Command::SetWriteAddress {
            address: Address(0x409),
        },
    );
    accept(&mut host, 2, Command::WriteMemory { value: 0 });
    assert_eq!(
        reject(&mut host, 2, Command::WriteMemory { value: 0 }),
        0x61
    );
}

#[test]
fn memory_map_reads_and_illegal_addresses() {
    let mut host = fast_host(&[0]);
    assert_eq!(read(&mut host, 0, 0x780C), 3, "execution RTIM");
    assert_eq!(read(&mut host, 0, 0x7809), 0x14, "execution BRSL");
    assert_eq!(read(&mut host, 0, 0x00C), 3, "edit RTIM written by §6-1");
    assert_eq!(read(&mut host, 0, 0x6800), 0x104, "ROM version");
    assert_eq!(read(&mut host, 0, 0x017), 5, "lead type 8 mm");
    for address in [0x1234, 0x402, 0x780E, 0x7C01, 0x8000_0000] {
        let r = send(
            &mut host,
            0,
            Command::ReadMemory {
                address: Address(address),
            },
        );
        // A rejected memory command answers in the direct format, Func-Num slot 8-F (§4-3).
        assert_eq!(r.reply.rejection(), Some(AlarmCode(0x61)), "{address:X}");
        let text = r.reply.emit().to_text();
        assert_eq!(&text[..3], b"U0R");
        assert!((b'8'..=b'F').contains(&text[3]));
    }
    assert_eq!(
        reject(
            &mut host,
            0,
            Command::SetWriteAddress {
                address: memory::PNOW
            }
        ),
        0x61
    );
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

// ----- line: establishment, delays, baud rates -----

#[test]
fn communication_establishment_6_1() {
    // Controllers that stored 38.4 kbit/s: the host cannot talk to them at 9.6 kbit/s...
    let config = ControllerConfig {
        stored_line: Some((Baud::B38400, rtim(10))),
        ..ControllerConfig::default()
    };
    let mut host = host_with(&[0, 3], config, BusConfig::default());
    assert_eq!(controller(&host, 0).baud(), Baud::B38400);
    assert!(host.status(axis(0)).is_none());
    // ...until the break, after which every axis is at 9.6 kbit/s and 255 ms.
    host.break_line(ms(200));
    for n in [0, 3] {
        assert_eq!(controller(&host, n).baud(), Baud::B9600);
        assert_eq!(controller(&host, n).rtim_ms(), 255);
    }
    // p: its own reply already comes 3 ms after the command.
    let p = accept(&mut host, 0, Command::SetResponseDelay(rtim(3)));
    assert_eq!(
        p.first_byte_at - p.sent_end,
        ms(3) + transmit_time(1, Baud::B9600)
    );
    host.set_baud(Baud::B9600);
    establish(&mut host, &[0, 3], Baud::B115200, 3);
    for n in [0, 3] {
        assert_eq!(controller(&host, n).baud(), Baud::B115200);
        assert_eq!(controller(&host, n).rtim_ms(), 3);
        assert_eq!(controller(&host, n).stats().comm_change_frames, 3);
        let answer = send(&mut host, n, Command::Status);
        let delay = answer.first_byte_at - answer.sent_end;
        assert_eq!(delay, ms(3) + transmit_time(1, Baud::B115200));
    }
}

#[test]
fn comm_change_takes_effect_about_150_ms_later() {
    let mut host = host_on(&[0]);
    host.break_line(ms(200));
    accept(&mut host, 0, Command::SetResponseDelay(rtim(3)));
    host.set_rtim_belief(3);
    accept(
        &mut host,
        0,
        Command::SetWriteAddress {
            address: common::BRSL,
        },
    );
    accept(&mut host, 0, Command::WriteMemory { value: 0x13 });
    let (_, end) = host.send_bytes(&COMM_CHANGE);
    host.wait_until(end + ms(140));
    assert_eq!(controller(&host, 0).baud(), Baud::B9600);
    host.wait_until(end + ms(151));
    assert_eq!(controller(&host, 0).baud(), Baud::B57600);
    // RTIM in the edit area was never written after the break: still 255 there.
    assert_eq!(controller(&host, 0).rtim_ms(), 255);
}

#[test]
fn replies_never_come_before_rtim() {
    let mut host = fast_host(&[0]);
    for delay_ms in [3u8, 10, 100, 255] {
        // The reply to p already waits for the new RTIM.
        host.set_rtim_belief(delay_ms);
        let p = accept(&mut host, 0, Command::SetResponseDelay(rtim(delay_ms)));
        assert!(p.first_byte_at - p.sent_end >= ms(delay_ms.into()));
        for command in [
            Command::Status,
            Command::ReadMemory {
                address: memory::PNOW,
            },
            Command::MoveAbsolute(Pulses(0)),
        ] {
            let answer = send(&mut host, 0, command);
            let delay = answer.first_byte_at - answer.sent_end;
            assert!(delay >= ms(delay_ms.into()), "{command:?}: {delay} µs");
            assert_eq!(delay, ms(delay_ms.into()) + transmit_time(1, Baud::B115200));
        }
    }
}

#[test]
fn bytes_at_the_wrong_baud_are_not_understood() {
    let mut host = host_on(&[0]);
    host.set_baud(Baud::B115200);
    assert!(host.status(axis(0)).is_none());
    assert_eq!(controller(&host, 0).stats().wrong_baud_bytes, 16);
    assert_eq!(controller(&host, 0).stats().frames_addressed, 0);
    host.set_baud(Baud::B19200);
    assert!(host.status(axis(0)).is_none());
    host.set_baud(Baud::B9600);
    assert!(host.status(axis(0)).is_some());

    // A controller at 115.2 kbit/s answering a host that listens at 9.6: garbage, not a reply.
    let mut host = fast_host(&[0]);
    let (_, end) = host.send_bytes(&Request::new(axis(0), Command::Status).emit().to_bytes());
    host.set_baud(Baud::B9600);
    host.wait_until(end + ms(50));
    assert_eq!(host.bus().stats().host_wrong_baud_bytes, 16);
    assert!(host.log().iter().rev().take(16).all(|&(_, b)| b == 0xFF));
}

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

// ----- fault injection -----

fn fast_host_with_faults(axes: &[u8], seed: u64, faults: Faults) -> ScriptedHost {
    let bus = BusConfig {
        seed,
        ..BusConfig::default()
    };
    let mut host = host_with(axes, ControllerConfig::default(), bus);
    establish(&mut host, axes, Baud::B115200, 3);
    host.bus_mut().set_faults(faults);
    host
}

/// `count` status polls of axis 0; returns how many were answered.
fn polls(host: &mut ScriptedHost, count: usize) -> usize {
    (0..count)
        .filter(|_| host.status(axis(0)).is_some())
        .count()
}

/// Within `sigmas` standard deviations of a binomial(n, p) mean.
fn within(observed: u64, n: u64, p: f64, sigmas: f64) -> bool {
    let mean = n as f64 * p;
    let sd = (n as f64 * p * (1.0 - p)).sqrt();
    (observed as f64 - mean).abs() <= sigmas * sd
}

#[test]
fn byte_corruption_happens_at_the_configured_rate() {
    let mut host = fast_host_with_faults(&[0], 11, Faults::byte_corruption(0.01));
    let before = host.bus().stats().clone();
    let sent_before = before.host_bytes_sent + 16 * before.replies_sent;
    let answered = polls(&mut host, 3_200);
    let stats = host.bus().stats().clone();
    let bytes = stats.host_bytes_sent + 16 * stats.replies_sent - sent_before;
    let corrupted = stats.host_bytes_corrupted + stats.reply_bytes_corrupted;
    assert!(bytes >= 90_000, "{bytes}");
    assert!(
        within(corrupted, bytes, 0.01, 4.0),
        "{corrupted} of {bytes}"
    );
    // Every corrupted frame is seen as broken, every intact one arrives.
    let intact_replies = stats.replies_sent - stats.replies_corrupted;
    let packets = u64::from(host.deframer().counters().packets);
    assert!(packets >= intact_replies && packets <= intact_replies + 3);
    let intact_commands =
        stats.host_transmissions - stats.host_frames_corrupted - before.host_transmissions;
    let addressed = controller(&host, 0).stats().frames_addressed - before.host_transmissions
        + before.host_frames_corrupted;
    assert!(
        addressed.abs_diff(intact_commands) <= 3,
        "{addressed} {intact_commands}"
    );
    // About (0.99^16)^2 of the polls are answered.
    assert!(
        within(answered as u64, 3_200, 0.99f64.powi(32), 4.0),
        "{answered}"
    );
    assert!(controller(&host, 0).stats().bad_bcc > 0);
}

#[test]
fn faults_are_deterministic_for_a_seed() {
    let faults = Faults {
        host_byte_corruption: 0.01,
        reply_byte_corruption: 0.01,
        reply_drop: 0.05,
        reply_delay: 0.05,
        reply_delay_us: ms(5),
        noise: 0.05,
        noise_max_bytes: 2,
    };
    let run = |seed: u64| {
        let mut host = fast_host_with_faults(&[0], seed, faults);
        polls(&mut host, 300);
        (host.log().to_vec(), host.bus().stats().clone())
    };
    let (log_a, stats_a) = run(1);
    let (log_b, stats_b) = run(1);
    let (log_c, stats_c) = run(2);
    assert_eq!(log_a, log_b);
    assert_eq!(stats_a, stats_b);
    assert_ne!(log_a, log_c);
    assert_ne!(stats_a, stats_c);
}

#[test]
fn dropped_replies_happen_at_the_configured_rate() {
    let faults = Faults {
        reply_drop: 0.1,
        ..Faults::default()
    };
    let mut host = fast_host_with_faults(&[0], 3, faults);
    let answered = polls(&mut host, 2_000);
    let dropped = host.bus().stats().replies_dropped;
    assert_eq!(2_000 - answered as u64, dropped);
    assert!(within(dropped, 2_000, 0.1, 4.0), "{dropped}");
}

#[test]
fn delayed_replies_happen_at_the_configured_rate() {
    let faults = Faults {
        reply_delay: 0.2,
        reply_delay_us: ms(10),
        ..Faults::default()
    };
    let mut host = fast_host_with_faults(&[0], 4, faults);
    let mut late = 0;
    for _ in 0..1_000 {
        let answer = send(&mut host, 0, Command::Status);
        let delay = answer.first_byte_at - answer.sent_end;
        let normal = ms(3) + transmit_time(1, Baud::B115200);
        if delay == normal + ms(10) {
            late += 1;
        } else {
            assert_eq!(delay, normal);
        }
    }
    assert_eq!(late, host.bus().stats().replies_delayed);
    assert!(within(late, 1_000, 0.2, 4.0), "{late}");
}

#[test]
fn a_silent_axis_executes_but_never_answers() {
    let mut host = fast_host(&[0, 1]);
    host.bus_mut().set_silent(axis(1), true);
    assert!(host
        .transact(&Request::new(axis(1), Command::Servo(false)))
        .is_none());
    assert!(!controller(&host, 1).servo(), "the command was executed");
    assert!(host.status(axis(1)).is_none());
    assert_eq!(host.bus().stats().replies_silenced, 2);
    assert!(host.status(axis(0)).is_some());
    host.bus_mut().set_silent(axis(1), false);
    assert!(host.status(axis(1)).is_some());
}

#[test]
fn power_cycle_restores_non_volatile_settings() {
    let mut host = fast_host(&[0]);
    home(&mut host, 0);
    move_to(&mut host, 0, -3_000);
    wait_pfin(&mut host, 0);
    host.wait(ms(20));
    let at = host.now() + ms(10);
    host.bus_mut().schedule_power_cycle(axis(0), at, ms(50));
    host.wait(ms(100));
    assert_eq!(host.bus().stats().power_cycles, 1);
    let c = controller(&host, 0);
    assert_eq!(c.stats().power_ups, 2);
    // Nothing was stored with V5: back to the default line state.
    assert_eq!((c.baud(), c.rtim_ms()), (Baud::B9600, 255));
    assert!(
        host.status(axis(0)).is_none(),
        "the host still talks at 115.2"
    );
    host.set_baud(Baud::B9600);
    host.set_rtim_belief(255);
    let r = status(&mut host, 0);
    assert!(r.status.servo() && r.status.run() && !r.status.home() && r.outputs.pfin());
    // The slider did not move; the incremental encoder counts from 0 again.
    assert_eq!(controller(&host, 0).physical_position(), 3_000);
    assert_eq!(read(&mut host, 0, memory::PNOW.0), 0);
    assert_eq!(reject(&mut host, 0, Command::MoveAbsolute(Pulses(0))), 0x71);
}

#[test]
fn power_cycle_comes_back_at_the_stored_baud() {
    let mut host = fast_host(&[0]);
    // Store BRSL 57.6k and RTIM 5 ms (common parameters, V5) without changing the line now.
    accept(
        &mut host,
        0,
        Command::LoadToEdit(Transfer::CommonParameters),
    );
    accept(
        &mut host,
        0,
        Command::SetWriteAddress {
            address: common::BRSL,
        },
    );
    accept(&mut host, 0, Command::WriteMemory { value: 0x13 });
    accept(
        &mut host,
        0,
        Command::SetWriteAddress {
            address: common::RTIM,
        },
    );
    accept(&mut host, 0, Command::WriteMemory { value: 5 });
    let v5 = accept(
        &mut host,
        0,
        Command::StoreFromEdit(Transfer::CommonParameters),
    );
    assert_eq!(v5.reply.memory_value(), Some(1));
    let at = host.now();
    host.bus_mut().schedule_power_cycle(axis(0), at, ms(10));
    host.wait(ms(20));
    host.set_baud(Baud::B57600);
    host.set_rtim_belief(5);
    let answer = send(&mut host, 0, Command::Status);
    assert_eq!(
        answer.first_byte_at - answer.sent_end,
        ms(5) + transmit_time(1, Baud::B57600)
    );
}

#[test]
fn noise_between_frames_happens_at_the_configured_rate() {
    let faults = Faults {
        noise: 0.05,
        noise_max_bytes: 3,
        ..Faults::default()
    };
    let mut host = fast_host_with_faults(&[0], 5, faults);
    let noise_before = host.deframer().counters().noise_bytes;
    let answered = polls(&mut host, 1_000);
    assert_eq!(answered, 1_000, "noise between frames harms nothing");
    let stats = host.bus().stats();
    assert_eq!(stats.collisions, 0);
    let seen = u64::from(host.deframer().counters().noise_bytes - noise_before);
    assert_eq!(seen, stats.noise_bytes);
    assert!(within(stats.noise_bursts, 2_000, 0.05, 4.0), "{stats:?}");
    assert!(stats.noise_bytes >= stats.noise_bursts && stats.noise_bytes <= 3 * stats.noise_bursts);
}

#[test]
fn talking_over_a_reply_is_a_collision() {
    let mut host = host_on(&[0]);
    accept(&mut host, 0, Command::SetResponseDelay(rtim(3)));
    host.set_rtim_belief(3);
    let request = Request::new(axis(0), Command::Status);
    let (sent_at, end) = host.send_bytes(&request.emit().to_bytes());
    // The reply starts 3 ms after `end` and lasts 16.7 ms: talk 5 ms after `end`.
    host.wait_until(end + ms(5));
    let (second_at, second_end) = host.send_bytes(&request.emit().to_bytes());
    assert!(host
        .await_reply(&request, sent_at, end, second_end + ms(40))
        .is_none());
    let stats = host.bus().stats();
    assert_eq!(stats.collisions, 1);
    assert!(stats.collided_bytes >= 16, "{stats:?}");
    // The host read garbage, and the controller did not understand the second command.
    assert!(host.log().iter().any(|&(t, _)| t > second_at));
    assert_eq!(controller(&host, 0).stats().replies_scheduled, 2);
    // The line recovers.
    host.wait(ms(10));
    assert!(host.status(axis(0)).is_some());
}

#[test]
fn a_break_over_a_reply_cancels_and_garbles() {
    let mut host = host_on(&[0]);
    let (_, end) = host.send_bytes(&Request::new(axis(0), Command::Status).emit().to_bytes());
    host.wait_until(end + ms(100));
    // The reply is still waiting for its RTIM (255 ms): the break drops it.
    host.break_line(ms(200));
    assert_eq!(host.bus().stats().replies_cancelled, 1);
    assert_eq!(controller(&host, 0).stats().replies_sent, 0);
    assert!(host.status(axis(0)).is_some());
}

#[test]
fn a_short_low_pulse_is_not_a_break() {
    let mut host = fast_host(&[0]);
    // 10 bit times at 115.2 kbit/s are 87 µs.
    let now = host.now();
    let end = host.bus_mut().host_break(now, 50);
    host.wait_until(end + ms(1));
    assert_eq!(controller(&host, 0).baud(), Baud::B115200);
    assert_eq!(controller(&host, 0).stats().breaks, 1, "only §6-1's break");
    assert!(host.status(axis(0)).is_some());
    let now = host.now();
    let end = host.bus_mut().host_break(now, 200);
    host.wait_until(end + ms(1));
    assert_eq!(controller(&host, 0).baud(), Baud::B9600);
    assert_eq!(controller(&host, 0).rtim_ms(), 255);
}
