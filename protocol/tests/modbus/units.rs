//! Units: broadcast writes without a reply, other units ignored, non-requests, exception codes.

use protocol::modbus::{Exception, Handled, PduError, Request, Slave};

use crate::{exchange_with, hex, with_crc, Memory};

// ------------------------------------------------------------------------------ units

#[test]
fn broadcast_writes_apply_without_reply() {
    let mut model = Memory::new(1000);
    let mut slave = Slave::new();
    let (handled, reply) = exchange_with(&mut slave, &mut model, &hex("00 06 00 01 00 03 99 DA"));
    assert_eq!((handled, reply.len()), (Handled::Broadcast, 0));
    assert_eq!(model.holding[1], 3);
    let (handled, _) = exchange_with(
        &mut slave,
        &mut model,
        &hex("00 10 00 01 00 02 04 00 0A 01 02 96 CC"),
    );
    assert_eq!(handled, Handled::Broadcast);
    assert_eq!(&model.holding[1..3], &[0x0A, 0x0102]);
    for request in ["00 05 00 AC FF 00", "00 0F 00 13 00 0A 02 CD 01"] {
        assert_eq!(
            exchange_with(&mut slave, &mut model, &with_crc(request)).0,
            Handled::Broadcast
        );
    }
    assert!(model.coils[0xAC] && model.coils[0x13]);
    // A refused broadcast write is not answered either.
    let (handled, reply) = exchange_with(&mut slave, &mut model, &with_crc("00 06 27 10 00 01"));
    assert_eq!((handled, reply.len()), (Handled::Broadcast, 0));
    let (handled, _) = exchange_with(&mut slave, &mut model, &with_crc("00 05 00 AC 12 34"));
    assert_eq!(handled, Handled::Broadcast);
    // Reads and diagnostics to unit 0 are ignored.
    for request in [
        "00 03 00 00 00 01",
        "00 01 00 00 00 01",
        "00 08 00 00 12 34",
        "00 07",
    ] {
        assert_eq!(
            exchange_with(&mut slave, &mut model, &with_crc(request)).0,
            Handled::Ignored
        );
    }
    let counters = slave.counters();
    assert_eq!(
        (
            counters.broadcasts,
            counters.broadcast_errors,
            counters.ignored
        ),
        (6, 2, 4)
    );
    assert_eq!((counters.replies, counters.illegal_data_address), (0, 0));
}

#[test]
fn other_units_are_ignored() {
    let mut model = Memory::new(1000);
    model.units = vec![0x11, 0x20];
    let mut slave = Slave::new();
    for unit in [0x01, 0x12, 0xF7, 0xF8, 0xFF] {
        let request = with_crc(&format!("{unit:02X} 06 00 01 00 03"));
        assert_eq!(
            exchange_with(&mut slave, &mut model, &request).0,
            Handled::Ignored
        );
        // Another slave's exception reply is not ours to judge either.
        let reply = with_crc(&format!("{unit:02X} 83 02"));
        assert_eq!(
            exchange_with(&mut slave, &mut model, &reply).0,
            Handled::Ignored
        );
    }
    assert_eq!(model.holding[1], 0);
    let (handled, _) = exchange_with(&mut slave, &mut model, &with_crc("20 06 00 01 00 03"));
    assert_eq!(handled, Handled::Reply(8));
    assert_eq!(slave.counters().ignored, 10);
}

#[test]
fn non_requests_are_malformed_and_not_answered() {
    let mut model = Memory::new(1000);
    let mut slave = Slave::new();
    for frame in [
        "11 81 02",
        "11 00",
        "11 00 00 00 00 01",
        "11 FF",
        "00 90 03",
    ] {
        assert_eq!(
            exchange_with(&mut slave, &mut model, &with_crc(frame)).0,
            Handled::Malformed,
            "{frame}"
        );
    }
    assert_eq!(
        (slave.counters().malformed, slave.counters().replies),
        (5, 0)
    );
    assert_eq!(Request::parse(&[]), Err(PduError::NotARequest));
    // A PDU longer than 253 bytes cannot come from a frame; parsed directly, it is refused.
    let mut long = hex("08 00 00");
    long.extend([0; 250]);
    assert!(Request::parse(&long).is_ok());
    long.push(0);
    assert_eq!(
        Request::parse(&long),
        Err(PduError::Exception(Exception::IllegalDataValue))
    );
}

#[test]
fn exception_codes() {
    for code in 1..=4 {
        assert_eq!(Exception::from_code(code).unwrap().code(), code);
    }
    assert_eq!(Exception::from_code(0), None);
    assert_eq!(Exception::from_code(5), None);
    assert_eq!(
        Exception::IllegalDataAddress.to_string(),
        "Modbus exception 02: illegal data address"
    );
}
