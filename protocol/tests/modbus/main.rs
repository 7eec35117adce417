//! The Modbus RTU slave: CRC vectors, the worked examples of the MODBUS Application Protocol
//! V1.1b3 (§6.1–§6.12, §7, all at unit 0x11), broadcast and unit filtering, t3.5/t1.5 framing in
//! virtual time (MODBUS over Serial Line V1.02 §2.5.1.1), and properties over arbitrary input.
//!
//! Every CRC written in these tests was computed twice: by `protocol::modbus::crc` and by an
//! independent bitwise CRC-16/MODBUS (python3, polynomial 0xA001, init 0xFFFF);
//! `spec_frames_have_valid_crcs` re-checks them all with the implementation.

mod examples;
mod exceptions;
mod framing;
mod properties;
mod units;

use protocol::modbus::{
    crc, Adu, BitTable, Bits, BitsMut, DataModel, Exception, Handled, Receiver, RegisterTable,
    ReplyBuffer, Slave,
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

fn with_crc_bytes(mut frame: Vec<u8>) -> Vec<u8> {
    frame.extend_from_slice(&crc::to_wire(crc::checksum(&frame)));
    frame
}
