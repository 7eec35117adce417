//! A Modbus **slave** (server), sans-IO: the PLC is the master and talks to the gateway, over a
//! serial line (RTU) or, with feature `tcp`, over TCP ([`tcp`](self#modbus-tcp)): one slave, one
//! register map, two framings.
//!
//! Sources: "MODBUS over Serial Line Specification and Implementation Guide V1.02" (*Serial
//! Line*) and "MODBUS Application Protocol Specification V1.1b3" (*Application Protocol*);
//! section numbers below refer to them.
//!
//! | Module | What it answers |
//! |---|---|
//! | [`crc`] | CRC-16/MODBUS (Serial Line §2.5.1.2, §6.2.2) |
//! | [`adu`] | What a serial frame is: unit id, PDU, CRC, at most 256 bytes (Serial Line §2.5.1) |
//! | [`rtu`] | Where frames end: t3.5 silence, t1.5 gaps ([`Receiver`], Serial Line §2.5.1.1) |
//! | [`pdu`] | What the master asks ([`Request`], Application Protocol §6) |
//! | [`slave`] | What the slave answers ([`Slave`], exceptions of Application Protocol §7) |
//! | `tcp` | Modbus TCP: MBAP frames, connections (feature `tcp`) |
//!
//! # Modbus TCP
//! Module `tcp` (feature `tcp`): MBAP frames in a connection's byte stream and the table of
//! connections; [`Slave::handle_tcp`] answers a frame with the serial line's model.
//!
//! This module holds what the gateway implements: the [`DataModel`] trait (the four tables of
//! Application Protocol §4.3) and the [`Exception`]s it may return.
//!
//! ```
//! use protocol::modbus::{
//!     BitTable, Bits, BitsMut, DataModel, Exception, Handled, Receiver, RegisterTable,
//!     ReplyBuffer, Slave,
//! };
//! use protocol::time::Instant;
//!
//! /// Ten holding registers at unit 0x11.
//! struct Registers([u16; 10]);
//!
//! impl DataModel for Registers {
//!     fn serves(&self, unit: u8) -> bool {
//!         unit == 0x11
//!     }
//!     fn read_bits(&mut self, _: u8, _: BitTable, _: u16, _: &mut BitsMut) -> Result<(), Exception> {
//!         Err(Exception::IllegalFunction)
//!     }
//!     fn read_registers(
//!         &mut self, _: u8, _: RegisterTable, address: u16, out: &mut [u16],
//!     ) -> Result<(), Exception> {
//!         let start = usize::from(address);
//!         let source = self.0.get(start..start + out.len()).ok_or(Exception::IllegalDataAddress)?;
//!         out.copy_from_slice(source);
//!         Ok(())
//!     }
//!     fn write_bits(&mut self, _: u8, _: u16, _: Bits) -> Result<(), Exception> {
//!         Err(Exception::IllegalFunction)
//!     }
//!     fn write_registers(&mut self, _: u8, address: u16, values: &[u16]) -> Result<(), Exception> {
//!         let start = usize::from(address);
//!         let target = self.0.get_mut(start..start + values.len());
//!         target.ok_or(Exception::IllegalDataAddress)?.copy_from_slice(values);
//!         Ok(())
//!     }
//! }
//!
//! let mut model = Registers([0, 0, 7, 0, 0, 0, 0, 0, 0, 0]);
//! let mut receiver = Receiver::new(19_200);
//! let mut slave = Slave::new();
//! let mut reply = ReplyBuffer::new();
//!
//! // The PLC reads holding register 2 (one character every 573 µs at 19200 baud).
//! let mut now = Instant(0);
//! for &byte in &[0x11, 0x03, 0x00, 0x02, 0x00, 0x01, 0x27, 0x5A] {
//!     receiver.push(now, byte);
//!     now = now + protocol::time::Duration::from_micros(573);
//! }
//! assert!(slave.poll(&mut receiver, now, &mut model, &mut reply).is_none(), "t3.5 not over");
//! let deadline = receiver.next_deadline().ok_or("a frame is pending")?;
//! let handled = slave.poll(&mut receiver, deadline, &mut model, &mut reply);
//! assert_eq!(handled, Some(Ok(Handled::Reply(7))));
//! assert_eq!(reply.as_bytes(), &[0x11, 0x03, 0x02, 0x00, 0x07, 0x38, 0x45]);
//! # Ok::<(), &str>(())
//! ```

pub mod adu;
pub mod bits;
pub mod client;
mod counters;
pub mod crc;
pub mod diag;
pub mod ident;
pub mod pdu;
pub mod rtu;
pub mod slave;
#[cfg(feature = "tcp")]
pub mod tcp;

pub use adu::{Adu, FrameError, Framing, MAX_ADU_LEN, MAX_PDU_LEN};
pub use bits::{Bits, BitsMut};
pub use counters::SlaveCounters;
pub use diag::Diagnostic;
pub use ident::{Identity, ReadDevId};
pub use pdu::{PduError, Request};
pub use rtu::{chars_time, t1_5, t3_5, Receiver, ReceiverCounters};
pub use slave::{Handled, ReplyBuffer, Slave};

use core::fmt;

/// The unit id of a broadcast request (Serial Line §2.2): every slave applies it, none answers.
pub const BROADCAST: u8 = 0;

/// What a Modbus slave exposes (the gateway's register map implements it).
///
/// The [`Slave`] has already checked the request's structure and limits (Application Protocol
/// §6: quantities, byte counts, coil values, `address + quantity <= 0x10000`) before calling a
/// method; the model checks that the addresses exist (else
/// [`Exception::IllegalDataAddress`]) and that the values are acceptable (else
/// [`Exception::IllegalDataValue`]). The slices hold exactly the requested quantity.
///
/// Unit 0 (broadcast) is never passed to [`serves`](DataModel::serves): broadcast writes are
/// always applied, with `unit == 0` (Serial Line §2.2), and never answered.
pub trait DataModel {
    /// Whether requests to this unit id are answered; others are ignored (no reply, counted).
    fn serves(&self, unit: u8) -> bool;
    /// FC01 (coils) / FC02 (discrete inputs): fill `out` with `out.len()` bits from `address`
    /// (all 0 when called).
    fn read_bits(
        &mut self,
        unit: u8,
        table: BitTable,
        address: u16,
        out: &mut BitsMut<'_>,
    ) -> Result<(), Exception>;
    /// FC03 (holding) / FC04 (input registers): fill `out` from `address`.
    fn read_registers(
        &mut self,
        unit: u8,
        table: RegisterTable,
        address: u16,
        out: &mut [u16],
    ) -> Result<(), Exception>;
    /// FC05/FC0F: write coils. Validate everything before applying anything.
    fn write_bits(&mut self, unit: u8, address: u16, values: Bits<'_>) -> Result<(), Exception>;
    /// FC06/FC10: write holding registers. Validate everything before applying anything.
    fn write_registers(&mut self, unit: u8, address: u16, values: &[u16]) -> Result<(), Exception>;

    /// FC08 sub-function 02: the unit's diagnostic register (device-specific bits).
    fn diagnostic_register(&self, _unit: u8) -> u16 {
        0
    }

    /// FC2B/0E and FC11: who the unit is; `None` answers both with exception 01.
    fn identity(&self, _unit: u8) -> Option<Identity> {
        None
    }

    /// FC11's run indicator: whether the unit is running (ON) or not (OFF).
    fn running(&self, _unit: u8) -> bool {
        true
    }
}

/// The single-bit tables (Application Protocol §4.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BitTable {
    /// Read-write bits: FC01 reads, FC05 and FC0F write.
    Coils,
    /// Read-only bits: FC02.
    DiscreteInputs,
}

/// The 16-bit tables (Application Protocol §4.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RegisterTable {
    /// Read-write registers: FC03 reads, FC06 and FC10 write.
    Holding,
    /// Read-only registers: FC04.
    Input,
}

/// An exception code (Application Protocol §7): the reply is the function code with bit 7 set,
/// then this code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Exception {
    /// 01: the function code (or FC08 sub-function) is not supported.
    IllegalFunction = 1,
    /// 02: the address, or the address range, does not exist.
    IllegalDataAddress = 2,
    /// 03: a value in the request is not allowed (quantity, byte count, length, coil value...).
    IllegalDataValue = 3,
    /// 04: an unrecoverable error while performing the action.
    ServerDeviceFailure = 4,
    /// 0A: a gateway has no path to the unit (on TCP: a unit id the gateway does not serve).
    GatewayPathUnavailable = 0x0A,
}

impl Exception {
    /// The code on the wire.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The exception with this code, if it is one of those above.
    pub const fn from_code(code: u8) -> Option<Exception> {
        match code {
            1 => Some(Exception::IllegalFunction),
            2 => Some(Exception::IllegalDataAddress),
            3 => Some(Exception::IllegalDataValue),
            4 => Some(Exception::ServerDeviceFailure),
            0x0A => Some(Exception::GatewayPathUnavailable),
            _ => None,
        }
    }
}

impl fmt::Display for Exception {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let text = match self {
            Exception::IllegalFunction => "illegal function",
            Exception::IllegalDataAddress => "illegal data address",
            Exception::IllegalDataValue => "illegal data value",
            Exception::ServerDeviceFailure => "server device failure",
            Exception::GatewayPathUnavailable => "gateway path unavailable",
        };
        write!(f, "Modbus exception {:02X}: {text}", self.code())
    }
}
