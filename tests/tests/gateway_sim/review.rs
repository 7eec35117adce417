//! Regressions found by review (G1-G5, each failed before its fix), the bus settings with the
//! watchdog action and link counters, and the position table's rows.

use protocol::line::Baud;
use protocol::modbus::Exception;
use protocol::plc::map::*;
use protocol::plc::CommandState;
use protocol::time::Instant;

use crate::{axis, coil, exchange, gateway, home, pnow_mm100, read, settle, unit, write, MS, S};

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
