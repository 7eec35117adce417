//! The status block, command edges and their status, validation (exceptions, and nothing
//! reaches the bus), the stop, the fail-safe watchdog, the synchronized start, the command
//! channel and the broadcast stop.

use protocol::memory::PointField;
use protocol::modbus::Exception;
use protocol::plc::map::*;
use protocol::plc::{CommandState, Reason};
use protocol::time::Instant;
use protocol::Request;
use rc_host::node_harness::{Answer, NodeHarness};

use crate::{axis, coil, exchange, gateway, home, pnow_mm100, read, settle, unit, write, MS, S};

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
    // Latched and the PLC talks again: no motion starts until it acknowledges (CMST: reason 12).
    write(&mut h, unit(0), DIRECT, &[0, 10_00, 0, 10, 0, 10_00, 30]).unwrap();
    assert_eq!(
        h.node.gateway().command_state(axis(0)),
        (CommandState::Failed, (Reason::Failsafe as u16) << 8)
    );
    write(&mut h, 63, G_FAILSAFE, &[0]).unwrap();
    assert_eq!(read(&mut h, 63, G_FAILSAFE, 1).unwrap(), [0]);
    write(&mut h, unit(0), DIRECT, &[0, 10_00, 0, 10, 0, 10_00, 30]).unwrap();
    h.run_until(h.now + 100 * MS);
    assert!(
        h.bus.controller(axis(0)).unwrap().moving(),
        "acknowledged: moves"
    );
    // The stop input latches bit 1.
    h.node.set_stop_input(Instant(h.now), true);
    assert_eq!(h.node.gateway().failsafe(), 2);
}

/// FAILSAFE is acknowledged as a safety relay's reset: refused (exception 03, the bit stays)
/// while the stop input is still open; once it is closed the latch still holds every motion
/// until the PLC acknowledges.
#[test]
fn the_fail_safe_is_acknowledged_only_once_the_stop_input_is_closed() {
    let mut h = gateway(1);
    home(&mut h, 0);
    h.node.set_stop_input(Instant(h.now), true);
    assert_eq!(
        write(&mut h, 63, G_FAILSAFE, &[0]),
        Err(Exception::IllegalDataValue),
        "the cause is still there"
    );
    assert_eq!(read(&mut h, 63, G_FAILSAFE, 1).unwrap(), [2]);
    h.node.set_stop_input(Instant(h.now), false);
    write(&mut h, unit(0), DIRECT, &[0, 50_00, 0, 10, 0, 20_00, 30]).unwrap();
    h.run_until(h.now + 300 * MS);
    assert!(
        !h.bus.controller(axis(0)).unwrap().moving(),
        "held by the latch"
    );
    assert_eq!(
        h.node.gateway().command_state(axis(0)),
        (CommandState::Failed, (Reason::Failsafe as u16) << 8)
    );
    write(&mut h, 63, G_FAILSAFE, &[0]).unwrap();
    assert_eq!(read(&mut h, 63, G_FAILSAFE, 1).unwrap(), [0]);
    write(&mut h, unit(0), DIRECT, &[0, 50_00, 0, 10, 0, 20_00, 30]).unwrap();
    h.run_until(h.now + 300 * MS);
    assert!(
        h.bus.controller(axis(0)).unwrap().moving(),
        "acknowledged: moves"
    );
}

/// With the watchdog's action "latch only" the PLC chose to keep the axes running: its latch
/// is shown but holds no motion.
#[test]
fn a_latch_only_watchdog_holds_no_motion() {
    let mut h = gateway(1);
    home(&mut h, 0);
    write(&mut h, 63, G_WD_ACTION, &[1]).unwrap();
    write(&mut h, 63, G_WATCHDOG, &[300]).unwrap();
    h.run_until(h.now + 600 * MS);
    assert_eq!(read(&mut h, 63, G_FAILSAFE, 1).unwrap(), [1], "latched");
    write(&mut h, unit(0), DIRECT, &[0, 50_00, 0, 10, 0, 20_00, 30]).unwrap();
    h.run_until(h.now + 200 * MS);
    assert!(h.bus.controller(axis(0)).unwrap().moving(), "not held");
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
    // 12.34 mm/s: 462 x 0.2 rpm with the 8 mm lead (462.75 truncated), which reads 12.32 mm/s.
    let first = exchange(&mut h, request(2, 1234));
    assert_eq!(first[0], 2, "{first:?}");
    assert!(
        first[4] >= 1 && first[4] != 0xFFFF,
        "written with V5: {first:?}"
    );
    let again = exchange(&mut h, request(2, 1234));
    assert_eq!(again[4], 0xFFFF, "same value: no V5 spent");
    let readback = exchange(&mut h, request(1, 0));
    assert_eq!((readback[0], readback[2], readback[3]), (1, 0, 1232));
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
