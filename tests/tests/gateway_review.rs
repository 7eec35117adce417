//! Regression tests from a review of the gateway: each reproduced a bug (a cleared read request
//! that wrote the point table, a running request overwritten by another, a synchronized start
//! that moved a paused axis or left commands buffered after failing, an invalid request accepted
//! while the channel was busy).
#![allow(clippy::inconsistent_digit_grouping)]

use protocol::engine::{AxisSet, Instant};
use protocol::line::Baud;
use protocol::modbus::{DataModel, Exception, RegisterTable};
use protocol::plc::map::*;
use protocol::plc::{AxisConfig, CommandState, Gateway, GatewayConfig};
use protocol::units::{Lead, Length};
use protocol::{Axis, PositionNo, Rtim};
use rc_host::harness::Harness;
use rc_host::sim::realtime::bus_at_line;
use rc_host::sim::{BusConfig, ControllerConfig};

const MS: u64 = 1000;
const S: u64 = 1_000_000;

fn axis(n: u8) -> Axis {
    Axis::new(n).unwrap()
}

/// Axes 0..n at 115.2 kbit/s / RTIM 3 (no establishment), lead 8 mm like the simulator's
/// actuator, 100 mm stroke; point 3 of every axis stored at 40 mm.
fn gateway(n: u8) -> Harness<Gateway> {
    let axes: Vec<Axis> = (0..n).map(axis).collect();
    let mut bus = bus_at_line(BusConfig::default(), &axes, Baud::B115200, Rtim::MIN);
    let mut config = GatewayConfig::new(AxisSet::first(n));
    config.bus.establish = false;
    let scale = protocol::units::Scale {
        lead: Lead::from_hundredths(800).unwrap(),
        ..AxisConfig::default().scale
    };
    config.axes = [AxisConfig {
        scale,
        stroke: Length(100_00),
    }; 16];
    let pcmd = scale.position_to_wire(Length(40_00)).unwrap().to_wire();
    for &a in &axes {
        let mut controller = ControllerConfig {
            stored_line: Some((Baud::B115200, Rtim::MIN)),
            ..ControllerConfig::default()
        };
        let mut row = [0u32; 10];
        row[0] = pcmd;
        controller.points = vec![(PositionNo::new(3).unwrap(), row)];
        bus.add_controller(a, controller);
    }
    let mut h = Harness::new(Gateway::new(config), bus);
    h.run_until(300 * MS);
    h
}

fn unit(a: u8) -> u8 {
    a + 1
}

fn write(
    h: &mut Harness<Gateway>,
    unit: u8,
    address: u16,
    values: &[u16],
) -> Result<(), Exception> {
    h.engine.set_time(Instant(h.now));
    h.engine.write_registers(unit, address, values)
}

fn read(h: &mut Harness<Gateway>, unit: u8, address: u16, n: usize) -> Result<Vec<u16>, Exception> {
    h.engine.set_time(Instant(h.now));
    let mut out = vec![0; n];
    h.engine
        .read_registers(unit, RegisterTable::Holding, address, &mut out)?;
    Ok(out)
}

fn coil(h: &mut Harness<Gateway>, unit: u8, address: u16, on: bool) -> Result<(), Exception> {
    h.engine.set_time(Instant(h.now));
    h.engine.write_bits(unit, address, &[on])
}

/// Keep "polling" like a PLC (so the watchdog stays quiet) until the command of `a` settles.
fn settle(h: &mut Harness<Gateway>, a: u8, timeout: u64) -> (CommandState, u16) {
    let until = h.now + timeout;
    while h.now < until {
        h.run_until(h.now + 50 * MS);
        let _ = read(h, unit(a), CMST, 1);
        let state = h.engine.command_state(axis(a));
        if matches!(state.0, CommandState::Done | CommandState::Failed) {
            return state;
        }
    }
    panic!(
        "axis {a}: command did not settle: {:?}",
        h.engine.command_state(axis(a))
    );
}

fn pnow_mm100(h: &mut Harness<Gateway>, a: u8) -> i32 {
    let r = read(h, unit(a), PNOW, 2).unwrap();
    ((u32::from(r[0]) << 16) | u32::from(r[1])) as i32
}

fn home(h: &mut Harness<Gateway>, a: u8) {
    write(h, unit(a), DRG1, &[DRG1_SON]).unwrap();
    settle(h, a, S);
    write(h, unit(a), DRG1, &[DRG1_SON | DRG1_HOME]).unwrap();
    assert_eq!(settle(h, a, 10 * S), (CommandState::Done, 0));
    write(h, unit(a), DRG1, &[DRG1_SON]).unwrap();
}

fn exchange(h: &mut Harness<Gateway>, req: [u16; 6]) -> Vec<u16> {
    write(h, 63, G_REQUEST, &req).unwrap();
    let until = h.now + 5 * S;
    let mut response = vec![0; 5];
    while h.now < until {
        h.run_until(h.now + 20 * MS);
        response = read(h, 63, G_RESPONSE, 5).unwrap();
        if response[0] != 0 {
            break;
        }
    }
    write(h, 63, G_REQUEST, &[0]).unwrap();
    response
}

/// G1: a READ request whose code the PLC clears while it runs becomes a WRITE of the value
/// registers (here 0) into the point table, with V5.
#[test]
fn g1_cleared_read_request_writes_the_point() {
    let mut h = gateway(1);
    let before = exchange(&mut h, [1, 0, 3, 0, 0, 0]);
    // read request, then the PLC gives up and clears the code at once
    write(&mut h, 63, G_REQUEST, &[1, 0, 3, 0, 0, 0]).unwrap();
    h.run_until(h.now + 5 * MS);
    write(&mut h, 63, G_REQUEST, &[0]).unwrap();
    for _ in 0..100 {
        h.run_until(h.now + 20 * MS);
        let _ = read(&mut h, 63, G_RESPONSE, 5);
    }
    write(&mut h, 63, G_REQUEST, &[0]).unwrap();
    let after = exchange(&mut h, [1, 0, 3, 0, 0, 0]);
    assert_eq!(
        before[2..4],
        after[2..4],
        "a cancelled READ rewrote point 3"
    );
}

/// G2: a second request with the same code overwrites the running one's block without any
/// validation; the gateway then answers/writes from the new block on the old read-back.
#[test]
fn g2_same_code_request_overwrites_running_request() {
    let mut h = gateway(1);
    // point 3 position = 40 mm; point 5 position = 0.
    let p3 = exchange(&mut h, [1, 0, 3, 0, 0, 0]);
    // write p5 := p3's value, but the request first names point 3 (a write that is a no-op),
    // and is then overwritten with the same code naming point 5.
    write(&mut h, 63, G_REQUEST, &[2, 0, 3, 0, p3[2], p3[3]]).unwrap();
    h.run_until(h.now + 5 * MS);
    let r = write(&mut h, 63, G_REQUEST, &[2, 0, 5, 0, p3[2], p3[3]]);
    let mut resp = vec![0; 5];
    for _ in 0..100 {
        h.run_until(h.now + 20 * MS);
        resp = read(&mut h, 63, G_RESPONSE, 5).unwrap();
        if resp[0] != 0 {
            break;
        }
    }
    write(&mut h, 63, G_REQUEST, &[0]).unwrap();
    let p5_after = exchange(&mut h, [1, 0, 5, 0, 0, 0]);
    // Either the second request is refused, or point 5 must now hold the value.
    assert!(
        r.is_err() || p5_after[2..4] == p3[2..4],
        "PLC told 'unchanged' but point 5 not written"
    );
    // also invalid data gets through while busy
    write(&mut h, 63, G_REQUEST, &[1, 0, 3, 0, 0, 0]).unwrap();
    let bad = write(&mut h, 63, G_REQUEST, &[1, 9, 99, 77, 0, 0]);
    assert!(bad.is_err(), "an invalid request block was accepted");
}

/// G3: STP on axis 0 after its `h` was accepted but before the `t`: axis 0 still starts.
#[test]
fn g3_sync_start_moves_a_paused_axis() {
    let mut h = gateway(2);
    home(&mut h, 0);
    home(&mut h, 1);
    write(&mut h, unit(0), POSR, &[3]).unwrap();
    write(&mut h, unit(1), POSR, &[3]).unwrap();
    write(&mut h, 63, G_SYNC_MASK, &[0b11]).unwrap();
    write(&mut h, 63, G_SYNC_START, &[1]).unwrap();
    // run until the `h` of axis 1 is on the wire (axis 0's `h` is answered by then)
    let until = h.now + S;
    while h.now < until {
        h.step(until);
        if h.sent.last().is_some_and(|(_, r)| {
            r.axis == axis(1) && matches!(r.command, protocol::Command::Buffer(_))
        }) {
            break;
        }
    }
    coil(&mut h, unit(0), COIL_STP, true).unwrap();
    for _ in 0..50 {
        h.run_until(h.now + 20 * MS);
        let _ = read(&mut h, 63, G_SYNC_STATUS, 1);
    }
    assert_eq!(
        read(&mut h, 63, G_SYNC_STATUS, 1).unwrap(),
        [3],
        "the start failed"
    );
    assert!(
        h.bus.controller(axis(0)).unwrap().buffered().is_none(),
        "axis 0's h cancelled"
    );
    assert_eq!(pnow_mm100(&mut h, 0), 0, "axis 0 moved while STP was on");
}

/// G4: a sync start that fails early leaves Q3 buffered in the other axes; a later sync start
/// of another axis (its `t` is received by all) moves them.
#[test]
fn g4_failed_sync_leaves_commands_buffered() {
    let mut h = gateway(3);
    for a in 0..3 {
        home(&mut h, a);
        write(&mut h, unit(a), POSR, &[3]).unwrap();
    }
    write(&mut h, 63, G_SYNC_MASK, &[0b111]).unwrap();
    write(&mut h, 63, G_SYNC_START, &[1]).unwrap();
    coil(&mut h, unit(1), COIL_STOP, true).unwrap(); // cancels axis 1's queued `h`
    for _ in 0..20 {
        h.run_until(h.now + 20 * MS);
        let _ = read(&mut h, 63, G_SYNC_STATUS, 1);
    }
    assert_eq!(read(&mut h, 63, G_SYNC_STATUS, 1).unwrap(), [3]);
    for a in 0..3 {
        assert!(
            h.bus.controller(axis(a)).unwrap().buffered().is_none(),
            "axis {a} still buffered"
        );
    }
    // Later: sync start of axis 1 alone.
    write(&mut h, 63, G_SYNC_MASK, &[0b010]).unwrap();
    write(&mut h, 63, G_SYNC_START, &[1]).unwrap();
    for _ in 0..200 {
        h.run_until(h.now + 20 * MS);
        let _ = read(&mut h, 63, G_SYNC_STATUS, 1);
    }
    assert_eq!(pnow_mm100(&mut h, 0), 0, "axis 0 (not in the mask) moved");
    assert_eq!(pnow_mm100(&mut h, 2), 0, "axis 2 (not in the mask) moved");
}

/// G5: while the channel is busy, an invalid block with the same code is accepted.
#[test]
fn g5_invalid_request_accepted_while_busy() {
    let mut h = gateway(1);
    write(&mut h, 63, G_REQUEST, &[1, 0, 3, 0, 0, 0]).unwrap();
    let bad = write(&mut h, 63, G_REQUEST, &[1, 9, 99, 77, 0, 0]);
    assert!(bad.is_err());
}
