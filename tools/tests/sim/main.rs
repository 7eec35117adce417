//! The simulator against the vendor documents' procedures, in virtual time.
//!
//! A small scripted host ([`ScriptedHost`]) writes frames with `Request::emit` and reads them
//! with `Deframer` + `Reply::parse`. Sections are the complete edition's unless the brief edition
//! is named. Everything is deterministic: the same seed gives the same bytes at the same times.

mod alarms;
mod faults;
mod line;
mod motion;
mod points;

use protocol::engine::point_jobs::PointData;
use protocol::line::Baud;
use protocol::memory::common;
use protocol::{
    Acceleration, Address, Axis, Command, HomeDirection, PositionNo, Pulses, Request, Rtim,
    StatusReport, Velocity,
};
use rc_tools::sim::host::Answer;
use rc_tools::sim::wire::ms;
use rc_tools::sim::{Bus, BusConfig, Controller, ControllerConfig, ScriptedHost};

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

fn point_row(data: &PointData) -> rc_tools::sim::memory::PointRow {
    let mut row = [0u32; rc_tools::sim::memory::POINT_LEN];
    for (field, value) in data.fields() {
        row[rc_tools::sim::memory::pi(field)] = value;
    }
    row
}

fn with_point(n: u8, data: &PointData) -> ControllerConfig {
    ControllerConfig {
        points: vec![(point(n), point_row(data))],
        ..ControllerConfig::default()
    }
}
