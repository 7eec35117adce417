//! The Modbus RTU slave: CRC vectors, the worked examples of the MODBUS Application Protocol
//! V1.1b3 (§6.1–§6.12, §7, all at unit 0x11), broadcast and unit filtering, t3.5/t1.5 framing in
//! virtual time (MODBUS over Serial Line V1.02 §2.5.1.1), and properties over arbitrary input.
//!
//! Every CRC written below was computed twice: by `protocol::modbus::crc` and by an independent
//! bitwise CRC-16/MODBUS (python3, polynomial 0xA001, init 0xFFFF); `spec_frames_have_valid_crcs`
//! re-checks them all with the implementation.

use proptest::prelude::*;
use proptest::sample::select;
use protocol::modbus::{
    crc, t1_5, t3_5, Adu, BitTable, Bits, BitsMut, DataModel, Exception, FrameError, Handled,
    PduError, Receiver, RegisterTable, ReplyBuffer, Request, Slave,
};
use protocol::time::{Duration, Instant};

// ------------------------------------------------------------------------------ test model

/// An in-memory data model: four tables of `size` entries at the units in `units`.
struct Memory {
    units: Vec<u8>,
    coils: Vec<bool>,
    discrete: Vec<bool>,
    holding: Vec<u16>,
    input: Vec<u16>,
    /// Every call fails with exception 04.
    broken: bool,
    writes: usize,
}

impl Memory {
    fn new(size: usize) -> Memory {
        Memory {
            units: vec![0x11],
            coils: vec![false; size],
            discrete: vec![false; size],
            holding: vec![0; size],
            input: vec![0; size],
            broken: false,
            writes: 0,
        }
    }

    /// The whole 16-bit address space.
    fn full() -> Memory {
        Memory::new(0x1_0000)
    }

    fn check(
        &self,
        address: u16,
        len: usize,
        size: usize,
    ) -> Result<std::ops::Range<usize>, Exception> {
        if self.broken {
            return Err(Exception::ServerDeviceFailure);
        }
        let start = usize::from(address);
        if start + len <= size {
            Ok(start..start + len)
        } else {
            Err(Exception::IllegalDataAddress)
        }
    }
}

impl DataModel for Memory {
    fn serves(&self, unit: u8) -> bool {
        assert_ne!(unit, 0, "broadcasts are not asked about");
        self.units.contains(&unit)
    }

    fn read_bits(
        &mut self,
        _: u8,
        table: BitTable,
        address: u16,
        out: &mut BitsMut<'_>,
    ) -> Result<(), Exception> {
        let bits = match table {
            BitTable::Coils => &self.coils,
            BitTable::DiscreteInputs => &self.discrete,
        };
        let range = self.check(address, out.len(), bits.len())?;
        for (i, &bit) in bits[range].iter().enumerate() {
            out.set(i, bit);
        }
        Ok(())
    }

    fn read_registers(
        &mut self,
        _: u8,
        table: RegisterTable,
        address: u16,
        out: &mut [u16],
    ) -> Result<(), Exception> {
        let registers = match table {
            RegisterTable::Holding => &self.holding,
            RegisterTable::Input => &self.input,
        };
        let range = self.check(address, out.len(), registers.len())?;
        out.copy_from_slice(&registers[range]);
        Ok(())
    }

    fn write_bits(&mut self, _: u8, address: u16, values: Bits<'_>) -> Result<(), Exception> {
        let range = self.check(address, values.len(), self.coils.len())?;
        for (slot, bit) in self.coils[range].iter_mut().zip(values.iter()) {
            *slot = bit;
        }
        self.writes += 1;
        Ok(())
    }

    fn write_registers(&mut self, _: u8, address: u16, values: &[u16]) -> Result<(), Exception> {
        let range = self.check(address, values.len(), self.holding.len())?;
        self.holding[range].copy_from_slice(values);
        self.writes += 1;
        Ok(())
    }
}

// ------------------------------------------------------------------------------ helpers

/// Bytes from hex text ("11 03 00 6B").
fn hex(text: &str) -> Vec<u8> {
    text.split_whitespace()
        .map(|byte| u8::from_str_radix(byte, 16).unwrap())
        .collect()
}

/// A frame from hex text without its CRC; the CRC is appended by the implementation.
fn with_crc(text: &str) -> Vec<u8> {
    let mut frame = hex(text);
    frame.extend_from_slice(&crc::to_wire(crc::checksum(&frame)));
    frame
}

/// Hands a whole frame to a fresh slave.
fn exchange(model: &mut Memory, request: &[u8]) -> (Handled, Vec<u8>) {
    let mut slave = Slave::new();
    exchange_with(&mut slave, model, request)
}

fn exchange_with(slave: &mut Slave, model: &mut Memory, request: &[u8]) -> (Handled, Vec<u8>) {
    let adu = Adu::new_checked(request).expect("a valid frame");
    let mut reply = ReplyBuffer::new();
    let handled = slave.handle(&adu, model, &mut reply);
    match handled {
        Handled::Reply(len) => {
            assert_eq!(reply.len(), len);
            assert!(crc::is_valid(reply.as_bytes()));
        }
        _ => assert!(reply.is_empty()),
    }
    (handled, reply.as_bytes().to_vec())
}

/// Asserts that `request` (hex, CRC included) gets exactly `response` (hex, CRC included).
fn assert_exchange(model: &mut Memory, request: &str, response: &str) {
    let (handled, reply) = exchange(model, &hex(request));
    assert_eq!(handled, Handled::Reply(reply.len()), "{request}");
    assert_eq!(reply, hex(response), "{request}");
}

/// Sets bits from packed bytes, the first bit being bit 0 of the first byte (§6.1).
fn set_bits(bits: &mut [bool], address: usize, packed: &str) {
    for (index, byte) in hex(packed).into_iter().enumerate() {
        for bit in 0..8 {
            if let Some(slot) = bits.get_mut(address + index * 8 + bit) {
                *slot = byte >> bit & 1 == 1;
            }
        }
    }
}

/// One character time at 19200 baud, 11 bits: 572.9 µs.
const CHAR_19200: Duration = Duration::from_micros(573);

/// Pushes `bytes` one character time apart from `start`; returns the time of the last one.
fn feed(receiver: &mut Receiver, start: Instant, bytes: &[u8], spacing: Duration) -> Instant {
    let mut now = start;
    for (index, &byte) in bytes.iter().enumerate() {
        if index > 0 {
            now = now + spacing;
        }
        receiver.push(now, byte);
    }
    now
}

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

fn with_crc_bytes(mut frame: Vec<u8>) -> Vec<u8> {
    frame.extend_from_slice(&crc::to_wire(crc::checksum(&frame)));
    frame
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

// ------------------------------------------------------------------------------ framing

#[test]
fn timers_follow_serial_line_2_5_1_1() {
    assert_eq!(t3_5(9_600), Duration::from_micros(4_011)); // 38.5 bits
    assert_eq!(t1_5(9_600), Duration::from_micros(1_719)); // 16.5 bits
    assert_eq!(t3_5(19_200), Duration::from_micros(2_006));
    assert_eq!(t1_5(19_200), Duration::from_micros(860));
    for baud in [19_201, 38_400, 57_600, 115_200, 230_400] {
        assert_eq!(t3_5(baud), Duration::from_micros(1_750));
        assert_eq!(t1_5(baud), Duration::from_micros(750));
    }
    assert_eq!(t3_5(1_200), Duration::from_micros(32_084));
    assert!(t3_5(0) > Duration::from_millis(1000), "no division by zero");
}

#[test]
fn frames_end_after_t3_5_of_silence() {
    let mut receiver = Receiver::new(19_200);
    let t35 = t3_5(19_200);
    assert_eq!(receiver.next_deadline(), None);
    assert!(receiver.poll(Instant(1_000_000)).is_none());
    let frame = hex("11 03 00 6B 00 03 76 87");
    let last = feed(&mut receiver, Instant(1_000), &frame, CHAR_19200);
    assert_eq!(receiver.next_deadline(), Some(last + t35));
    assert!(receiver
        .poll(last + Duration::from_micros(t35.as_micros() - 1))
        .is_none());
    let adu = receiver.poll(last + t35).unwrap().unwrap();
    assert_eq!(
        (adu.unit(), adu.function(), adu.as_bytes()),
        (0x11, 0x03, &frame[..])
    );
    assert_eq!(adu.pdu(), &frame[1..6]);
    assert!(receiver.poll(last + t35).is_none(), "delivered once");
    assert_eq!(receiver.next_deadline(), None);

    // Two frames separated by exactly t3.5 are two frames.
    let second = hex("11 06 00 01 00 03 9A 9B");
    let start = last + t35 + Duration::from_micros(10);
    let end = feed(&mut receiver, start, &frame, CHAR_19200);
    assert!(receiver.poll(end + t35).unwrap().is_ok());
    let end2 = feed(&mut receiver, end + t35, &second, CHAR_19200);
    assert_eq!(
        receiver.poll(end2 + t35).unwrap().unwrap().as_bytes(),
        &second[..]
    );
    assert_eq!(receiver.counters().frames, 3);
    assert_eq!(receiver.counters().overruns, 0);
}

#[test]
fn a_frame_not_polled_in_time_is_an_overrun() {
    let mut receiver = Receiver::new(19_200);
    let t35 = t3_5(19_200);
    let last = feed(
        &mut receiver,
        Instant(0),
        &hex("11 03 00 6B 00 03 76 87"),
        CHAR_19200,
    );
    let second = hex("11 06 00 01 00 03 9A 9B");
    let end = feed(&mut receiver, last + t35, &second, CHAR_19200);
    assert_eq!(
        receiver.poll(end + t35).unwrap().unwrap().as_bytes(),
        &second[..]
    );
    assert_eq!(
        (receiver.counters().frames, receiver.counters().overruns),
        (2, 1)
    );
}

#[test]
fn frames_closer_than_t1_5_merge_and_fail_the_crc() {
    let mut receiver = Receiver::new(19_200);
    let mut bytes = hex("11 03 00 6B 00 03 76 87");
    bytes.extend(hex("11 06 00 01 00 03 9A 9B"));
    let last = feed(&mut receiver, Instant(0), &bytes, CHAR_19200);
    assert_eq!(
        receiver.poll(last + t3_5(19_200)).unwrap(),
        Err(FrameError::Crc)
    );
    assert_eq!(receiver.counters().crc_errors, 1);
}

#[test]
fn a_gap_between_t1_5_and_t3_5_discards_the_frame() {
    let frame = hex("11 03 00 6B 00 03 76 87");
    let gap = Duration::from_micros(1_500); // t1.5 = 860 µs < 1500 µs < t3.5 = 2006 µs
    let run = |receiver: &mut Receiver| {
        let middle = feed(receiver, Instant(0), &frame[..4], CHAR_19200);
        let last = feed(receiver, middle + gap, &frame[4..], CHAR_19200);
        assert!(receiver.poll(last + Duration::from_micros(2_005)).is_none());
        receiver
            .poll(last + t3_5(19_200))
            .unwrap()
            .map(|adu| adu.as_bytes().to_vec())
    };
    let mut receiver = Receiver::new(19_200);
    assert_eq!(run(&mut receiver), Err(FrameError::BadGap));
    assert_eq!(receiver.counters().bad_gaps, 1);
    // Bytes after the gap are discarded too, until t3.5: then the next frame is fine.
    let start = Instant(100_000);
    let last = feed(&mut receiver, start, &frame, CHAR_19200);
    assert_eq!(
        receiver
            .poll(last + t3_5(19_200))
            .unwrap()
            .unwrap()
            .as_bytes(),
        &frame[..]
    );
    // A gap of exactly t1.5 is allowed.
    let middle = feed(&mut receiver, Instant(200_000), &frame[..4], CHAR_19200);
    let last = feed(
        &mut receiver,
        middle + t1_5(19_200),
        &frame[4..],
        CHAR_19200,
    );
    assert!(receiver.poll(last + t3_5(19_200)).unwrap().is_ok());
    // Without the gap check the same timing gives the frame.
    let mut lenient = Receiver::new(19_200).without_gap_check();
    assert_eq!(lenient.t1_5(), None);
    assert_eq!(run(&mut lenient), Ok(frame.clone()));
}

#[test]
fn garbage_over_256_bytes_is_discarded_then_frames_work() {
    let mut receiver = Receiver::new(115_200);
    let mut slave = Slave::new();
    let mut model = Memory::new(1000);
    let mut reply = ReplyBuffer::new();
    let char_time = Duration::from_micros(96);
    let garbage: Vec<u8> = (0..300u32).map(|n| (n * 37 + 11) as u8).collect();
    let last = feed(&mut receiver, Instant(5), &garbage, char_time);
    let deadline = receiver.next_deadline().unwrap();
    assert_eq!(deadline, last + Duration::from_micros(1_750));
    assert_eq!(
        slave.poll(&mut receiver, deadline, &mut model, &mut reply),
        Some(Err(FrameError::TooLong))
    );
    assert!(reply.is_empty());
    let frame = hex("11 03 00 6B 00 03 76 87");
    let last = feed(&mut receiver, deadline, &frame, char_time);
    let handled = slave.poll(
        &mut receiver,
        last + Duration::from_micros(1_750),
        &mut model,
        &mut reply,
    );
    assert_eq!(handled, Some(Ok(Handled::Reply(11))));
    assert_eq!(
        reply.as_bytes(),
        &with_crc("11 03 06 00 00 00 00 00 00")[..]
    );
    let counters = slave.counters();
    assert_eq!(
        (counters.too_long, counters.frames, counters.replies),
        (1, 1, 1)
    );
    assert_eq!(receiver.counters().too_long, 1);

    // 256 bytes is a frame, 257 is not.
    let mut longest = hex("11 08 00 00");
    longest.extend([0x5A; 250]);
    let longest = with_crc_bytes(longest);
    let last = feed(&mut receiver, Instant(1_000_000), &longest, char_time);
    assert_eq!(
        receiver
            .poll(last + Duration::from_micros(1_750))
            .unwrap()
            .unwrap()
            .as_bytes()
            .len(),
        256
    );
    let mut too_long = longest.clone();
    too_long.push(0);
    let last = feed(&mut receiver, Instant(2_000_000), &too_long, char_time);
    assert_eq!(
        receiver.poll(last + Duration::from_micros(1_750)).unwrap(),
        Err(FrameError::TooLong)
    );
}

#[test]
fn crc_errors_are_counted_and_not_answered() {
    let mut receiver = Receiver::new(19_200);
    let mut slave = Slave::new();
    let mut model = Memory::new(1000);
    let mut reply = ReplyBuffer::new();
    let mut frame = hex("11 06 00 01 00 03 9A 9B");
    frame[5] ^= 0x01;
    let last = feed(&mut receiver, Instant(0), &frame, CHAR_19200);
    let result = slave.poll(&mut receiver, last + t3_5(19_200), &mut model, &mut reply);
    assert_eq!(result, Some(Err(FrameError::Crc)));
    assert!(reply.is_empty());
    assert_eq!(model.holding[1], 0);
    assert_eq!(
        (slave.counters().crc_errors, slave.counters().replies),
        (1, 0)
    );
    // Too short.
    let last = feed(
        &mut receiver,
        Instant(100_000),
        &hex("11 03 76"),
        CHAR_19200,
    );
    let result = slave.poll(&mut receiver, last + t3_5(19_200), &mut model, &mut reply);
    assert_eq!(result, Some(Err(FrameError::TooShort)));
    assert_eq!(
        Adu::new_checked(&hex("11 03 76")),
        Err(FrameError::TooShort)
    );
    assert_eq!(Adu::new_checked(&[0; 257]), Err(FrameError::TooLong));
}

#[test]
fn reset_drops_the_burst_in_progress() {
    let mut receiver = Receiver::new(19_200);
    feed(&mut receiver, Instant(0), &hex("11 03 00"), CHAR_19200);
    assert!(receiver.is_busy());
    receiver.reset();
    assert!(!receiver.is_busy() && receiver.next_deadline().is_none());
    let last = feed(
        &mut receiver,
        Instant(600),
        &hex("11 03 00 6B 00 03 76 87"),
        CHAR_19200,
    );
    assert!(receiver.poll(last + t3_5(19_200)).unwrap().is_ok());
}

// ------------------------------------------------------------------------------ properties

/// A request owning its data, so that a strategy can make one.
#[derive(Clone, Debug)]
enum Owned {
    Read {
        function: u8,
        address: u16,
        quantity: u16,
    },
    Coil {
        address: u16,
        value: bool,
    },
    Register {
        address: u16,
        value: u16,
    },
    Coils {
        address: u16,
        bits: Vec<bool>,
    },
    Registers {
        address: u16,
        values: Vec<u16>,
    },
    Echo {
        data: Vec<u8>,
    },
}

/// `(address, quantity)` with `1 <= quantity <= max` and `address + quantity <= 0x10000`.
fn range(max: u16) -> impl Strategy<Value = (u16, u16)> {
    (1..=max).prop_flat_map(|quantity| {
        (
            (0..=(0x1_0000 - u32::from(quantity)) as u16),
            Just(quantity),
        )
    })
}

fn owned() -> impl Strategy<Value = Owned> {
    prop_oneof![
        (select(vec![1u8, 2]), range(2000)).prop_map(|(function, (address, quantity))| {
            Owned::Read {
                function,
                address,
                quantity,
            }
        }),
        (select(vec![3u8, 4]), range(125)).prop_map(|(function, (address, quantity))| {
            Owned::Read {
                function,
                address,
                quantity,
            }
        }),
        (any::<u16>(), any::<bool>()).prop_map(|(address, value)| Owned::Coil { address, value }),
        (any::<u16>(), any::<u16>())
            .prop_map(|(address, value)| Owned::Register { address, value }),
        range(1968).prop_flat_map(|(address, quantity)| {
            proptest::collection::vec(any::<bool>(), usize::from(quantity))
                .prop_map(move |bits| Owned::Coils { address, bits })
        }),
        range(123).prop_flat_map(|(address, quantity)| {
            proptest::collection::vec(any::<u16>(), usize::from(quantity))
                .prop_map(move |values| Owned::Registers { address, values })
        }),
        proptest::collection::vec(any::<u8>(), 0..=250).prop_map(|data| Owned::Echo { data }),
    ]
}

/// The owned request's bytes (packed coils or big-endian registers), then its `Request`.
fn payload(owned: &Owned) -> Vec<u8> {
    match owned {
        Owned::Coils { bits, .. } => bits
            .chunks(8)
            .map(|chunk| {
                chunk
                    .iter()
                    .enumerate()
                    .fold(0u8, |byte, (i, &bit)| byte | (u8::from(bit) << i))
            })
            .collect(),
        Owned::Registers { values, .. } => values
            .iter()
            .flat_map(|value| value.to_be_bytes())
            .collect(),
        Owned::Echo { data } => data.clone(),
        _ => Vec::new(),
    }
}

fn request<'a>(owned: &Owned, payload: &'a [u8]) -> Request<'a> {
    match *owned {
        Owned::Read {
            function: 1,
            address,
            quantity,
        } => Request::ReadCoils { address, quantity },
        Owned::Read {
            function: 2,
            address,
            quantity,
        } => Request::ReadDiscreteInputs { address, quantity },
        Owned::Read {
            function: 3,
            address,
            quantity,
        } => Request::ReadHoldingRegisters { address, quantity },
        Owned::Read {
            address, quantity, ..
        } => Request::ReadInputRegisters { address, quantity },
        Owned::Coil { address, value } => Request::WriteSingleCoil { address, value },
        Owned::Register { address, value } => Request::WriteSingleRegister { address, value },
        Owned::Coils { address, ref bits } => Request::WriteMultipleCoils {
            address,
            quantity: bits.len() as u16,
            values: payload,
        },
        Owned::Registers { address, .. } => Request::WriteMultipleRegisters {
            address,
            values: payload,
        },
        Owned::Echo { .. } => Request::ReturnQueryData { data: payload },
    }
}

/// The expected reply PDU, from the model (after the request was carried out).
fn expected_reply(owned: &Owned, model: &Memory, request_pdu: &[u8]) -> Vec<u8> {
    let pack = |bits: &[bool]| -> Vec<u8> {
        bits.chunks(8)
            .map(|chunk| {
                chunk
                    .iter()
                    .enumerate()
                    .fold(0u8, |byte, (i, &bit)| byte | (u8::from(bit) << i))
            })
            .collect()
    };
    match *owned {
        Owned::Read {
            function,
            address,
            quantity,
        } => {
            let range = usize::from(address)..usize::from(address) + usize::from(quantity);
            let data: Vec<u8> = match function {
                1 => pack(&model.coils[range]),
                2 => pack(&model.discrete[range]),
                3 => model.holding[range]
                    .iter()
                    .flat_map(|r| r.to_be_bytes())
                    .collect(),
                _ => model.input[range]
                    .iter()
                    .flat_map(|r| r.to_be_bytes())
                    .collect(),
            };
            let mut pdu = vec![function, data.len() as u8];
            pdu.extend(data);
            pdu
        }
        Owned::Coils { .. } | Owned::Registers { .. } => request_pdu[..5].to_vec(),
        _ => request_pdu.to_vec(),
    }
}

/// A model with some content, so that reads are not all zeros.
fn patterned() -> Memory {
    let mut model = Memory::full();
    for address in 0..0x1_0000usize {
        model.coils[address] = address % 3 == 0;
        model.discrete[address] = address % 5 == 1;
        model.holding[address] = (address as u16).wrapping_mul(7);
        model.input[address] = !(address as u16);
    }
    model
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// A valid request goes through emit, the receiver and parse unchanged, and gets its
    /// normal (non-exception) reply; writes land in the model.
    #[test]
    fn valid_requests_round_trip_and_get_normal_replies(
        owned in owned(),
        unit in 1u8..=247,
        baud in select(vec![9_600u32, 19_200, 115_200]),
    ) {
        let payload = payload(&owned);
        let request = request(&owned, &payload);
        let mut frame = [0u8; 256];
        let len = request.emit(unit, &mut frame).unwrap();
        let frame = &frame[..len];
        prop_assert!(crc::is_valid(frame));

        let mut receiver = Receiver::new(baud);
        let char_time = Duration::from_micros(11_000_000u64.div_ceil(u64::from(baud)));
        let last = feed(&mut receiver, Instant(123), frame, char_time);
        let deadline = receiver.next_deadline().unwrap();
        prop_assert_eq!(deadline, last + t3_5(baud));
        let adu = receiver.poll(deadline).unwrap().unwrap();
        prop_assert_eq!(adu.as_bytes(), frame);
        prop_assert_eq!(Request::parse(adu.pdu()), Ok(request));

        let mut model = patterned();
        model.units = vec![unit];
        let mut slave = Slave::new();
        let mut reply = ReplyBuffer::new();
        let handled = slave.handle(&adu, &mut model, &mut reply);
        prop_assert_eq!(handled, Handled::Reply(reply.len()));
        let bytes = reply.as_bytes();
        prop_assert!(crc::is_valid(bytes) && bytes.len() <= 256);
        prop_assert_eq!(bytes[0], unit);
        prop_assert_eq!(&bytes[1..bytes.len() - 2], &expected_reply(&owned, &model, adu.pdu())[..]);
        match owned {
            Owned::Coil { address, value } => prop_assert_eq!(model.coils[usize::from(address)], value),
            Owned::Register { address, value } => prop_assert_eq!(model.holding[usize::from(address)], value),
            Owned::Coils { address, ref bits } => {
                let start = usize::from(address);
                prop_assert_eq!(&model.coils[start..start + bits.len()], &bits[..]);
            }
            Owned::Registers { address, ref values } => {
                let start = usize::from(address);
                prop_assert_eq!(&model.holding[start..start + values.len()], &values[..]);
            }
            _ => prop_assert_eq!(model.writes, 0),
        }
        prop_assert_eq!(slave.counters().replies, 1);
    }

    /// Whatever parses is canonical: emitting it gives back the PDU.
    #[test]
    fn parse_is_canonical(pdu in proptest::collection::vec(any::<u8>(), 0..260)) {
        if let Ok(request) = Request::parse(&pdu) {
            let mut frame = [0u8; 256];
            let len = request.emit(0x11, &mut frame).unwrap();
            prop_assert_eq!(&frame[1..len - 2], &pdu[..]);
        }
    }

    /// Arbitrary bytes at arbitrary times: no panic, replies are whole frames of at most 256
    /// bytes for a served unit, and every burst is accounted for.
    #[test]
    fn arbitrary_streams_never_panic(
        stream in proptest::collection::vec((0u32..5_000, any::<u8>()), 0..1_200),
        baud in select(vec![1_200u32, 9_600, 19_200, 38_400, 115_200]),
        gap_check in any::<bool>(),
        poll_late in any::<bool>(),
    ) {
        let mut receiver = if gap_check { Receiver::new(baud) } else { Receiver::new(baud).without_gap_check() };
        let mut slave = Slave::new();
        let mut model = Memory::new(300);
        model.units = vec![0x11, 0x01];
        let mut reply = ReplyBuffer::new();
        let mut now = Instant(0);
        let mut polled = 0u32;
        for (gap, byte) in stream {
            now = now + Duration::from_micros(u64::from(gap));
            if !poll_late {
                if let Some(deadline) = receiver.next_deadline() {
                    if deadline <= now && slave.poll(&mut receiver, deadline, &mut model, &mut reply).is_some() {
                        polled += 1;
                    }
                }
            }
            if let Some(Ok(Handled::Reply(len))) = slave.poll(&mut receiver, now, &mut model, &mut reply) {
                prop_assert!(len <= 256 && crc::is_valid(reply.as_bytes()));
            }
            receiver.push(now, byte);
        }
        if slave.poll(&mut receiver, now + Duration::from_millis(100), &mut model, &mut reply).is_some() {
            polled += 1;
        }
        let rx = receiver.counters();
        let bursts = rx.frames + rx.too_short + rx.too_long + rx.crc_errors + rx.bad_gaps;
        prop_assert_eq!(bursts - rx.overruns, slave.counters().frames + slave.counters().crc_errors
            + slave.counters().too_short + slave.counters().too_long + slave.counters().bad_gaps);
        prop_assert!(polled <= bursts);
    }
}
