//! The PLC side against simulated controllers, in virtual time: the register map, command
//! edges and their status, validation (exceptions, and nothing reaches the bus), the fail-safe,
//! the synchronized start and the command channel. Requests are Modbus RTU frames to the
//! calls the Modbus slave makes.
#![allow(clippy::inconsistent_digit_grouping)]

use protocol::line::Baud;
use protocol::memory::PointField;
use protocol::modbus::Exception;
use protocol::node::Node;
use protocol::plc::map::*;
use protocol::plc::{AxisConfig, CommandState, GatewayConfig, Reason};
use protocol::time::Instant;
use protocol::units::{Lead, Length};
use protocol::{Axis, PositionNo, Request, Rtim};
use protocol::{AxisMap, AxisSet};
use rc_host::node_harness::{Answer, NodeHarness};
use rc_host::sim::realtime::bus_at_line;
use rc_host::sim::{BusConfig, ControllerConfig};

const MS: u64 = 1000;
const S: u64 = 1_000_000;

fn axis(n: u8) -> Axis {
    Axis::new(n).unwrap()
}

/// Axes 0..n at 115.2 kbit/s / RTIM 3 (no establishment), lead 8 mm like the simulator's
/// actuator, 100 mm stroke; point 3 of every axis stored at 40 mm.
fn gateway(n: u8) -> NodeHarness {
    gateway_with(n, 100_00, None, &[])
}

/// [`gateway`] with another stroke, another stored point 3 (wire values), and silent axes.
fn gateway_with(n: u8, stroke: i32, row3: Option<[u32; 10]>, silent: &[u8]) -> NodeHarness {
    let axes: Vec<Axis> = (0..n).map(axis).collect();
    let mut bus = bus_at_line(BusConfig::default(), &axes, Baud::B115200, Rtim::MIN);
    let mut config = GatewayConfig::new(AxisSet::first(n));
    config.bus.establish = false;
    config.axes = AxisMap::new(AxisConfig {
        scale: scale(),
        stroke: Length(stroke),
    });
    let mut row = [0u32; 10];
    row[0] = scale().position_to_wire(Length(40_00)).unwrap().to_wire();
    for &a in &axes {
        let mut controller = ControllerConfig {
            stored_line: Some((Baud::B115200, Rtim::MIN)),
            ..ControllerConfig::default()
        };
        controller.points = vec![(PositionNo::new(3).unwrap(), row3.unwrap_or(row))];
        bus.add_controller(a, controller);
    }
    for &a in silent {
        bus.set_silent(axis(a), true);
    }
    let mut h = NodeHarness::new(Node::new(config), bus);
    h.run_until(300 * MS);
    h
}

/// The simulator's actuator (8 mm lead) with the gateway's default conventions.
fn scale() -> protocol::units::Scale {
    protocol::units::Scale {
        lead: Lead::from_hundredths(800).unwrap(),
        ..AxisConfig::default().scale
    }
}

fn unit(a: u8) -> u8 {
    a + 1
}

fn write(h: &mut NodeHarness, unit: u8, address: u16, values: &[u16]) -> Result<(), Exception> {
    h.write(unit, address, values)
}

fn read(h: &mut NodeHarness, unit: u8, address: u16, n: usize) -> Result<Vec<u16>, Exception> {
    h.read(unit, address, n as u16)
}

fn coil(h: &mut NodeHarness, unit: u8, address: u16, on: bool) -> Result<(), Exception> {
    h.write_coil(unit, address, on)
}

/// Keep "polling" like a PLC (so the watchdog stays quiet) until the command of `a` settles.
fn settle(h: &mut NodeHarness, a: u8, timeout: u64) -> (CommandState, u16) {
    let until = h.now + timeout;
    while h.now < until {
        h.run_until(h.now + 50 * MS);
        let _ = read(h, unit(a), CMST, 1);
        let state = h.node.gateway().command_state(axis(a));
        if matches!(state.0, CommandState::Done | CommandState::Failed) {
            return state;
        }
    }
    panic!(
        "axis {a}: command did not settle: {:?}",
        h.node.gateway().command_state(axis(a))
    );
}

fn pnow_mm100(h: &mut NodeHarness, a: u8) -> i32 {
    let r = read(h, unit(a), PNOW, 2).unwrap();
    ((u32::from(r[0]) << 16) | u32::from(r[1])) as i32
}

fn home(h: &mut NodeHarness, a: u8) {
    write(h, unit(a), DRG1, &[DRG1_SON]).unwrap();
    settle(h, a, S);
    write(h, unit(a), DRG1, &[DRG1_SON | DRG1_HOME]).unwrap();
    assert_eq!(settle(h, a, 10 * S), (CommandState::Done, 0));
    write(h, unit(a), DRG1, &[DRG1_SON]).unwrap();
}

/// One command-channel exchange (ROBONET's five steps): write the request, wait for the
/// response, clear the request, and check that the gateway cleared the response.
fn exchange(h: &mut NodeHarness, request: [u16; 6]) -> Vec<u16> {
    write(h, 63, G_REQUEST, &request).unwrap();
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
    assert_eq!(
        read(h, 63, G_RESPONSE, 1).unwrap(),
        [0],
        "step 5: response cleared"
    );
    response
}

#[test]
fn status_block_follows_the_axis() {
    let mut h = gateway(1);
    let block = read(&mut h, unit(0), PNOW, 8).unwrap();
    let (dss1, dopm) = (block[5], block[4]);
    assert_ne!(dss1 & (1 << 12), 0, "SV: servo on at power-up");
    assert_ne!(dss1 & (1 << 13), 0, "PWR");
    assert_eq!(dss1 & (1 << 4), 0, "HEND off before homing");
    assert_ne!(dopm & (1 << 14), 0, "*ALM on: no alarm");
    home(&mut h, 0);
    let block = read(&mut h, unit(0), PNOW, 8).unwrap();
    assert_ne!(block[5] & (1 << 4), 0, "HEND after homing");
    assert_eq!(read(&mut h, unit(0), LINK, 1).unwrap(), [1]);
    // FC04 reads the same status registers; DRG1 is a holding register only.
    assert!(h.read_registers(unit(0), DSS1, 1, true).is_ok());
    assert_eq!(
        h.read_registers(unit(0), DRG1, 1, true),
        Err(Exception::IllegalDataAddress)
    );
}

#[test]
fn cstr_moves_to_posr_and_direct_move_goes_to_the_millimetre() {
    let mut h = gateway(1);
    home(&mut h, 0);
    write(&mut h, unit(0), POSR, &[3]).unwrap();
    write(&mut h, unit(0), DRG1, &[DRG1_SON | DRG1_CSTR]).unwrap();
    assert_eq!(settle(&mut h, 0, 10 * S), (CommandState::Done, 0));
    assert_eq!(pnow_mm100(&mut h, 0), 40_00, "point 3 is 40 mm");
    let dopm = read(&mut h, unit(0), DOPM, 1).unwrap()[0];
    assert_eq!(dopm & 0xF, 3, "PM shows the completed position");
    // Direct numeric move: 62.50 mm at 50 mm/s, 0.3 G.
    let [phi, plo] = [0u16, 62_50];
    write(&mut h, unit(0), DIRECT, &[phi, plo, 0, 10, 0, 50_00, 30]).unwrap();
    assert_eq!(settle(&mut h, 0, 10 * S), (CommandState::Done, 0));
    assert_eq!(pnow_mm100(&mut h, 0), 62_50);
    // Incremental: -12.5 mm.
    let d = (-12_50i32) as u32;
    write(
        &mut h,
        unit(0),
        DIRECT,
        &[(d >> 16) as u16, d as u16, 0, 10, 0, 50_00, 30, 0, 1 << 3],
    )
    .unwrap();
    assert_eq!(settle(&mut h, 0, 10 * S), (CommandState::Done, 0));
    assert_eq!(pnow_mm100(&mut h, 0), 50_00);
    assert_eq!(
        read(&mut h, unit(0), CMCT, 1).unwrap(),
        [5],
        "SON, HOME, CSTR, 2 direct moves"
    );
}

#[test]
fn invalid_requests_get_exceptions_and_never_reach_the_bus() {
    let mut h = gateway(1);
    home(&mut h, 0);
    h.run_until(h.now + 100 * MS);
    let sent_before = h.sent.len();
    let motion = |h: &NodeHarness| {
        h.sent[sent_before..]
            .iter()
            .filter(|(_, r): &&(u64, Request)| {
                r.command.moves()
                    || matches!(
                        r.command,
                        protocol::Command::Servo(_)
                            | protocol::Command::SetVelocityAcceleration { .. }
                    )
            })
            .count()
    };
    let bad: [(u16, &[u16], Exception); 8] = [
        (DRG1, &[DRG1_SON | 1 << 7], Exception::IllegalDataValue), // BKRL
        (POSR, &[16], Exception::IllegalDataValue),
        (
            DIRECT,
            &[0, 100_01, 0, 10, 0, 50_00, 30],
            Exception::IllegalDataValue,
        ), // past the stroke
        (
            DIRECT,
            &[0, 10_00, 0, 10, 0, 0, 30],
            Exception::IllegalDataValue,
        ), // zero speed
        (
            DIRECT,
            &[0, 10_00, 0, 10, 0, 50_00, 30, 50, 0],
            Exception::IllegalDataValue,
        ), // push
        (DIRECT, &[0, 10_00, 0, 10], Exception::IllegalDataAddress), // too short
        (PNOW, &[1], Exception::IllegalDataValue),                   // read-only
        (0x1234, &[1], Exception::IllegalDataAddress),
    ];
    for (address, values, exception) in bad {
        assert_eq!(
            write(&mut h, unit(0), address, values),
            Err(exception),
            "{address:#06X} {values:?}"
        );
    }
    assert_eq!(
        coil(&mut h, unit(0), 0x0404, true),
        Err(Exception::IllegalDataAddress)
    );
    assert_eq!(
        write(&mut h, 63, G_WATCHDOG, &[10]),
        Err(Exception::IllegalDataValue)
    );
    assert_eq!(
        write(&mut h, 63, G_AXIS_CONFIG + 2, &[9]),
        Err(Exception::IllegalDataValue)
    );
    // A request to a unit that is not served is ignored by the slave: no answer.
    assert_eq!(
        h.request(
            unit(5),
            &protocol::modbus::Request::ReadHoldingRegisters {
                address: PNOW,
                quantity: 1
            }
        ),
        Answer::Silence
    );
    h.run_until(h.now + 200 * MS);
    assert_eq!(
        motion(&h),
        0,
        "no command from an invalid request reached the bus"
    );
    assert_eq!(
        read(&mut h, unit(0), DRG1, 1).unwrap(),
        [DRG1_SON],
        "state untouched"
    );
}

#[test]
fn stp_stops_and_blocks_motion_and_the_stop_coil_stops() {
    let mut h = gateway(1);
    home(&mut h, 0);
    write(&mut h, unit(0), DIRECT, &[0, 90_00, 0, 10, 0, 20_00, 30]).unwrap();
    h.run_until(h.now + 300 * MS);
    assert!(h.bus.controller(axis(0)).unwrap().moving());
    coil(&mut h, unit(0), COIL_STP, true).unwrap();
    h.run_until(h.now + 500 * MS);
    assert!(!h.bus.controller(axis(0)).unwrap().moving(), "paused");
    // While STP is on, nothing may start.
    write(&mut h, unit(0), DRG1, &[DRG1_SON | DRG1_STP | DRG1_CSTR]).unwrap();
    assert_eq!(
        h.node.gateway().command_state(axis(0)),
        (CommandState::Failed, (Reason::Paused as u16) << 8)
    );
    let dss1 = read(&mut h, unit(0), DSS1, 1).unwrap()[0];
    assert_ne!(dss1 & (1 << 5), 0, "STP shown in DSS1");
    coil(&mut h, unit(0), COIL_STP, false).unwrap();
    write(&mut h, unit(0), DIRECT, &[0, 90_00, 0, 10, 0, 20_00, 30]).unwrap();
    h.run_until(h.now + 300 * MS);
    assert!(h.bus.controller(axis(0)).unwrap().moving());
    coil(&mut h, unit(0), COIL_STOP, true).unwrap();
    h.run_until(h.now + 500 * MS);
    assert!(!h.bus.controller(axis(0)).unwrap().moving(), "STOP coil");
    assert_eq!(
        h.read_coils(unit(0), COIL_STOP, 1).unwrap(),
        [false],
        "STOP reads 0"
    );
}

#[test]
fn plc_silence_trips_the_watchdog_and_stops_every_axis() {
    let mut h = gateway(2);
    home(&mut h, 0);
    home(&mut h, 1);
    write(&mut h, 63, G_WATCHDOG, &[300]).unwrap();
    for a in 0..2 {
        write(&mut h, unit(a), DIRECT, &[0, 95_00, 0, 10, 0, 10_00, 30]).unwrap();
    }
    h.run_until(h.now + 200 * MS);
    assert!(
        h.bus.controller(axis(0)).unwrap().moving() && h.bus.controller(axis(1)).unwrap().moving()
    );
    // The PLC goes quiet: within 300 ms + a stop transaction both axes are stopped.
    h.run_until(h.now + 600 * MS);
    for a in 0..2 {
        let c = h.bus.controller(axis(a)).unwrap();
        assert!(!c.moving(), "axis {a} stopped");
        assert!(c.position() > -9_500, "axis {a} stopped short of 95 mm");
    }
    assert_eq!(
        read(&mut h, 63, G_FAILSAFE, 2).unwrap(),
        [1, 1],
        "latched, counted"
    );
    write(&mut h, 63, G_FAILSAFE, &[0]).unwrap();
    assert_eq!(read(&mut h, 63, G_FAILSAFE, 1).unwrap(), [0]);
    // The stop input latches bit 1.
    h.node.set_stop_input(Instant(h.now), true);
    assert_eq!(h.node.gateway().failsafe(), 2);
}

#[test]
fn synchronized_start_of_two_axes() {
    let mut h = gateway(3);
    home(&mut h, 0);
    home(&mut h, 2);
    write(&mut h, unit(0), POSR, &[3]).unwrap();
    write(&mut h, unit(2), POSR, &[3]).unwrap();
    write(&mut h, 63, G_SYNC_MASK, &[0b101]).unwrap();
    write(&mut h, 63, G_SYNC_START, &[1]).unwrap();
    let until = h.now + 10 * S;
    while h.now < until && read(&mut h, 63, G_SYNC_STATUS, 1).unwrap()[0] == 1 {
        h.run_until(h.now + 20 * MS);
    }
    assert_eq!(read(&mut h, 63, G_SYNC_STATUS, 1).unwrap(), [2]);
    let (c0, c2) = (
        h.bus.controller(axis(0)).unwrap(),
        h.bus.controller(axis(2)).unwrap(),
    );
    assert!(c0.last_move_start().is_some());
    assert_eq!(c0.last_move_start(), c2.last_move_start());
    h.run_until(h.now + 5 * S);
    assert_eq!(pnow_mm100(&mut h, 2), 40_00);
    assert_eq!(
        write(&mut h, 63, G_SYNC_MASK, &[0b1000]),
        Err(Exception::IllegalDataValue),
        "axis 3 is not configured"
    );
}

#[test]
fn command_channel_writes_once_and_skips_unchanged_data() {
    let mut h = gateway(1);
    let stores = |h: &NodeHarness| h.bus.controller(axis(0)).unwrap().stats().clone();
    let v5_before = format!("{:?}", stores(&h));
    let field = (PointField::Velocity.address().0 - 0x400) as u16;
    let request = |code: u16, value: u32| [code, 0, 5, field, (value >> 16) as u16, value as u16];
    let first = exchange(&mut h, request(2, 1234));
    assert_eq!(first[0], 2, "{first:?}");
    assert!(
        first[4] >= 1 && first[4] != 0xFFFF,
        "written with V5: {first:?}"
    );
    let again = exchange(&mut h, request(2, 1234));
    assert_eq!(again[4], 0xFFFF, "same value: no V5 spent");
    let readback = exchange(&mut h, request(1, 0));
    assert_eq!((readback[0], readback[2], readback[3]), (1, 0, 1234));
    assert_ne!(format!("{:?}", stores(&h)), v5_before);
    // A request while the response is not cleared is refused.
    write(&mut h, 63, G_REQUEST, &[1, 0, 5, field, 0, 0]).unwrap();
    assert_eq!(
        write(&mut h, 63, G_REQUEST, &[2, 0, 5, field, 0, 1]),
        Err(Exception::ServerDeviceFailure)
    );
    // Invalid requests: axis not configured, point 16, unknown field.
    write(&mut h, 63, G_REQUEST, &[0]).unwrap();
    for bad in [
        [1, 4, 0, 0, 0, 0],
        [1, 0, 16, 0, 0, 0],
        [1, 0, 0, 2, 0, 0],
        [9, 0, 0, 0, 0, 0],
    ] {
        h.run_until(h.now + 200 * MS);
        write(&mut h, 63, G_REQUEST, &[0]).unwrap();
        assert_eq!(
            write(&mut h, 63, G_REQUEST, &bad),
            Err(Exception::IllegalDataValue),
            "{bad:?}"
        );
    }
}

#[test]
fn a_broadcast_stop_coil_stops_every_axis() {
    let mut h = gateway(3);
    for a in 0..3 {
        home(&mut h, a);
        write(&mut h, unit(a), DIRECT, &[0, 90_00, 0, 10, 0, 20_00, 30]).unwrap();
    }
    h.run_until(h.now + 300 * MS);
    assert!((0..3).all(|a| h.bus.controller(axis(a)).unwrap().moving()));
    h.write_coil(0, COIL_STOP, true).unwrap();
    h.run_until(h.now + 500 * MS);
    assert!((0..3).all(|a| !h.bus.controller(axis(a)).unwrap().moving()));
    // Only DRG1, POSR and coils can be broadcast; bad values are refused before any effect
    // (a broadcast is never answered: the refusals are counted).
    let refused = h.node.plc_counters().broadcast_errors;
    let sent = h.sent.len();
    write(&mut h, 0, DIRECT, &[0, 1, 0, 10, 0, 20_00, 30]).unwrap();
    write(&mut h, 0, POSR, &[16]).unwrap();
    assert_eq!(h.node.plc_counters().broadcast_errors, refused + 2);
    h.run_until(h.now + 100 * MS);
    assert!(
        h.sent[sent..].iter().all(|(_, r)| !r.command.moves()),
        "no move from a refused broadcast"
    );
    assert!((0..3).all(|a| read(&mut h, unit(a), POSR, 1).unwrap() == [0]));
    write(&mut h, 0, POSR, &[3]).unwrap();
    assert!((0..3).all(|a| read(&mut h, unit(a), POSR, 1).unwrap() == [3]));
}

// ---------------------------------------------------------------- regressions found by review (each failed before its fix)

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

#[test]
fn bus_settings_watchdog_action_and_link_counters() {
    let mut h = gateway(1);
    // Line settings: validated, taken on APPLY (which runs the establishment procedure).
    assert_eq!(read(&mut h, 63, G_BUS_BAUD, 3).unwrap(), [1152, 3, 2]);
    assert_eq!(
        write(&mut h, 63, G_BUS_BAUD, &[1000]),
        Err(Exception::IllegalDataValue)
    );
    assert_eq!(
        write(&mut h, 63, G_BUS_RTIM, &[2]),
        Err(Exception::IllegalDataValue)
    );
    assert_eq!(
        write(&mut h, 63, G_RETRIES, &[4]),
        Err(Exception::IllegalDataValue)
    );
    write(&mut h, 63, G_RETRIES, &[1]).unwrap();
    assert_eq!(h.node.gateway().engine().config().retries, 1);
    write(&mut h, 63, G_BUS_BAUD, &[384, 10]).unwrap();
    assert_eq!(
        h.node.gateway().engine().line_baud(),
        Baud::B115200,
        "not before APPLY"
    );
    write(&mut h, 63, G_APPLY, &[1]).unwrap();
    assert!(h.node.gateway().engine().establishing());
    for _ in 0..40 {
        h.run_until(h.now + 100 * MS);
        let _ = read(&mut h, 63, G_VERSION, 1);
    }
    let c = h.bus.controller(axis(0)).unwrap();
    assert_eq!((c.baud(), c.rtim_ms()), (Baud::B38400, 10));
    assert_eq!(h.node.gateway().engine().line_baud(), Baud::B38400);
    assert_eq!(read(&mut h, unit(0), LINK, 1).unwrap(), [1]);
    // Watchdog action "latch only": the event is latched, nothing is stopped.
    write(&mut h, 63, G_WD_ACTION, &[1]).unwrap();
    write(&mut h, 63, G_WATCHDOG, &[100]).unwrap();
    let stops_before = h
        .sent
        .iter()
        .filter(|(_, r)| r.command == protocol::Command::CancelMotion)
        .count();
    h.run_until(h.now + 500 * MS);
    assert_eq!(read(&mut h, 63, G_FAILSAFE, 1).unwrap(), [1]);
    let stops = h
        .sent
        .iter()
        .filter(|(_, r)| r.command == protocol::Command::CancelMotion)
        .count();
    assert_eq!(stops, stops_before, "latch only: no stop sent");
    assert_eq!(
        write(&mut h, 63, G_PIO_AXIS, &[16]),
        Err(Exception::IllegalDataValue)
    );
    write(&mut h, 63, G_PIO_AXIS, &[0]).unwrap();
    assert_eq!(h.node.gateway().config().pio_axis, Some(axis(0)));
    // PLC-link counters are the node's own slave's: a frame with a bad CRC is counted, and the
    // frames counted so far include this very read's predecessors.
    h.node.plc_received(
        Instant(h.now),
        &[0x3F, 0x03, 0x00, 0x00, 0x00, 0x01, 0x00, 0x00],
    );
    h.run_until(h.now + 10 * MS);
    let frames = h.node.plc_counters().frames;
    let [hi, lo] = [(frames >> 16) as u16, frames as u16];
    assert_eq!(read(&mut h, 63, G_PLC, 4).unwrap(), [hi, lo, 0, 1]);
}

#[test]
fn position_table_rows_read_on_demand_and_written_whole() {
    let mut h = gateway(1);
    let row = |n: u16| 0x1000 + 16 * n;
    // Not read yet: exception 04 while the gateway fetches it, then the row.
    assert_eq!(
        read(&mut h, unit(0), row(3), 16),
        Err(Exception::ServerDeviceFailure)
    );
    h.run_until(h.now + 200 * MS);
    let r3 = read(&mut h, unit(0), row(3), 16).unwrap();
    assert_eq!((r3[0], r3[1]), (0, 40_00), "PCMD 40.00 mm");
    // Write row 5: 62.50 mm, band 0.10 mm, 80 mm/s, 0.3 G (DCMD = ACMD).
    let mut values = [0u16; 16];
    values[1] = 62_50;
    values[3] = 10;
    values[5] = 80_00;
    values[10] = 30;
    values[11] = 30;
    write(&mut h, unit(0), row(5), &values).unwrap();
    // A PLC sees the row stored by reading it back (04 until the verified row is there).
    let mut r5 = Err(Exception::ServerDeviceFailure);
    for _ in 0..100 {
        h.run_until(h.now + 20 * MS);
        r5 = read(&mut h, unit(0), row(5), 16);
        if r5.is_ok() {
            break;
        }
    }
    let r5 = r5.unwrap();
    assert_eq!(
        (r5[1], r5[3], r5[5], r5[10], r5[11]),
        (62_50, 10, 80_00, 30, 30),
        "{r5:?}"
    );
    // The same row again: nothing is written (no command taken, no V5).
    let taken = read(&mut h, unit(0), CMCT, 1).unwrap();
    write(&mut h, unit(0), row(5), &values).unwrap();
    assert_eq!(read(&mut h, unit(0), CMCT, 1).unwrap(), taken);
    // CSTR to point 5 goes there.
    home(&mut h, 0);
    write(&mut h, unit(0), POSR, &[5]).unwrap();
    write(&mut h, unit(0), DRG1, &[DRG1_SON | DRG1_CSTR]).unwrap();
    assert_eq!(settle(&mut h, 0, 10 * S), (CommandState::Done, 0));
    assert_eq!(pnow_mm100(&mut h, 0), 62_50);
    // Refused: part of a row, an unsupported field, beyond the stroke.
    assert_eq!(
        write(&mut h, unit(0), row(5) + 2, &[0, 10]),
        Err(Exception::IllegalDataAddress)
    );
    let mut zoned = values;
    zoned[7] = 1;
    assert_eq!(
        write(&mut h, unit(0), row(6), &zoned),
        Err(Exception::IllegalDataValue)
    );
    let mut far = values;
    far[0] = 1;
    assert_eq!(
        write(&mut h, unit(0), row(6), &far),
        Err(Exception::IllegalDataValue)
    );
}

// ---------------------------------------------------------------- regressions from a second review

const ROW3: u16 = 0x1000 + 16 * 3;

/// Row registers: `pcmd` (0.01 mm), band 0.10 mm, 80 mm/s, 0.3 G.
fn row_regs(pcmd: u32) -> [u16; 16] {
    let mut v = [0u16; 16];
    v[0] = (pcmd >> 16) as u16;
    v[1] = pcmd as u16;
    v[3] = 10;
    v[5] = 80_00;
    v[10] = 30;
    v[11] = 30;
    v
}

/// The same row in the controller's units, as a point write stores it.
fn row_wire(pcmd: i32) -> [u32; 10] {
    use protocol::units::{Accel, Speed};
    let s = scale();
    let mut r = [0u32; 10];
    r[0] = s.position_to_wire(Length(pcmd)).unwrap().to_wire();
    r[1] = 0xC0;
    r[3] = s.band_to_wire(Length(10)).unwrap();
    r[4] = s.velocity(Speed(80_00)).unwrap().get().into();
    r[5] = s.acceleration(Accel(30)).unwrap().get().into();
    r
}

/// Point `p`'s stored position on the controller, pulses.
fn stored_pos(h: &NodeHarness, a: u8, p: usize) -> i32 {
    h.bus.controller(axis(a)).unwrap().memory().nv.points[p][0] as i32
}

fn stored_mm100(pcmd: i32) -> i32 {
    scale().position_to_wire(Length(pcmd)).unwrap().0
}

/// A table read that started before a write must not put the old row back in the cache (a
/// later write of the old values would then be skipped).
#[test]
fn a_read_started_before_a_write_does_not_refill_the_cache() {
    let mut h = gateway_with(1, 100_00, Some(row_wire(40_00)), &[]);
    assert_eq!(
        read(&mut h, unit(0), ROW3, 16),
        Err(Exception::ServerDeviceFailure)
    );
    write(&mut h, unit(0), ROW3, &row_regs(60_00)).unwrap();
    h.run_until(h.now + 3 * S);
    let _ = read(&mut h, unit(0), ROW3, 16);
    h.run_until(h.now + 300 * MS);
    write(&mut h, unit(0), ROW3, &row_regs(40_00)).unwrap();
    h.run_until(h.now + 3 * S);
    assert_eq!(
        stored_pos(&h, 0, 3),
        stored_mm100(40_00),
        "the PLC's last write wins"
    );
}

/// A command-channel write the PLC abandons still invalidates the table's cached row.
#[test]
fn an_abandoned_channel_write_invalidates_the_cached_row() {
    let mut h = gateway_with(1, 100_00, Some(row_wire(40_00)), &[]);
    let _ = read(&mut h, unit(0), ROW3, 16);
    h.run_until(h.now + 200 * MS);
    assert!(read(&mut h, unit(0), ROW3, 16).is_ok());
    let x = stored_mm100(60_00) as u32;
    write(
        &mut h,
        63,
        G_REQUEST,
        &[2, 0, 3, 0, (x >> 16) as u16, x as u16],
    )
    .unwrap();
    let sent0 = h.sent.len();
    for _ in 0..200 {
        h.run_until(h.now + MS);
        if h.sent[sent0..]
            .iter()
            .any(|(_, r)| matches!(r.command, protocol::Command::WriteMemory { .. }))
        {
            break;
        }
    }
    write(&mut h, 63, G_REQUEST, &[0]).unwrap();
    h.run_until(h.now + 2 * S);
    assert_eq!(
        stored_pos(&h, 0, 3),
        stored_mm100(60_00),
        "the channel write happened"
    );
    write(&mut h, unit(0), ROW3, &row_regs(40_00)).unwrap();
    h.run_until(h.now + 2 * S);
    assert_eq!(
        stored_pos(&h, 0, 3),
        stored_mm100(40_00),
        "not skipped against a stale row"
    );
}

/// APPLY (a break and the whole establishment, during which no stop reaches an axis) is
/// refused while anything moves, runs or waits, or while an establishment runs.
#[test]
fn apply_is_refused_unless_the_bus_is_idle() {
    let mut h = gateway_with(2, 100_00, None, &[1]);
    home(&mut h, 0);
    write(&mut h, unit(0), DIRECT, &[0, 95_00, 0, 10, 0, 5_00, 30]).unwrap();
    h.run_until(h.now + 200 * MS);
    assert_eq!(
        write(&mut h, 63, G_APPLY, &[1]),
        Err(Exception::IllegalDataValue)
    );
    coil(&mut h, unit(0), COIL_STOP, true).unwrap();
    h.run_until(h.now + 500 * MS);
    write(&mut h, 63, G_BUS_BAUD, &[384]).unwrap();
    write(&mut h, 63, G_APPLY, &[1]).unwrap();
    h.run_until(h.now + 300 * MS);
    assert!(h.node.gateway().engine().establishing());
    assert_eq!(
        write(&mut h, 63, G_APPLY, &[1]),
        Err(Exception::IllegalDataValue),
        "not twice"
    );
    for _ in 0..60 {
        h.run_until(h.now + 100 * MS);
        let _ = read(&mut h, 63, G_VERSION, 1);
    }
    assert_eq!(h.bus.controller(axis(0)).unwrap().baud(), Baud::B38400);
    assert_eq!(read(&mut h, unit(0), LINK, 1).unwrap(), [1]);
}

/// A relative direct move is checked from where the axis is: only from rest with nothing
/// queued (else it would run from the end of the queued move, past the stroke).
#[test]
fn a_relative_move_behind_another_is_refused() {
    let mut h = gateway_with(1, 60_00, None, &[]);
    home(&mut h, 0);
    write(&mut h, unit(0), DIRECT, &[0, 55_00, 0, 10, 0, 50_00, 30]).unwrap();
    let relative = [0, 40_00, 0, 10, 0, 50_00, 30, 0, 1 << 3];
    assert_eq!(
        write(&mut h, unit(0), DIRECT, &relative),
        Err(Exception::ServerDeviceFailure)
    );
    assert_eq!(settle(&mut h, 0, 10 * S), (CommandState::Done, 0));
    assert_eq!(
        write(&mut h, unit(0), DIRECT, &relative),
        Err(Exception::IllegalDataValue),
        "55 + 40 > 60 mm"
    );
    assert!(pnow_mm100(&mut h, 0) <= 60_00);
}

/// Invalid reads of the table (FC04, or a range starting at an undefined address) get 02 and
/// put nothing on the bus.
#[test]
fn invalid_table_reads_never_reach_the_bus() {
    let mut h = gateway(1);
    h.run_until(h.now + 50 * MS);
    let before = h.sent.len();
    assert_eq!(
        h.read_registers(unit(0), ROW3, 16, true),
        Err(Exception::IllegalDataAddress)
    );
    assert_eq!(
        h.read(unit(0), 0x0FFF, 2),
        Err(Exception::IllegalDataAddress)
    );
    h.run_until(h.now + 200 * MS);
    let q1 = h.sent[before..]
        .iter()
        .filter(|(_, r)| matches!(r.command, protocol::Command::LoadToEdit(_)))
        .count();
    assert_eq!(q1, 0);
}

/// A failed synchronized start may leave an `h` queued behind a move; a new start is refused
/// until it is out of the way, so it can never be taken for the new start's.
#[test]
fn a_sync_restart_waits_for_the_old_attempt() {
    let mut h = gateway_with(3, 100_00, None, &[]);
    for a in 0..3 {
        home(&mut h, a);
        write(&mut h, unit(a), POSR, &[3]).unwrap();
    }
    write(&mut h, unit(0), DIRECT, &[0, 20_00, 0, 10, 0, 5_00, 30]).unwrap();
    write(&mut h, unit(2), DIRECT, &[0, 30_00, 0, 10, 0, 5_00, 30]).unwrap();
    h.run_until(h.now + 100 * MS);
    write(&mut h, 63, G_SYNC_MASK, &[0b111]).unwrap();
    write(&mut h, 63, G_SYNC_START, &[1]).unwrap();
    coil(&mut h, unit(1), COIL_STOP, true).unwrap();
    h.run_until(h.now + 100 * MS);
    assert_eq!(read(&mut h, 63, G_SYNC_STATUS, 1).unwrap(), [3]);
    write(&mut h, 63, G_SYNC_MASK, &[0b100]).unwrap();
    assert_eq!(
        write(&mut h, 63, G_SYNC_START, &[1]),
        Err(Exception::ServerDeviceFailure)
    );
    // Once the old `h`s are done (and cancelled), the start goes ahead for axis 2 alone.
    let mut started = false;
    for _ in 0..600 {
        h.run_until(h.now + 20 * MS);
        if !started {
            started = write(&mut h, 63, G_SYNC_START, &[1]).is_ok();
        }
    }
    assert!(started);
    assert_eq!(read(&mut h, 63, G_SYNC_STATUS, 1).unwrap(), [2]);
    assert_eq!(
        pnow_mm100(&mut h, 0),
        20_00,
        "axis 0 (not in the mask) did not move"
    );
    assert_eq!(pnow_mm100(&mut h, 2), 40_00);
}

/// A table write does not take over CMST (nor unmask PEND of a starting move).
#[test]
fn a_table_write_leaves_the_command_status_alone() {
    let mut h = gateway_with(1, 100_00, Some(row_wire(40_00)), &[]);
    home(&mut h, 0);
    write(&mut h, unit(0), POSR, &[3]).unwrap();
    write(&mut h, unit(0), DRG1, &[DRG1_SON | DRG1_CSTR]).unwrap();
    let before = read(&mut h, unit(0), CMST, 4).unwrap();
    write(&mut h, unit(0), 0x1000 + 16 * 5, &row_regs(10_00)).unwrap();
    assert_eq!(read(&mut h, unit(0), CMST, 4).unwrap(), before);
    assert_eq!(
        read(&mut h, unit(0), DSS1, 1).unwrap()[0] >> 3 & 1,
        0,
        "PEND off while starting"
    );
}

/// SON held: the servo an alarm reset turned off comes back on, without a command in CMST.
#[test]
fn held_son_turns_the_servo_back_on_without_touching_cmst() {
    let mut h = gateway(1);
    home(&mut h, 0);
    h.bus
        .inject_alarm(axis(0), protocol::alarm::AlarmCode(0xC0))
        .unwrap();
    h.run_until(h.now + 100 * MS);
    write(&mut h, unit(0), DRG1, &[DRG1_SON | DRG1_ALRS]).unwrap();
    assert_eq!(settle(&mut h, 0, 2 * S), (CommandState::Done, 0));
    let status = read(&mut h, unit(0), CMST, 4).unwrap();
    for _ in 0..60 {
        h.run_until(h.now + 50 * MS);
        let _ = read(&mut h, unit(0), CMST, 1);
    }
    assert!(h.bus.controller(axis(0)).unwrap().servo(), "servo back on");
    assert_eq!(
        read(&mut h, unit(0), CMST, 4).unwrap(),
        status,
        "CMST/CMCT untouched"
    );
}

/// A row read and written back unchanged costs no write (no V5), whatever the rounding.
#[test]
fn writing_back_a_row_as_read_writes_nothing() {
    let mut h = gateway_with(1, 100_00, Some(row_wire(33_33)), &[]);
    let _ = read(&mut h, unit(0), ROW3, 16);
    h.run_until(h.now + 200 * MS);
    let row = read(&mut h, unit(0), ROW3, 16).unwrap();
    let sent = h.sent.len();
    write(&mut h, unit(0), ROW3, &row).unwrap();
    h.run_until(h.now + 500 * MS);
    let writes = h.sent[sent..]
        .iter()
        .filter(|(_, r)| matches!(r.command, protocol::Command::WriteMemory { .. }))
        .count();
    assert_eq!(writes, 0);
}

/// Reading the table of an offline axis does not put its frames on the bus.
#[test]
fn the_table_of_an_offline_axis_is_not_fetched() {
    let mut h = gateway_with(2, 100_00, None, &[1]);
    h.run_until(2 * S);
    let s0 = h.sent.len();
    for _ in 0..200 {
        h.run_until(h.now + 10 * MS);
        assert_eq!(
            read(&mut h, unit(1), ROW3, 16),
            Err(Exception::ServerDeviceFailure)
        );
    }
    let jobs = h.sent[s0..]
        .iter()
        .filter(|(_, r)| r.axis == axis(1) && r.command != protocol::Command::Status)
        .count();
    assert_eq!(jobs, 0, "no point-table frames to the dead axis");
    let polls0 = h.sent[s0..]
        .iter()
        .filter(|(_, r)| r.axis == axis(0) && r.command == protocol::Command::Status)
        .count();
    assert!(polls0 > 150, "the live axis keeps its cycle: {polls0}");
}
