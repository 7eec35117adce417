//! The synchronized start when it fails: an axis paused between its `h` and the `t` (G3), the
//! `h`s a failed start leaves buffered (G4; both regressions found by review, each failed before
//! its fix), and a restart that waits for the old attempt.

use protocol::modbus::Exception;
use protocol::plc::map::*;

use crate::{axis, coil, gateway, gateway_with, home, pnow_mm100, read, unit, write, MS, S};

/// Axes 0 and 1 homed, both POSR 3, a synchronized start of both written, and run until the
/// `h` of axis `a` is on the wire.
fn sync_start_until_h_of(a: u8) -> rc_host::node_harness::NodeHarness {
    let mut h = gateway(2);
    for n in 0..2 {
        home(&mut h, n);
        write(&mut h, unit(n), POSR, &[3]).unwrap();
    }
    write(&mut h, 63, G_SYNC_MASK, &[0b11]).unwrap();
    write(&mut h, 63, G_SYNC_START, &[1]).unwrap();
    let until = h.now + S;
    while h.now < until {
        h.step(until);
        if h.sent.last().is_some_and(|(_, r)| {
            r.axis == axis(a) && matches!(r.command, protocol::Command::Buffer(_))
        }) {
            break;
        }
    }
    h
}

/// G3: STP on axis 0 after its `h` was accepted but before the `t`: axis 0 still starts.
#[test]
fn g3_sync_start_moves_a_paused_axis() {
    // Until the `h` of axis 1 is on the wire (axis 0's `h` is answered by then).
    let mut h = sync_start_until_h_of(1);
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

/// A move of its own for an axis in a running synchronized start gives the start up (as a stop
/// does) and cancels what it buffered: the start's `t` must not take the axis to the start's
/// point after the newer move (the soak found it doing so).
#[test]
fn a_move_of_its_own_gives_a_running_sync_start_up() {
    let mut h = sync_start_until_h_of(0);
    write(&mut h, unit(0), DIRECT, &[0, 10_00, 0, 10, 0, 20_00, 30]).unwrap();
    for _ in 0..100 {
        h.run_until(h.now + 20 * MS);
        let _ = read(&mut h, 63, G_SYNC_STATUS, 1);
    }
    assert_eq!(read(&mut h, 63, G_SYNC_STATUS, 1).unwrap(), [3], "given up");
    assert_eq!(
        pnow_mm100(&mut h, 0),
        10_00,
        "at the direct move's target, not point 3"
    );
    assert!(h.bus.controller(axis(0)).unwrap().buffered().is_none());
}
