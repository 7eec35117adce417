//! Responses from a controller (complete edition §3, §4-2, §4-3) and the §5 rules that decide
//! whether a response answers a given command.

use super::field::{Reader, Writer};
use crate::alarm::AlarmCode;
use crate::command::{Code, Request};
use crate::error::{Error, Field};
use crate::frame::Frame;
use crate::status::{Inputs, Outputs, Status, StatusReport};
use crate::types::{Axis, Pulses};

/// The response identifier, first data character of every response.
pub const RESPONSE_ID: u8 = b'U';

/// The memory commands whose response carries a 32-bit operand (complete edition §3-1-1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MemoryCode {
    /// R4: the word read.
    ReadMemory,
    /// T4: the address set, echoed.
    SetWriteAddress,
    /// W4: the next write address (incremented).
    WriteMemory,
    /// V5: the number of times the area has been written.
    Store,
}

impl MemoryCode {
    /// The command character.
    pub const fn code(self) -> Code {
        match self {
            MemoryCode::ReadMemory => Code::ReadMemory,
            MemoryCode::SetWriteAddress => Code::SetWriteAddress,
            MemoryCode::WriteMemory => Code::WriteMemory,
            MemoryCode::Store => Code::Store,
        }
    }

    fn from_code(code: Code) -> Option<MemoryCode> {
        match code {
            Code::ReadMemory => Some(MemoryCode::ReadMemory),
            Code::SetWriteAddress => Some(MemoryCode::SetWriteAddress),
            Code::WriteMemory => Some(MemoryCode::WriteMemory),
            Code::Store => Some(MemoryCode::Store),
            _ => None,
        }
    }

    /// The Func-Num of a successful response: `4`, or `5` for V5.
    pub const fn function_number(self) -> u8 {
        match self {
            MemoryCode::Store => b'5',
            _ => b'4',
        }
    }
}

/// One response frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Reply {
    /// The direct response format (§4-2): `U`, axis, the echoed command character, Status,
    /// Alarm, IN, OUT, `0`.
    ///
    /// Every direct command and Q1/Q2/Q3 answer this way; so does a rejected R4/T4/W4/V5,
    /// whose Func-Num slot then holds the Status byte's high digit, 8-F (§4-3). A `Status` reply
    /// with a memory `code` is therefore only valid with [`Status::REJECTED`] set.
    Status {
        /// The axis that answered.
        axis: Axis,
        /// The echoed command character.
        code: Code,
        /// Status, Alarm, IN, OUT.
        report: StatusReport,
    },
    /// A successful memory response (§3-1-1): `U`, axis, Func-CHAR, Func-Num, 8 hex digits.
    Memory {
        /// The axis that answered.
        axis: Axis,
        /// Which memory command.
        code: MemoryCode,
        /// R4 data, T4 address, W4 next address, or V5 write count.
        value: u32,
    },
}

impl Reply {
    /// The axis that answered.
    pub const fn axis(&self) -> Axis {
        match *self {
            Reply::Status { axis, .. } | Reply::Memory { axis, .. } => axis,
        }
    }

    /// The echoed command character.
    pub const fn code(&self) -> Code {
        match *self {
            Reply::Status { code, .. } => code,
            Reply::Memory { code, .. } => code.code(),
        }
    }

    /// The status, for direct-format responses.
    pub const fn report(&self) -> Option<&StatusReport> {
        match self {
            Reply::Status { report, .. } => Some(report),
            Reply::Memory { .. } => None,
        }
    }

    /// The reason, if the controller rejected the command (Status bit 7, or a memory response
    /// with Func-Num 8-F: complete edition §4-3).
    pub fn rejection(&self) -> Option<AlarmCode> {
        self.report()
            .filter(|report| report.rejected())
            .map(|report| report.alarm)
    }

    /// The 32-bit operand of an R4/T4/W4/V5 response.
    pub const fn memory_value(&self) -> Option<u32> {
        match *self {
            Reply::Memory { value, .. } => Some(value),
            Reply::Status { .. } => None,
        }
    }

    /// An R4 response read as a position or distance (e.g. PNOW at 0x7400).
    pub fn position(&self) -> Option<Pulses> {
        match *self {
            Reply::Memory {
                code: MemoryCode::ReadMemory,
                value,
                ..
            } => Some(Pulses::from_wire(value)),
            _ => None,
        }
    }

    /// The frame a controller sends.
    pub fn emit(&self) -> Frame {
        let mut w = Writer::new();
        w.byte(RESPONSE_ID).byte(self.axis().to_char());
        match *self {
            Reply::Status { code, report, .. } => w
                .byte(code.to_char())
                .hex(2, report.status.bits().into())
                .hex(2, report.alarm.0.into())
                .hex(2, report.inputs.bits().into())
                .hex(2, report.outputs.bits().into())
                .byte(b'0'),
            Reply::Memory { code, value, .. } => w
                .byte(code.code().to_char())
                .byte(code.function_number())
                .hex(8, value),
        };
        Frame::from_data(w.finish())
    }

    /// Read a response frame.
    pub fn parse(frame: &Frame) -> Result<Reply, Error> {
        let mut r = Reader::new(frame.data());
        r.literal(&[RESPONSE_ID])?;
        let axis = Axis::from_char(r.byte()?)?;
        let char = r.byte()?;
        let code = Code::from_char(char).ok_or(Error::UnknownCommand { code: [char, 0] })?;
        if let Some(memory) = MemoryCode::from_code(code) {
            // Func-Num 8-F is the high digit of a rejecting Status byte: direct format (§4-3).
            let num = r.peek()?;
            if num != memory.function_number() {
                return match crate::hex::value(num) {
                    Some(8..=15) => read_status(&mut r, axis, code),
                    _ => Err(Field::FunctionNumber.out_of_range(num)),
                };
            }
            r.byte()?;
            let value = r.hex(8)?;
            return Ok(Reply::Memory {
                axis,
                code: memory,
                value,
            });
        }
        read_status(&mut r, axis, code)
    }

    /// Whether this response answers `request` (complete edition §5): the same axis and the
    /// same first command character. Format and BCC were checked by parsing.
    pub fn answers(&self, request: &Request) -> Result<(), Mismatch> {
        if self.axis() != request.axis {
            return Err(Mismatch::Axis {
                expected: request.axis,
                received: self.axis(),
            });
        }
        if self.code() != request.command.code() {
            return Err(Mismatch::Code {
                expected: request.command.code(),
                received: self.code(),
            });
        }
        Ok(())
    }
}

fn read_status(r: &mut Reader<'_>, axis: Axis, code: Code) -> Result<Reply, Error> {
    // Status, Alarm, IN and OUT as one 8-digit number (one read and one check, not four), then
    // split into its bytes.
    let [status, alarm, inputs, outputs] = r.hex(8)?.to_be_bytes();
    let status = Status::from_bits(status);
    let alarm = AlarmCode(alarm);
    let inputs = Inputs::from_bits(inputs);
    let outputs = Outputs::from_bits(outputs);
    r.zeros(1)?;
    Ok(Reply::Status {
        axis,
        code,
        report: StatusReport {
            status,
            alarm,
            inputs,
            outputs,
        },
    })
}

/// Why a well-formed response does not answer the command sent (complete edition §5).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Mismatch {
    /// Another axis answered (§5 rule 3).
    Axis {
        /// The axis addressed.
        expected: Axis,
        /// The axis that answered.
        received: Axis,
    },
    /// The response echoes another command (§5 rule 4).
    Code {
        /// The command sent.
        expected: Code,
        /// The command echoed.
        received: Code,
    },
}
