//! The command channel (REQ/RESP): fields in the register map's units, checked as the position
//! table checks them; and the channel when the PLC does not follow the handshake: a request
//! cleared or overwritten while it runs, an invalid block written while the channel is busy.
//! G1, G2 and G5 are regressions found by review (each failed before its fix).

use protocol::modbus::Exception;
use protocol::plc::map::*;
use rc_host::node_harness::NodeHarness;

use crate::{axis, exchange, gateway, read, scale, write, MS};

/// Field offsets from 0x400.
const PCMD: u16 = 0;
const INP: u16 = 3;
const VCMD: u16 = 4;
const ACMD: u16 = 5;

/// A request block for axis 0.
fn request(code: u16, point: u16, field: u16, value: u32) -> [u16; 6] {
    [code, 0, point, field, (value >> 16) as u16, value as u16]
}

/// Field `field` (offset from 0x400) of point `p` of axis 0 as the simulated controller stores it.
fn stored(h: &NodeHarness, p: usize, field: usize) -> u32 {
    h.bus.controller(axis(0)).unwrap().memory().nv.points[p][field]
}

/// Issue 24: the channel showed a motor-end axis' 20 mm as the controller's FFFF F830 (-2000
/// pulses). Code 1 reads 0.01 mm from home, as PNOW and the position table do; code 3 the
/// controller's value.
#[test]
fn a_position_reads_in_hundredths_of_a_millimetre_from_home() {
    let mut h = gateway(1);
    let wire = scale()
        .position_to_wire(protocol::units::Length(20_00))
        .unwrap();
    assert_eq!(wire.to_wire(), 0xFFFF_F830, "motor-end homing, 8 mm lead");
    h.bus
        .controller_mut(axis(0))
        .unwrap()
        .memory_mut()
        .nv
        .points[4][0] = wire.to_wire();
    assert_eq!(
        exchange(&mut h, request(1, 4, PCMD, 0)),
        [1, 0, 0, 20_00, 0]
    );
    assert_eq!(
        exchange(&mut h, request(3, 4, PCMD, 0)),
        [3, 0, 0xFFFF, 0xF830, 0],
        "code 3: as stored"
    );
}

/// A write in the map's units stores the controller's units; the response shows what the
/// controller now holds, in the request's units; the same write again spends no V5.
#[test]
fn a_write_in_the_map_units_stores_the_controller_units() {
    let mut h = gateway(1);
    let first = exchange(&mut h, request(2, 5, PCMD, 60_00));
    assert_eq!(first[..4], [2, 0, 0, 60_00], "{first:?}");
    assert!(
        (1..0xFFFF).contains(&first[4]),
        "written with V5: {first:?}"
    );
    let pulses = scale()
        .position_to_wire(protocol::units::Length(60_00))
        .unwrap();
    assert_eq!(
        stored(&h, 5, 0),
        pulses.to_wire(),
        "-6000 pulses: 60 mm from the motor end"
    );
    assert_eq!(pulses.0, -6000);
    assert_eq!(exchange(&mut h, request(2, 5, PCMD, 60_00))[4], 0xFFFF);
    assert_eq!(
        exchange(&mut h, request(1, 5, PCMD, 0)),
        [1, 0, 0, 60_00, 0]
    );
    // Band 0.10 mm = 10 pulses; 12.34 mm/s = 462 x 0.2 rpm (462.75 truncated, which reads
    // 12.32 mm/s); 0.30 G = 220 x 0.1 rpm/ms
    // (220.6 truncated).
    let band = exchange(&mut h, request(2, 5, INP, 10));
    assert_eq!((band[3], stored(&h, 5, 3)), (10, 10));
    let speed = exchange(&mut h, request(2, 5, VCMD, 12_34));
    assert_eq!((speed[3], stored(&h, 5, 4)), (1232, 462));
    assert_eq!(
        exchange(&mut h, request(2, 5, VCMD, 12_34))[4],
        0xFFFF,
        "the same request stores the same units: nothing written"
    );
    let accel = exchange(&mut h, request(2, 5, ACMD, 30));
    assert_eq!((accel[3], stored(&h, 5, 5)), (30, 220));
    assert_eq!(exchange(&mut h, request(1, 5, ACMD, 0))[3], accel[3]);
    assert_eq!(
        exchange(&mut h, request(3, 5, VCMD, 0))[3],
        462,
        "code 3: as stored"
    );
}

/// Issue 24: raw 7000 was stored as -70 mm. A value the position table would refuse is refused
/// with 03 on the request's write, and nothing reaches the bus.
#[test]
fn a_write_out_of_range_is_refused_and_nothing_is_sent() {
    let mut h = gateway(1);
    let before = stored(&h, 5, 0);
    let sent = h.sent.len();
    for bad in [
        request(2, 5, PCMD, 100_01),             // past the 100 mm stroke
        request(2, 5, PCMD, (-70_00i32) as u32), // behind home
        request(2, 5, INP, 0x8000_0000),         // not within i32
        request(2, 5, VCMD, 0),                  // no speed
        request(2, 5, VCMD, 0x0100_0000),        // beyond the controller's velocity
        request(2, 5, ACMD, 0),                  // no acceleration
        request(4, 5, PCMD, 0xFFFF_E4A8),        // no raw write
    ] {
        assert_eq!(
            write(&mut h, 63, G_REQUEST, &bad),
            Err(Exception::IllegalDataValue),
            "{bad:?}"
        );
        assert_eq!(read(&mut h, 63, G_RESPONSE, 5).unwrap(), [0; 5], "{bad:?}");
    }
    h.run_until(h.now + 200 * MS);
    assert!(
        h.sent[sent..]
            .iter()
            .all(|(_, r)| matches!(r.command, protocol::Command::Status)),
        "nothing but status polls reached the bus: {:?}",
        &h.sent[sent..]
    );
    assert_eq!(stored(&h, 5, 0), before);
    // The stroke itself is in range.
    assert_eq!(
        exchange(&mut h, request(2, 5, PCMD, 100_00))[..4],
        [2, 0, 0, 100_00]
    );
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

/// G5: while the channel is busy, an invalid block with the same code is accepted.
#[test]
fn g5_invalid_request_accepted_while_busy() {
    let mut h = gateway(1);
    write(&mut h, 63, G_REQUEST, &[1, 0, 3, 0, 0, 0]).unwrap();
    let bad = write(&mut h, 63, G_REQUEST, &[1, 9, 99, 77, 0, 0]);
    assert!(bad.is_err());
}
