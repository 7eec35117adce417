//! CRC check values, every specification frame's CRC, and the worked examples of §6
//! (FC01-FC10).

use protocol::modbus::{crc, Handled};

use crate::{assert_exchange, exchange, hex, set_bits, with_crc, Memory};

// ------------------------------------------------------------------------------ CRC

#[test]
fn crc_check_values() {
    assert_eq!(crc::checksum(b"123456789"), 0x4B37);
    assert_eq!(
        crc::to_wire(crc::checksum(&hex("01 03 00 00 00 0A"))),
        [0xC5, 0xCD]
    );
    assert!(crc::is_valid(&hex("01 03 00 00 00 0A C5 CD")));
    assert!(
        !crc::is_valid(&hex("01 03 00 00 00 0A CD C5")),
        "high byte first is wrong"
    );
    assert!(!crc::is_valid(&[0xFF]));
    assert!(!crc::is_valid(&[]));
}

/// Every frame written with its CRC in this file.
const SPEC_FRAMES: &[&str] = &[
    "11 01 00 13 00 13 8E 92",
    "11 01 03 CD 6B 05 40 12",
    "11 01 00 13 00 25 0E 84",
    "11 01 05 CD 6B B2 0E 1B 45 E6",
    "11 02 00 C4 00 16 BA A9",
    "11 02 03 AC DB 35 20 18",
    "11 03 00 6B 00 03 76 87",
    "11 03 06 02 2B 00 00 00 64 C8 BA",
    "11 04 00 08 00 01 B2 98",
    "11 04 02 00 0A F8 F4",
    "11 05 00 AC FF 00 4E 8B",
    "11 06 00 01 00 03 9A 9B",
    "11 08 00 00 A5 37 D8 1D",
    "11 0F 00 13 00 0A 02 CD 01 BF 0B",
    "11 0F 00 13 00 0A 26 99",
    "11 10 00 01 00 02 04 00 0A 01 02 C6 F0",
    "11 10 00 01 00 02 12 98",
    "11 01 04 A1 00 01 AF 88",
    "11 81 02 C0 54",
    "11 07 4C 22",
    "11 87 01 83 F5",
    "11 08 00 01 00 00 B3 5B",
    "11 88 01 86 05",
    "11 03 00 6B 00 00 36 86",
    "11 83 03 00 F4",
    "11 05 00 AC 12 34 02 0C",
    "11 85 03 03 54",
    "11 03 FF FF 00 02 C6 BF",
    "11 83 02 C1 34",
    "11 84 04 43 06",
    "00 06 00 01 00 03 99 DA",
    "00 10 00 01 00 02 04 00 0A 01 02 96 CC",
];

#[test]
fn spec_frames_have_valid_crcs() {
    for frame in SPEC_FRAMES {
        let bytes = hex(frame);
        assert!(crc::is_valid(&bytes), "{frame}");
        assert_eq!(bytes, with_crc(&frame[..frame.len() - 6]), "{frame}");
    }
}

// ------------------------------------------------------------------------------ §6 examples

#[test]
fn fc01_read_coils() {
    // §6.1: coils 20–38 (addresses 0x13..) are CD 6B 05.
    let mut model = Memory::new(1000);
    set_bits(&mut model.coils, 0x13, "CD 6B 05");
    // Independently of set_bits: CD = 1100 1101, so address 0x13 (coil 20) is ON, 0x14 OFF.
    assert!(model.coils[0x13] && !model.coils[0x14] && model.coils[0x15] && model.coils[0x1A]);
    assert_exchange(
        &mut model,
        "11 01 00 13 00 13 8E 92",
        "11 01 03 CD 6B 05 40 12",
    );
    // The classic 37-coil example (PI-MBUS-300, another device: coils 36–38 differ); unused
    // high bits of the last byte are zero.
    set_bits(&mut model.coils, 0x13, "CD 6B B2 0E 1B");
    assert_exchange(
        &mut model,
        "11 01 00 13 00 25 0E 84",
        "11 01 05 CD 6B B2 0E 1B 45 E6",
    );
}

#[test]
fn fc02_read_discrete_inputs() {
    // §6.2: inputs 197–218 (addresses 0xC4..) are AC DB 35.
    let mut model = Memory::new(1000);
    set_bits(&mut model.discrete, 0xC4, "AC DB 35");
    assert_exchange(
        &mut model,
        "11 02 00 C4 00 16 BA A9",
        "11 02 03 AC DB 35 20 18",
    );
}

#[test]
fn fc03_read_holding_registers() {
    // §6.3: registers 108–110 (addresses 0x6B..) hold 0x022B, 0x0000, 0x0064.
    let mut model = Memory::new(1000);
    model.holding[0x6B..0x6E].copy_from_slice(&[0x022B, 0, 0x64]);
    assert_exchange(
        &mut model,
        "11 03 00 6B 00 03 76 87",
        "11 03 06 02 2B 00 00 00 64 C8 BA",
    );
}

#[test]
fn fc04_read_input_registers() {
    // §6.4: input register 9 (address 8) holds 10.
    let mut model = Memory::new(1000);
    model.input[8] = 10;
    assert_exchange(
        &mut model,
        "11 04 00 08 00 01 B2 98",
        "11 04 02 00 0A F8 F4",
    );
}

#[test]
fn fc05_write_single_coil() {
    // §6.5: coil 173 (address 0xAC) ON; the reply echoes the request.
    let mut model = Memory::new(1000);
    assert_exchange(
        &mut model,
        "11 05 00 AC FF 00 4E 8B",
        "11 05 00 AC FF 00 4E 8B",
    );
    assert!(model.coils[0xAC]);
    let off = with_crc("11 05 00 AC 00 00");
    let (_, reply) = exchange(&mut model, &off);
    assert_eq!(reply, off);
    assert!(!model.coils[0xAC]);
}

#[test]
fn fc06_write_single_register() {
    // §6.6: register 2 (address 1) := 3; the reply echoes the request.
    let mut model = Memory::new(1000);
    assert_exchange(
        &mut model,
        "11 06 00 01 00 03 9A 9B",
        "11 06 00 01 00 03 9A 9B",
    );
    assert_eq!(model.holding[1], 3);
}

#[test]
fn fc08_return_query_data() {
    // §6.8: sub-function 0000 echoes its data.
    let mut model = Memory::new(1000);
    assert_exchange(
        &mut model,
        "11 08 00 00 A5 37 D8 1D",
        "11 08 00 00 A5 37 D8 1D",
    );
    // Also with no data, and with the most data a frame can carry (a 256-byte reply).
    let empty = with_crc("11 08 00 00");
    assert_eq!(exchange(&mut model, &empty).1, empty);
    let mut longest = hex("11 08 00 00");
    longest.extend((0..250).map(|n| n as u8));
    longest.extend_from_slice(&crc::to_wire(crc::checksum(&longest)));
    assert_eq!(longest.len(), 256);
    assert_eq!(
        exchange(&mut model, &longest),
        (Handled::Reply(256), longest.clone())
    );
    assert_eq!(model.writes, 0);
}

#[test]
fn fc0f_write_multiple_coils() {
    // §6.11: coils 20–29 (addresses 0x13..) := CD 01 (1011 0011 11 from coil 20 up).
    let mut model = Memory::new(1000);
    model.coils[0x13..0x1D].fill(true);
    model.coils[0x1D] = true; // just past the range: untouched
    assert_exchange(
        &mut model,
        "11 0F 00 13 00 0A 02 CD 01 BF 0B",
        "11 0F 00 13 00 0A 26 99",
    );
    let expected = [
        true, false, true, true, false, false, true, true, true, false,
    ];
    assert_eq!(&model.coils[0x13..0x1D], &expected);
    assert!(model.coils[0x1D]);
}

#[test]
fn fc10_write_multiple_registers() {
    // §6.12: registers 2–3 (addresses 1..) := 0x000A, 0x0102.
    let mut model = Memory::new(1000);
    assert_exchange(
        &mut model,
        "11 10 00 01 00 02 04 00 0A 01 02 C6 F0",
        "11 10 00 01 00 02 12 98",
    );
    assert_eq!(&model.holding[..4], &[0, 0x000A, 0x0102, 0]);
}
