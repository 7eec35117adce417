//! The synchronized start when it fails: an axis paused between its `h` and the `t` (G3), the
//! `h`s a failed start leaves buffered (G4; both regressions found by review, each failed before
//! its fix), a restart that waits for the old attempt, and what a stop leaves buffered (issue 33
//! item 8: a stop leaves nothing a later `t` could start; each failed before its fix).

use protocol::modbus::Exception;
use protocol::modbus::{Request as Modbus, MAX_ADU_LEN};
use protocol::plc::map::*;
use protocol::plc::CommandState;
use protocol::time::Instant;
use protocol::Command;
use rc_host::node_harness::NodeHarness;

use crate::{
    axis, coil, gateway, gateway_with, home, pnow_mm100, read, settle, unit, write, MS, S,
};

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

/// `n` axes homed, POSR 3 on each; axis 1 busy with a long move (its `h` of a synchronized start
/// waits behind it), then a synchronized start of axes 1 and 3 written.
fn sync_start_of_1_and_3_behind_a_move() -> NodeHarness {
    let mut h = gateway(4);
    for a in 0..4 {
        home(&mut h, a);
        write(&mut h, unit(a), POSR, &[3]).unwrap();
    }
    write(&mut h, unit(1), DIRECT, &[0, 90_00, 0, 10, 0, 20_00, 30]).unwrap();
    h.run_until(h.now + 100 * MS);
    write(&mut h, 63, G_SYNC_MASK, &[0b1010]).unwrap();
    write(&mut h, 63, G_SYNC_START, &[1]).unwrap();
    h
}

/// Step until `done` holds (at most 1 s).
fn step_until(h: &mut NodeHarness, done: impl Fn(&NodeHarness) -> bool) {
    let until = h.now + S;
    while !done(h) {
        assert!(h.now < until, "not reached in 1 s");
        h.step(until);
    }
}

/// A synchronized start of `mask` (written again while it is refused with 04: an old attempt's
/// frames still run, behind a move for up to 5 s), then run until it is over; SYNCSTAT.
fn sync_start_of(h: &mut NodeHarness, mask: u16) -> u16 {
    write(h, 63, G_SYNC_MASK, &[mask]).unwrap();
    let mut started = false;
    for _ in 0..300 {
        started = write(h, 63, G_SYNC_START, &[1]).is_ok();
        if started {
            break;
        }
        h.run_until(h.now + 20 * MS);
    }
    assert!(started, "the start of {mask:#b} was refused for 6 s");
    for _ in 0..100 {
        h.run_until(h.now + 20 * MS);
        if read(h, 63, G_SYNC_STATUS, 1).unwrap() != [1] {
            break;
        }
    }
    read(h, 63, G_SYNC_STATUS, 1).unwrap()[0]
}

/// Axis `a` holds nothing buffered, and a later synchronized start of other axes (mask
/// `others`, whose `t` every axis receives) does not move it.
fn nothing_buffered_on(h: &mut NodeHarness, a: u8, others: u16) {
    assert_eq!(
        h.bus.controller(axis(a)).unwrap().buffered(),
        None,
        "axis {a} still holds a buffered command after the stop"
    );
    let before = h.bus.controller(axis(a)).unwrap().position();
    let sent = h.sent.len();
    assert_eq!(sync_start_of(h, others), 2, "the start of {others:#b}");
    let c = h.bus.controller(axis(a)).unwrap();
    assert!(
        !c.moving() && c.position() == before,
        "the `t` of the start of {others:#b} moved axis {a} (from {before} to {}, moving {})",
        c.position(),
        c.moving()
    );
    let t = h.sent[sent..]
        .iter()
        .position(|(_, r)| r.command == Command::ExecuteBuffered);
    assert!(t.is_some(), "the start sent its `t`");
}

/// Issue 33 item 8, the firmware soak's seeds 5577 and 31337: a synchronized start of axes 1
/// and 3 waits for axis 1's `h` (behind its move) while axis 3 holds its buffered Q3; a
/// broadcast STOP stops the axes one by one: axis 1's stop gives the start up, which buffers an
/// `n` on axis 3, and axis 3's stop, a moment later, cancelled that `n` with its other jobs.
/// Axis 3 kept its move, and the `t` of the next synchronized start (axes 0 and 2) started it.
#[test]
fn a_broadcast_stop_leaves_nothing_buffered_for_a_later_start() {
    let mut h = sync_start_of_1_and_3_behind_a_move();
    step_until(&mut h, |h| {
        h.bus.controller(axis(3)).unwrap().buffered().is_some()
    });
    h.write_coil(0, COIL_STOP, true).unwrap();
    h.run_until(h.now + 300 * MS);
    assert_eq!(read(&mut h, 63, G_SYNC_STATUS, 1).unwrap(), [3], "given up");
    nothing_buffered_on(&mut h, 3, 0b0101);
}

/// A stop that comes while the axis' `h` is on the wire cancels its job, but the controller
/// takes the frame: the axis holds the move though its `h` never finished.
#[test]
fn a_stop_while_the_h_is_on_the_wire_leaves_nothing_buffered() {
    let mut h = sync_start_of_1_and_3_behind_a_move();
    step_until(&mut h, |h| {
        h.sent
            .last()
            .is_some_and(|(_, r)| r.axis == axis(3) && matches!(r.command, Command::Buffer(_)))
    });
    coil(&mut h, unit(3), COIL_STOP, true).unwrap();
    h.run_until(h.now + 300 * MS);
    assert_eq!(read(&mut h, 63, G_SYNC_STATUS, 1).unwrap(), [3], "given up");
    nothing_buffered_on(&mut h, 3, 0b0101);
}

/// An `h` whose answers are all lost (the axis goes silent: it hears, it does not answer)
/// fails the start, but the controller holds the move: it is cancelled too, and no `t` goes out
/// until it is (the start of other axes is refused with 04 meanwhile).
#[test]
fn an_h_whose_answer_is_lost_is_cancelled_before_the_next_t() {
    let mut h = gateway(4);
    for a in 0..4 {
        home(&mut h, a);
        write(&mut h, unit(a), POSR, &[3]).unwrap();
    }
    write(&mut h, 63, G_SYNC_MASK, &[0b1100]).unwrap();
    write(&mut h, 63, G_SYNC_START, &[1]).unwrap();
    // Silent from its `h` on: it hears that frame, it answers nothing.
    step_until(&mut h, |h| {
        h.sent
            .last()
            .is_some_and(|(_, r)| r.axis == axis(3) && matches!(r.command, Command::Buffer(_)))
    });
    h.bus.set_silent(axis(3), true);
    for _ in 0..50 {
        h.run_until(h.now + 20 * MS);
        let _ = read(&mut h, 63, G_SYNC_STATUS, 1);
    }
    assert_eq!(read(&mut h, 63, G_SYNC_STATUS, 1).unwrap(), [3], "given up");
    assert!(h.bus.controller(axis(3)).unwrap().buffered().is_some());
    h.bus.set_silent(axis(3), false);
    // Back online (a probe answered), then a synchronized start of axes 0 and 1.
    for _ in 0..100 {
        h.run_until(h.now + 20 * MS);
        if read(&mut h, unit(3), LINK, 1).unwrap() == [1] {
            break;
        }
    }
    let before = h.bus.controller(axis(3)).unwrap().position();
    assert_eq!(sync_start_of(&mut h, 0b0011), 2);
    let c = h.bus.controller(axis(3)).unwrap();
    assert_eq!(c.buffered(), None, "axis 3's move cancelled");
    assert!(
        !c.moving() && c.position() == before,
        "the start of axes 0 and 1 moved axis 3 (from {before} to {})",
        c.position()
    );
}

/// A stop of one axis of a start whose `t` is asked for but not sent yet (it waits for the
/// line's 1 ms gap after the last `h`'s answer, or for other axes' frames): the start is given
/// up, and the `t`, once out, would start the move the stop left buffered. It is taken off the
/// queue. (The STOP coil's request arrives while the last `h`'s answer is on the wire, so that
/// the gateway takes it just after the `t` was asked for.)
#[test]
fn a_stop_while_the_t_waits_its_turn_takes_the_t_off_the_queue() {
    let mut h = gateway(2);
    for a in 0..2 {
        home(&mut h, a);
        write(&mut h, unit(a), POSR, &[3]).unwrap();
    }
    write(&mut h, 63, G_SYNC_MASK, &[0b11]).unwrap();
    write(&mut h, 63, G_SYNC_START, &[1]).unwrap();
    let buffers = |h: &NodeHarness| {
        h.sent
            .iter()
            .filter(|(_, r)| matches!(r.command, Command::Buffer(_)))
            .count()
    };
    let before = buffers(&h);
    step_until(&mut h, |h| buffers(h) == before + 2);
    // The last `h`'s answer begins to arrive: the STOP coil of axis 1 (not the `t`'s axis).
    step_until(&mut h, |h| h.node.gateway().engine().frame_due().is_some());
    let mut adu = [0u8; MAX_ADU_LEN];
    let request = Modbus::WriteSingleCoil {
        address: COIL_STOP,
        value: true,
    };
    let len = request.emit(unit(1), &mut adu).unwrap();
    let sent = h.sent.len();
    h.node.plc_received(Instant(h.now), &adu[..len]);
    h.run_until(h.now + 500 * MS);
    let stop = h.sent[sent..]
        .iter()
        .position(|(_, r)| r.axis == axis(1) && r.command == Command::CancelMotion)
        .expect("axis 1's `d`");
    assert!(
        h.sent[sent..sent + stop]
            .iter()
            .all(|(_, r)| r.command != Command::ExecuteBuffered),
        "the `t` went out before the stop (the test missed its moment)"
    );
    for a in 0..2 {
        let c = h.bus.controller(axis(a)).unwrap();
        assert!(
            !c.moving() && c.position() == 0,
            "axis {a} moved after the stop (to {})",
            c.position()
        );
        assert_eq!(c.buffered(), None, "axis {a} still holds its move");
    }
    assert_eq!(read(&mut h, 63, G_SYNC_STATUS, 1).unwrap(), [3], "given up");
}

/// A synchronized start of axes 0 and 1, each given a table write (about 36 frames) right after
/// it: their `h`s are answered while the writes wait behind them, so that the `t` finds both
/// axes busy. Runs until both moves are buffered and the gateway has their answers.
fn sync_start_with_table_writes_behind() -> NodeHarness {
    let mut h = gateway(2);
    for a in 0..2 {
        home(&mut h, a);
        write(&mut h, unit(a), POSR, &[3]).unwrap();
    }
    write(&mut h, 63, G_SYNC_MASK, &[0b11]).unwrap();
    write(&mut h, 63, G_SYNC_START, &[1]).unwrap();
    let mut row = [0u16; 16];
    row[1] = 20_00;
    row[3] = 10;
    row[5] = 80_00;
    row[10] = 30;
    row[11] = 30;
    for a in 0..2 {
        write(&mut h, unit(a), 0x1000 + 16 * 5, &row).unwrap();
    }
    step_until(&mut h, |h| {
        (0..2).all(|a| h.bus.controller(axis(a)).unwrap().buffered().is_some())
    });
    h.run_until(h.now + 10 * MS);
    h
}

/// The `t` goes to an axis of the start with nothing else queued, so that the gateway can tell
/// whether it has gone out (the next frame to that axis is the `t`); while every axis of the
/// start has a job, it waits for one to end.
#[test]
fn the_t_waits_for_an_axis_of_the_start_to_be_free() {
    let mut h = sync_start_with_table_writes_behind();
    let sent = h.sent.len();
    assert_eq!(sync_start_settles(&mut h), 2);
    let t = h.sent[sent..]
        .iter()
        .position(|(_, r)| r.command == Command::ExecuteBuffered)
        .expect("the `t`");
    let lead = h.sent[sent + t].1.axis;
    assert!(
        h.sent[sent + t..]
            .iter()
            .all(|(_, r)| r.axis != lead || !matches!(r.command, Command::WriteMemory { .. })),
        "the `t` went to axis {lead:?} before its table write was over"
    );
    for a in 0..2 {
        assert_eq!(settle(&mut h, a, 5 * S), (CommandState::Done, 0));
        assert_eq!(pnow_mm100(&mut h, a), 40_00, "axis {a} at point 3");
    }
}

/// The same start stopped (axis 1) while its `t` waits for a free axis: the start is given up
/// and no `t` goes out (before, the `t` waited behind axis 0's table write and went out after
/// axis 1's stop, starting the move of the given-up start that axis 0 still held).
#[test]
fn a_stop_while_the_t_waits_for_a_free_axis_sends_no_t() {
    let mut h = sync_start_with_table_writes_behind();
    let sent = h.sent.len();
    coil(&mut h, unit(1), COIL_STOP, true).unwrap();
    h.run_until(h.now + S);
    assert!(
        h.sent[sent..]
            .iter()
            .all(|(_, r)| r.command != Command::ExecuteBuffered),
        "a `t` after the stop"
    );
    for a in 0..2 {
        let c = h.bus.controller(axis(a)).unwrap();
        assert!(!c.moving() && c.position() == 0, "axis {a} moved");
        assert_eq!(c.buffered(), None, "axis {a} still holds its move");
    }
    assert_eq!(read(&mut h, 63, G_SYNC_STATUS, 1).unwrap(), [3], "given up");
}

/// Run until the synchronized start is over (PLC-like polling); SYNCSTAT.
fn sync_start_settles(h: &mut NodeHarness) -> u16 {
    for _ in 0..150 {
        h.run_until(h.now + 20 * MS);
        if read(h, 63, G_SYNC_STATUS, 1).unwrap() != [1] {
            break;
        }
    }
    read(h, 63, G_SYNC_STATUS, 1).unwrap()[0]
}
