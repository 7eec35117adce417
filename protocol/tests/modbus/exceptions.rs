//! §7 exceptions: 01-03 from the slave, 04 from the model, and their counters.

use protocol::modbus::{Exception, Slave};

use crate::{assert_exchange, exchange, exchange_with, hex, with_crc, with_crc_bytes, Memory};

// ------------------------------------------------------------------------------ §7 exceptions

#[test]
fn exception_01_illegal_function() {
    let mut model = Memory::new(1000);
    // FC07 (Read Exception Status) is not supported.
    assert_exchange(&mut model, "11 07 4C 22", "11 87 01 83 F5");
    // FC08 sub-functions this slave does not have (0003 is for ASCII mode).
    let (_, reply) = exchange(&mut model, &with_crc("11 08 00 03 00 00"));
    assert_eq!(reply, with_crc("11 88 01"));
    // FC2B with another MEI type than 0E.
    let (_, reply) = exchange(&mut model, &with_crc("11 2B 0D 01 00"));
    assert_eq!(reply, with_crc("11 AB 01"));
    // Any other code below 0x80.
    for function in [0x09, 0x16, 0x17, 0x7F] {
        let (_, reply) = exchange(
            &mut model,
            &with_crc(&format!("11 {function:02X} 00 00 00 01")),
        );
        assert_eq!(reply, with_crc(&format!("11 {:02X} 01", function | 0x80)));
    }
}

#[test]
fn exception_02_illegal_data_address() {
    // §7's example: coil 1186 (address 0x04A1) does not exist.
    let mut model = Memory::new(1000);
    assert_exchange(&mut model, "11 01 04 A1 00 01 AF 88", "11 81 02 C0 54");
    // address + quantity past 0x10000, even in a model covering every address.
    let mut full = Memory::full();
    assert_exchange(&mut full, "11 03 FF FF 00 02 C6 BF", "11 83 02 C1 34");
    let (_, reply) = exchange(&mut full, &with_crc("11 03 FF FF 00 01"));
    assert_eq!(reply[1], 0x03, "address 0xFFFF itself is fine");
    let (_, reply) = exchange(&mut full, &with_crc("11 01 F8 30 07 D0"));
    assert_eq!(reply[1], 0x01, "0xF830 + 2000 == 0x10000 is fine");
    let (_, reply) = exchange(&mut full, &with_crc("11 01 F8 31 07 D0"));
    assert_eq!(reply, with_crc("11 81 02"));
    let (_, reply) = exchange(&mut full, &with_crc("11 10 FF FF 00 02 04 00 01 00 02"));
    assert_eq!(reply, with_crc("11 90 02"));
    assert_eq!(full.writes, 0);
}

#[test]
fn exception_03_illegal_data_value() {
    let mut model = Memory::full();
    // Quantity 0 and quantity over the limit.
    assert_exchange(&mut model, "11 03 00 6B 00 00 36 86", "11 83 03 00 F4");
    let cases = [
        ("11 01 00 00 07 D1", "11 81 03"), // 2001 coils
        ("11 02 00 00 00 00", "11 82 03"),
        ("11 03 00 00 00 7E", "11 83 03"), // 126 registers
        ("11 04 00 00 00 7E", "11 84 03"),
        ("11 03 00 00 00", "11 83 03"),       // PDU too short
        ("11 03 00 00 00 01 00", "11 83 03"), // PDU too long
        ("11 06 00 01 00", "11 86 03"),
        ("11 08 00", "11 88 03"),
        ("11 0F 00 00 07 B1 F7", "11 8F 03"),    // 1969 coils
        ("11 0F 00 13 00 0A 01 CD", "11 8F 03"), // byte count 1 for 10 coils
        ("11 0F 00 13 00 0A 02 CD", "11 8F 03"), // one data byte missing
        ("11 0F 00 13 00 0A 02 CD 01 00", "11 8F 03"), // one data byte too many
        ("11 0F 00 13 00 0A", "11 8F 03"),
        ("11 10 00 00 00 7C F8", "11 90 03"), // 124 registers
        ("11 10 00 01 00 02 03 00 0A 01", "11 90 03"), // byte count != 2 * quantity
        ("11 10 00 01 00 02 04 00 0A 01", "11 90 03"),
        ("11 10 00 01 00 00 00", "11 90 03"),
    ];
    for (request, response) in cases {
        let (_, reply) = exchange(&mut model, &with_crc(request));
        assert_eq!(reply, with_crc(response), "{request}");
    }
    // FC05 accepts only 0xFF00 and 0x0000.
    assert_exchange(&mut model, "11 05 00 AC 12 34 02 0C", "11 85 03 03 54");
    for value in ["00 FF", "FF FF", "00 01"] {
        let (_, reply) = exchange(&mut model, &with_crc(&format!("11 05 00 AC {value}")));
        assert_eq!(reply, with_crc("11 85 03"), "{value}");
    }
    // The largest legal quantities are accepted.
    for request in [
        "11 01 00 00 07 D0",
        "11 02 00 00 07 D0",
        "11 03 00 00 00 7D",
        "11 04 00 00 00 7D",
    ] {
        let (_, reply) = exchange(&mut model, &with_crc(request));
        assert_eq!(reply[1] & 0x80, 0, "{request}");
        assert_eq!(reply.len(), 5 + 250, "{request}");
    }
    let mut coils = hex("11 0F 00 00 07 B0 F6");
    coils.extend([0xFF; 246]);
    assert_eq!(
        exchange(&mut model, &with_crc_bytes(coils)).1,
        with_crc("11 0F 00 00 07 B0")
    );
    let mut registers = hex("11 10 00 00 00 7B F6");
    registers.extend([0xAB; 246]);
    assert_eq!(
        exchange(&mut model, &with_crc_bytes(registers)).1,
        with_crc("11 10 00 00 00 7B")
    );
    assert!(model.coils[..1968].iter().all(|&coil| coil) && !model.coils[1968]);
    assert!(model.holding[..123].iter().all(|&r| r == 0xABAB) && model.holding[123] == 0);
    assert_eq!(model.writes, 2);
}
#[test]
fn exception_04_from_the_model() {
    let mut model = Memory::new(1000);
    model.broken = true;
    assert_exchange(&mut model, "11 04 00 08 00 01 B2 98", "11 84 04 43 06");
}

#[test]
fn exceptions_are_counted() {
    let mut model = Memory::new(1000);
    let mut slave = Slave::new();
    for request in [
        "11 07",
        "11 01 04 A1 00 01",
        "11 03 00 00 00 00",
        "11 03 00 00 00 7E",
        "11 03 00 00 00 01",
    ] {
        exchange_with(&mut slave, &mut model, &with_crc(request));
    }
    let counters = slave.counters();
    assert_eq!(counters.exceptions(Exception::IllegalFunction), 1);
    assert_eq!(counters.exceptions(Exception::IllegalDataAddress), 1);
    assert_eq!(counters.exceptions(Exception::IllegalDataValue), 2);
    assert_eq!(counters.exceptions(Exception::ServerDeviceFailure), 0);
    assert_eq!((counters.frames, counters.replies), (5, 5));
}
