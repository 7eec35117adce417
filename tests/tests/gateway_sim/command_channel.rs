//! The command channel (REQ/RESP) when the PLC does not follow the handshake: a request
//! cleared or overwritten while it runs, an invalid block written while the channel is busy.
//! G1, G2 and G5 are regressions found by review (each failed before its fix).

use protocol::plc::map::*;

use crate::{exchange, gateway, read, write, MS};

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
