//! What the master asks: the request PDUs of Application Protocol §6, decoded and checked.
//!
//! Checks follow the state diagrams of each function in §6, in their order: an unsupported
//! function code (or FC08 sub-function) is exception 01; a quantity, byte count, PDU length or
//! coil value out of range is exception 03 (§7: "the implied length is incorrect"); an address
//! range past 0xFFFF (`address + quantity > 0x10000`) is exception 02. Whether the addresses
//! exist is the [`DataModel`](super::DataModel)'s business.

use core::fmt;

use super::adu::{Writer, MAX_PDU_LEN};
use super::diag::Diagnostic;
use super::ident::{ReadDevId, MEI_READ_DEVICE_ID};
use super::Exception;

/// FC01 Read Coils (§6.1).
pub const READ_COILS: u8 = 0x01;
/// FC02 Read Discrete Inputs (§6.2).
pub const READ_DISCRETE_INPUTS: u8 = 0x02;
/// FC03 Read Holding Registers (§6.3).
pub const READ_HOLDING_REGISTERS: u8 = 0x03;
/// FC04 Read Input Registers (§6.4).
pub const READ_INPUT_REGISTERS: u8 = 0x04;
/// FC05 Write Single Coil (§6.5).
pub const WRITE_SINGLE_COIL: u8 = 0x05;
/// FC06 Write Single Register (§6.6).
pub const WRITE_SINGLE_REGISTER: u8 = 0x06;
/// FC08 Diagnostics (§6.8; Serial Line §6.1): the sub-functions of [`Diagnostic`].
pub const DIAGNOSTICS: u8 = 0x08;
/// FC15 (0x0F) Write Multiple Coils (§6.11).
pub const WRITE_MULTIPLE_COILS: u8 = 0x0F;
/// FC16 (0x10) Write Multiple Registers (§6.12).
pub const WRITE_MULTIPLE_REGISTERS: u8 = 0x10;
/// FC17 (0x11) Report Server ID (§6.13; serial line only).
pub const REPORT_SERVER_ID: u8 = 0x11;
/// FC43 (0x2B) Encapsulated Interface Transport (§6.19); MEI type 0x0E only (§6.21).
pub const ENCAPSULATED_INTERFACE: u8 = 0x2B;

/// The most bits FC01/FC02 may read (0x07D0).
pub const MAX_READ_BITS: u16 = 2000;
/// The most registers FC03/FC04 may read (0x007D).
pub const MAX_READ_REGISTERS: u16 = 125;
/// The most coils FC0F may write (0x07B0).
pub const MAX_WRITE_BITS: u16 = 1968;
/// The most registers FC10 may write (0x007B).
pub const MAX_WRITE_REGISTERS: u16 = 123;

/// FC05's value for ON; 0x0000 is OFF (§6.5).
pub(super) const COIL_ON: u16 = 0xFF00;
/// FC08 sub-function 0000, Return Query Data (§6.8.1).
const RETURN_QUERY_DATA: u16 = 0x0000;

/// A decoded request; multi-value fields borrow from the frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Request<'a> {
    /// FC01: `quantity` (1..=2000) coils from `address`.
    ReadCoils {
        /// First coil.
        address: u16,
        /// Number of coils.
        quantity: u16,
    },
    /// FC02: `quantity` (1..=2000) discrete inputs from `address`.
    ReadDiscreteInputs {
        /// First input.
        address: u16,
        /// Number of inputs.
        quantity: u16,
    },
    /// FC03: `quantity` (1..=125) holding registers from `address`.
    ReadHoldingRegisters {
        /// First register.
        address: u16,
        /// Number of registers.
        quantity: u16,
    },
    /// FC04: `quantity` (1..=125) input registers from `address`.
    ReadInputRegisters {
        /// First register.
        address: u16,
        /// Number of registers.
        quantity: u16,
    },
    /// FC05: one coil ON (0xFF00 on the wire) or OFF (0x0000).
    WriteSingleCoil {
        /// The coil.
        address: u16,
        /// ON.
        value: bool,
    },
    /// FC06: one holding register.
    WriteSingleRegister {
        /// The register.
        address: u16,
        /// Its new value.
        value: u16,
    },
    /// FC0F: `quantity` (1..=1968) coils from `address`.
    WriteMultipleCoils {
        /// First coil.
        address: u16,
        /// Number of coils.
        quantity: u16,
        /// `ceil(quantity / 8)` bytes; the first coil is bit 0 of the first byte.
        values: &'a [u8],
    },
    /// FC10: `values.len() / 2` (1..=123) holding registers from `address`.
    WriteMultipleRegisters {
        /// First register.
        address: u16,
        /// The values as big-endian pairs (§4.2).
        values: &'a [u8],
    },
    /// FC08 sub-function 0000: the slave echoes `data` (§6.8.1).
    ReturnQueryData {
        /// Whatever followed the sub-function (0..=250 bytes).
        data: &'a [u8],
    },
    /// FC08, another sub-function, with its (checked) two-byte data field.
    Diagnostic {
        /// The sub-function.
        sub: Diagnostic,
        /// Its data field.
        data: u16,
    },
    /// FC11: the server's id, run indicator and description.
    ReportServerId,
    /// FC2B/0E: the device identification objects.
    ReadDeviceId {
        /// Which objects.
        code: ReadDevId,
        /// The first object (or the one, for [`ReadDevId::Individual`]).
        object: u8,
    },
}

/// Why a PDU is not a request to carry out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PduError {
    /// Empty, function code 0, or a code of 0x80 and above (an exception response's): not a
    /// request at all, so nothing sensible can be answered.
    NotARequest,
    /// A request to answer with this exception.
    Exception(Exception),
}

impl fmt::Display for PduError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PduError::NotARequest => f.write_str("not a Modbus request"),
            PduError::Exception(exception) => exception.fmt(f),
        }
    }
}

impl From<Exception> for PduError {
    fn from(exception: Exception) -> PduError {
        PduError::Exception(exception)
    }
}

/// The big-endian 16-bit field at byte `at` of `pdu` (0 if absent: lengths are checked first).
fn field(pdu: &[u8], at: usize) -> u16 {
    match pdu.get(at..at + 2) {
        Some(&[high, low]) => u16::from_be_bytes([high, low]),
        _ => 0,
    }
}

/// Exception 03 unless the PDU is exactly `len` bytes.
fn expect_len(pdu: &[u8], len: usize) -> Result<(), Exception> {
    if pdu.len() == len {
        Ok(())
    } else {
        Err(Exception::IllegalDataValue)
    }
}

/// Exception 03 unless `1 <= quantity <= max`.
fn check_quantity(quantity: u16, max: u16) -> Result<(), Exception> {
    if (1..=max).contains(&quantity) {
        Ok(())
    } else {
        Err(Exception::IllegalDataValue)
    }
}

/// Exception 02 if the range runs past address 0xFFFF.
fn check_range(address: u16, quantity: u16) -> Result<(), Exception> {
    if u32::from(address) + u32::from(quantity) <= 0x1_0000 {
        Ok(())
    } else {
        Err(Exception::IllegalDataAddress)
    }
}

/// Address and quantity of a read (FC01..=04): 5-byte PDU.
fn read(pdu: &[u8], max: u16) -> Result<(u16, u16), Exception> {
    expect_len(pdu, 5)?;
    let (address, quantity) = (field(pdu, 1), field(pdu, 3));
    check_quantity(quantity, max)?;
    check_range(address, quantity)?;
    Ok((address, quantity))
}

/// Address, quantity and values of a multiple write of coils (FC0F) or registers (FC10): byte
/// count == the bytes of the quantity (packed bits, or two per register).
fn write_multiple(pdu: &[u8], coils: bool) -> Result<(u16, u16, &[u8]), Exception> {
    let (address, quantity) = (field(pdu, 1), field(pdu, 3));
    let (max, bytes) = if coils {
        (MAX_WRITE_BITS, usize::from(quantity).div_ceil(8))
    } else {
        (MAX_WRITE_REGISTERS, 2 * usize::from(quantity))
    };
    check_quantity(quantity, max)?;
    let byte_count = usize::from(*pdu.get(5).ok_or(Exception::IllegalDataValue)?);
    if byte_count != bytes {
        return Err(Exception::IllegalDataValue);
    }
    expect_len(pdu, 6 + byte_count)?;
    check_range(address, quantity)?;
    Ok((address, quantity, pdu.get(6..).unwrap_or(&[])))
}

impl<'a> Request<'a> {
    /// Decodes and checks a request PDU (function code and data). A PDU longer than 253 bytes
    /// (§4.1; it cannot come from a frame) is exception 03.
    pub fn parse(pdu: &'a [u8]) -> Result<Request<'a>, PduError> {
        let function = match pdu.first() {
            Some(&code) if (1..0x80).contains(&code) => code,
            _ => return Err(PduError::NotARequest),
        };
        if pdu.len() > MAX_PDU_LEN {
            return Err(Exception::IllegalDataValue.into());
        }
        let request = match function {
            READ_COILS..=READ_INPUT_REGISTERS => {
                let max = if function <= READ_DISCRETE_INPUTS {
                    MAX_READ_BITS
                } else {
                    MAX_READ_REGISTERS
                };
                let (address, quantity) = read(pdu, max)?;
                match function {
                    READ_COILS => Request::ReadCoils { address, quantity },
                    READ_DISCRETE_INPUTS => Request::ReadDiscreteInputs { address, quantity },
                    READ_HOLDING_REGISTERS => Request::ReadHoldingRegisters { address, quantity },
                    _ => Request::ReadInputRegisters { address, quantity },
                }
            }
            WRITE_SINGLE_COIL | WRITE_SINGLE_REGISTER => {
                expect_len(pdu, 5)?;
                let (address, value) = (field(pdu, 1), field(pdu, 3));
                if function == WRITE_SINGLE_REGISTER {
                    Request::WriteSingleRegister { address, value }
                } else {
                    let value = match value {
                        COIL_ON => true,
                        0 => false,
                        _ => return Err(Exception::IllegalDataValue.into()),
                    };
                    Request::WriteSingleCoil { address, value }
                }
            }
            WRITE_MULTIPLE_COILS | WRITE_MULTIPLE_REGISTERS => {
                let coils = function == WRITE_MULTIPLE_COILS;
                let (address, quantity, values) = write_multiple(pdu, coils)?;
                if coils {
                    Request::WriteMultipleCoils {
                        address,
                        quantity,
                        values,
                    }
                } else {
                    Request::WriteMultipleRegisters { address, values }
                }
            }
            DIAGNOSTICS => {
                if pdu.len() < 3 {
                    return Err(Exception::IllegalDataValue.into());
                }
                let code = field(pdu, 1);
                if code == RETURN_QUERY_DATA {
                    Request::ReturnQueryData {
                        data: pdu.get(3..).unwrap_or(&[]),
                    }
                } else {
                    let sub = Diagnostic::from_code(code).ok_or(Exception::IllegalFunction)?;
                    expect_len(pdu, 5)?;
                    let data = field(pdu, 3);
                    if !sub.accepts(data) {
                        return Err(Exception::IllegalDataValue.into());
                    }
                    Request::Diagnostic { sub, data }
                }
            }
            REPORT_SERVER_ID => {
                expect_len(pdu, 1)?;
                Request::ReportServerId
            }
            ENCAPSULATED_INTERFACE => {
                if pdu.get(1) != Some(&MEI_READ_DEVICE_ID) {
                    return Err(Exception::IllegalFunction.into());
                }
                expect_len(pdu, 4)?;
                let code = pdu
                    .get(2)
                    .and_then(|&c| ReadDevId::from_code(c))
                    .ok_or(Exception::IllegalDataValue)?;
                Request::ReadDeviceId {
                    code,
                    object: pdu.get(3).copied().unwrap_or(0),
                }
            }
            _ => return Err(Exception::IllegalFunction.into()),
        };
        Ok(request)
    }

    /// The function code.
    pub fn function(&self) -> u8 {
        match self {
            Request::ReadCoils { .. } => READ_COILS,
            Request::ReadDiscreteInputs { .. } => READ_DISCRETE_INPUTS,
            Request::ReadHoldingRegisters { .. } => READ_HOLDING_REGISTERS,
            Request::ReadInputRegisters { .. } => READ_INPUT_REGISTERS,
            Request::WriteSingleCoil { .. } => WRITE_SINGLE_COIL,
            Request::WriteSingleRegister { .. } => WRITE_SINGLE_REGISTER,
            Request::WriteMultipleCoils { .. } => WRITE_MULTIPLE_COILS,
            Request::WriteMultipleRegisters { .. } => WRITE_MULTIPLE_REGISTERS,
            Request::ReturnQueryData { .. } | Request::Diagnostic { .. } => DIAGNOSTICS,
            Request::ReportServerId => REPORT_SERVER_ID,
            Request::ReadDeviceId { .. } => ENCAPSULATED_INTERFACE,
        }
    }

    /// Whether it writes (FC05, FC06, FC0F, FC10): the only requests a broadcast may carry.
    pub fn is_write(&self) -> bool {
        is_write_function(self.function())
    }

    /// Encodes the request as a whole frame for `unit` into `out` (CRC included) and returns
    /// the frame length; `None` if it does not fit. Fields are written as given, so only a
    /// request that [`parse`](Self::parse) accepts is guaranteed to encode as a valid one (the
    /// master side, for tests and simulators).
    pub fn emit(&self, unit: u8, out: &mut [u8]) -> Option<usize> {
        let mut w = Writer::new(out);
        w.byte(unit);
        w.byte(self.function());
        match *self {
            Request::ReadCoils { address, quantity }
            | Request::ReadDiscreteInputs { address, quantity }
            | Request::ReadHoldingRegisters { address, quantity }
            | Request::ReadInputRegisters { address, quantity } => {
                w.u16(address);
                w.u16(quantity);
            }
            Request::WriteSingleCoil { address, value } => {
                w.u16(address);
                w.u16(if value { COIL_ON } else { 0 });
            }
            Request::WriteSingleRegister { address, value } => {
                w.u16(address);
                w.u16(value);
            }
            Request::WriteMultipleCoils {
                address,
                quantity,
                values,
            } => {
                w.u16(address);
                w.u16(quantity);
                w.len8(values.len());
                w.bytes(values);
            }
            Request::WriteMultipleRegisters { address, values } => {
                w.u16(address);
                w.len16(values.len() / 2);
                w.len8(values.len());
                w.bytes(values);
            }
            Request::ReturnQueryData { data } => {
                w.u16(RETURN_QUERY_DATA);
                w.bytes(data);
            }
            Request::Diagnostic { sub, data } => {
                w.u16(sub.code());
                w.u16(data);
            }
            Request::ReportServerId => {}
            Request::ReadDeviceId { code, object } => {
                w.byte(MEI_READ_DEVICE_ID);
                w.byte(code.code());
                w.byte(object);
            }
        }
        w.finish()
    }
}

/// Whether `function` is one of the supported writes (FC05, FC06, FC0F, FC10).
pub fn is_write_function(function: u8) -> bool {
    matches!(
        function,
        WRITE_SINGLE_COIL | WRITE_SINGLE_REGISTER | WRITE_MULTIPLE_COILS | WRITE_MULTIPLE_REGISTERS
    )
}
