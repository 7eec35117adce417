//! The gateway unit's settings: the bus line settings and APPLY (refused unless the bus is
//! idle), the watchdog action, PIOAXIS and the PLC-link counters.

use protocol::line::Baud;
use protocol::modbus::Exception;
use protocol::plc::map::*;
use protocol::time::Instant;

use crate::{axis, coil, gateway, gateway_with, home, read, unit, write, MS};

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
    assert_eq!(h.node.gateway().config().settings.pio_axis, Some(axis(0)));
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
