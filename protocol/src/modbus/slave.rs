//! The slave: carries out a checked request against a [`DataModel`] and encodes the reply
//! (Application Protocol §6 for normal replies, §7 for exceptions; Serial Line §2.2 for
//! unicast and broadcast).
//!
//! - Unit 0 is a broadcast: writes (FC05, FC06, FC0F, FC10) are applied and never answered;
//!   anything else sent to unit 0 is ignored.
//! - A unit the model does not [serve](DataModel::serves) is ignored: the frame is another
//!   slave's request, or another slave's reply.
//! - A PDU that is not a request at all (function code 0 or 0x80 and above) is not answered.
//! - In Listen Only mode (FC08 sub-function 04) nothing is answered or carried out, only
//!   counted, until FC08 sub-function 01 (Serial Line §6.1, [`diag`](super::diag)).
//! - Everything else gets exactly one reply: the normal one, or the function code with bit 7 set
//!   and an [`Exception`] code.
//!
//! Memory: the reply goes to a caller-provided [`ReplyBuffer`] (the longest frame: 256 bytes,
//! 260 with feature `tcp`).
//! The model reads into a scratch array inside the [`Slave`], sized to the Modbus maxima: 250
//! bytes of packed bits (FC01/02 read at most 2000) or 125 `u16`s (FC03/04 read at most 125
//! registers, FC10 writes at most 123), 250 bytes shared by the two; FC0F hands the model the
//! request's own packed bits ([`Bits`]). A long write is handed over whole, never in chunks, so
//! the model can validate everything before applying anything. Keeping the scratch in the
//! `Slave` (typically a `static` or a task's state) rather than on the stack keeps
//! [`Slave::handle`]'s stack frame small.

use super::adu::{Adu, FrameError, Framing, Writer};
use super::bits::{Bits, BitsMut};
pub use super::counters::SlaveCounters;
use super::diag::{Diagnostic, LineCounts, OVERRUNS};
use super::ident::{self, RUN_OFF, RUN_ON};
use super::pdu::{self, PduError, Request, MAX_READ_BITS, MAX_READ_REGISTERS};
use super::rtu::Receiver;
use super::{BitTable, DataModel, Exception, RegisterTable, BROADCAST};
use crate::time::Instant;

/// What [`Slave::handle`] did with a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Handled {
    /// Transmit the first `len` bytes of the [`ReplyBuffer`] (a normal or an exception reply).
    Reply(usize),
    /// A broadcast write, applied if the model accepted it; no reply.
    Broadcast,
    /// For another unit, or a broadcast that is not a write; no reply.
    Ignored,
    /// Not a request (function code 0 or 0x80 and above); no reply.
    Malformed,
    /// A request to a unit served, deliberately not answered (Listen Only mode, or the request
    /// that enters or leaves it).
    Silent,
    /// On TCP, a request for a unit nobody serves: answered with exception 0A, the first `len`
    /// bytes of the [`ReplyBuffer`] (never on the serial line, where it is [`Handled::Ignored`]).
    Unserved(usize),
}

/// Adds one to a wrapping counter.
fn bump(counter: &mut u32) {
    *counter = counter.wrapping_add(1);
}

/// The longest reply: an RTU frame (256 bytes), or with feature `tcp` a TCP one (260).
#[cfg(not(feature = "tcp"))]
const REPLY_LEN: usize = super::adu::MAX_ADU_LEN;
/// See above.
#[cfg(feature = "tcp")]
const REPLY_LEN: usize = super::tcp::MAX_TCP_ADU_LEN;

/// The reply to transmit: one frame, RTU or TCP.
#[derive(Clone, Debug)]
pub struct ReplyBuffer {
    bytes: [u8; REPLY_LEN],
    len: usize,
}

impl Default for ReplyBuffer {
    fn default() -> Self {
        ReplyBuffer::new()
    }
}

impl ReplyBuffer {
    /// An empty buffer.
    pub const fn new() -> ReplyBuffer {
        ReplyBuffer {
            bytes: [0; REPLY_LEN],
            len: 0,
        }
    }

    /// The last reply, CRC included; empty if the last frame got none.
    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..self.len).unwrap_or(&[])
    }

    /// The length of the last reply.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the last frame got no reply.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

/// The Modbus RTU slave; see the [module documentation](self).
#[derive(Clone, Debug)]
pub struct Slave {
    scratch: Scratch,
    counters: SlaveCounters,
    /// The serial-line counts at the last restart or clear: FC08 counts from here.
    cleared: LineCounts,
    /// FC08 sub-function 04 is in force.
    listen_only: bool,
}

/// What a request reads or writes: packed bits or registers, never both (one request at a time),
/// so they share their bytes.
// 250 bytes of the node, which lives on the MCU's stack.
#[derive(Clone, Debug)]
enum Scratch {
    /// FC01/FC02: at most 2000 bits.
    Bits([u8; BIT_BYTES]),
    /// FC03/FC04 read at most 125 registers, FC10 writes at most 123.
    Registers([u16; REGISTERS]),
}

/// Bytes of the longest bit read, packed.
const BIT_BYTES: usize = MAX_READ_BITS.div_ceil(8) as usize;
/// Registers of the longest register read.
const REGISTERS: usize = MAX_READ_REGISTERS as usize;

impl Default for Slave {
    fn default() -> Self {
        Slave::new()
    }
}

impl Slave {
    /// A slave with zeroed counters.
    // Not inlined: it makes its scratch in a temporary of its own frame, which is then gone;
    // inlined, the temporary sat in the frame of `Node::new`, on the deepest path at start-up
    // (264 B, `scripts/stack_depth.py`).
    #[inline(never)]
    pub const fn new() -> Slave {
        Slave {
            scratch: Scratch::Registers([0; REGISTERS]),
            counters: SlaveCounters::ZERO,
            cleared: LineCounts::ZERO,
            listen_only: false,
        }
    }

    /// Whether Listen Only mode is in force (FC08 sub-function 04, left with 01).
    pub fn listen_only(&self) -> bool {
        self.listen_only
    }

    /// What has been counted since the slave was made.
    pub fn counters(&self) -> SlaveCounters {
        self.counters
    }

    /// Polls `receiver` at `now` and handles the frame it completes, if any. Bursts that are
    /// not frames are counted and returned as errors (never answered).
    pub fn poll(
        &mut self,
        receiver: &mut Receiver,
        now: Instant,
        model: &mut impl DataModel,
        reply: &mut ReplyBuffer,
    ) -> Option<Result<Handled, FrameError>> {
        match receiver.poll(now)? {
            Ok(adu) => Some(Ok(self.handle(&adu, model, reply))),
            Err(error) => {
                reply.len = 0;
                bump(match error {
                    FrameError::Crc => &mut self.counters.crc_errors,
                    FrameError::TooShort => &mut self.counters.too_short,
                    FrameError::TooLong => &mut self.counters.too_long,
                    FrameError::BadGap => &mut self.counters.bad_gaps,
                });
                Some(Err(error))
            }
        }
    }

    /// Carries out one received frame and writes its reply, if any, into `reply`.
    pub fn handle(
        &mut self,
        adu: &Adu<'_>,
        model: &mut impl DataModel,
        reply: &mut ReplyBuffer,
    ) -> Handled {
        bump(&mut self.counters.frames);
        reply.len = 0;
        let unit = adu.unit();
        let served = if unit == BROADCAST {
            // Only writes are broadcast; any other request to unit 0 is nobody's business (a
            // frame that is no request at all is counted as malformed below).
            pdu::is_write_function(adu.function()) || !(1..0x80).contains(&adu.function())
        } else {
            model.serves(unit)
        };
        if !served {
            bump(&mut self.counters.ignored);
            return Handled::Ignored;
        }
        bump(&mut self.counters.served);
        let request = match Request::parse(adu.pdu()) {
            Err(PduError::NotARequest) => {
                bump(&mut self.counters.malformed);
                bump(&mut self.counters.unanswered);
                return Handled::Malformed;
            }
            Err(PduError::Exception(exception)) => Err(exception),
            Ok(request) => Ok(request),
        };
        if self.listen_only {
            // Monitored and counted; only a restart is carried out (and not answered).
            bump(&mut self.counters.unanswered);
            if let (Ok(Request::Diagnostic { sub, .. }), false) = (request, unit == BROADCAST) {
                if sub == Diagnostic::RestartCommunications {
                    self.restart();
                }
            }
            return Handled::Silent;
        }
        if unit == BROADCAST {
            bump(&mut self.counters.unanswered);
            return self.broadcast(request, model);
        }
        if let Ok(Request::Diagnostic {
            sub: Diagnostic::ForceListenOnly,
            ..
        }) = request
        {
            self.listen_only = true;
            bump(&mut self.counters.unanswered);
            return Handled::Silent;
        }
        self.answer(unit, adu.function(), request, Framing::Rtu, model, reply)
    }

    /// Carries out a request to a served unit and writes its reply, normal or exception, in
    /// `framing`; FC08's restart and clears take effect after their reply.
    fn answer(
        &mut self,
        unit: u8,
        function: u8,
        request: Result<Request<'_>, Exception>,
        framing: Framing,
        model: &mut impl DataModel,
        reply: &mut ReplyBuffer,
    ) -> Handled {
        let result = request.and_then(|request| {
            self.execute(unit, &request, model)?;
            self.encode(unit, function, &request, framing, model, &mut reply.bytes)
        });
        let len = match result {
            Ok(len) => len,
            Err(exception) => self.exception(unit, function, exception, framing, reply),
        };
        reply.len = len;
        bump(&mut self.counters.replies);
        // A restart or a clear takes effect after its own reply, which it echoes.
        match request {
            Ok(Request::Diagnostic {
                sub: Diagnostic::RestartCommunications,
                ..
            }) => self.restart(),
            Ok(Request::Diagnostic {
                sub: Diagnostic::ClearCounters,
                ..
            }) => self.cleared = LineCounts::of(&self.counters),
            Ok(Request::Diagnostic {
                sub: Diagnostic::ClearOverrunCounter,
                ..
            }) => {
                if let Some(overruns) = self.cleared.0.get_mut(OVERRUNS) {
                    *overruns = self.counters.too_long;
                }
            }
            _ => {}
        }
        Handled::Reply(len)
    }

    /// An exception reply, counted; its length.
    fn exception(
        &mut self,
        unit: u8,
        function: u8,
        exception: Exception,
        framing: Framing,
        reply: &mut ReplyBuffer,
    ) -> usize {
        bump(self.counters.exception_counter(exception));
        // Never 0: the buffer holds the longest frame.
        encode_exception(unit, function, exception, framing, &mut reply.bytes).unwrap_or(0)
    }

    /// Carries out one Modbus TCP frame and writes its reply, if any, into `reply`: 0xFF and 0
    /// are `direct_unit` (the device at the IP address, TCP Guide §4.4.2), there is no
    /// broadcast, a unit nobody serves is answered with exception 0A, and FC08 (serial line
    /// only) with 01. The reply echoes the transaction id and the unit id byte.
    #[cfg(feature = "tcp")]
    pub fn handle_tcp(
        &mut self,
        adu: &super::tcp::TcpAdu<'_>,
        direct_unit: u8,
        model: &mut impl DataModel,
        reply: &mut ReplyBuffer,
    ) -> Handled {
        bump(&mut self.counters.frames);
        reply.len = 0;
        let framing = Framing::Tcp {
            transaction: adu.transaction(),
            unit: adu.unit(),
        };
        let unit = match adu.unit() {
            BROADCAST | super::tcp::DIRECT_UNIT => direct_unit,
            unit => unit,
        };
        let function = adu.function();
        if !(1..0x80).contains(&function) {
            bump(&mut self.counters.malformed);
            bump(&mut self.counters.unanswered);
            return Handled::Malformed;
        }
        if !model.serves(unit) {
            bump(&mut self.counters.ignored);
            let exception = Exception::GatewayPathUnavailable;
            reply.len = self.exception(unit, function, exception, framing, reply);
            bump(&mut self.counters.replies);
            return Handled::Unserved(reply.len);
        }
        bump(&mut self.counters.served);
        let request = match Request::parse(adu.pdu()) {
            Ok(Request::Diagnostic { .. } | Request::ReturnQueryData { .. }) => {
                Err(Exception::IllegalFunction)
            }
            Ok(request) => Ok(request),
            Err(PduError::Exception(exception)) => Err(exception),
            // Ruled out above (function codes 1-0x7F are requests).
            Err(PduError::NotARequest) => Err(Exception::IllegalFunction),
        };
        self.answer(unit, function, request, framing, model, reply)
    }

    /// FC08 sub-function 01: the port starts afresh (counters cleared, Listen Only left).
    fn restart(&mut self) {
        self.listen_only = false;
        self.cleared = LineCounts::of(&self.counters);
    }

    /// A request to unit 0: writes are applied, nothing is answered.
    fn broadcast(
        &mut self,
        request: Result<Request<'_>, Exception>,
        model: &mut impl DataModel,
    ) -> Handled {
        bump(&mut self.counters.broadcasts);
        if request
            .and_then(|request| self.execute(BROADCAST, &request, model))
            .is_err()
        {
            bump(&mut self.counters.broadcast_errors);
        }
        Handled::Broadcast
    }

    /// Asks the model: reads fill the scratch, writes are taken from it.
    fn execute(
        &mut self,
        unit: u8,
        request: &Request<'_>,
        model: &mut impl DataModel,
    ) -> Result<(), Exception> {
        match *request {
            Request::ReadCoils { address, quantity }
            | Request::ReadDiscreteInputs { address, quantity } => {
                let table = match request {
                    Request::ReadCoils { .. } => BitTable::Coils,
                    _ => BitTable::DiscreteInputs,
                };
                let mut out = self.bits_mut(quantity)?;
                model.read_bits(unit, table, address, &mut out)
            }
            Request::ReadHoldingRegisters { address, quantity }
            | Request::ReadInputRegisters { address, quantity } => {
                let table = match request {
                    Request::ReadHoldingRegisters { .. } => RegisterTable::Holding,
                    _ => RegisterTable::Input,
                };
                let out = self.registers_mut(quantity)?;
                model.read_registers(unit, table, address, out)
            }
            Request::WriteSingleCoil { address, value } => {
                let byte = [u8::from(value)];
                let bits = Bits::new(&byte, 1).ok_or(Exception::ServerDeviceFailure)?;
                model.write_bits(unit, address, bits)
            }
            Request::WriteSingleRegister { address, value } => {
                model.write_registers(unit, address, &[value])
            }
            Request::WriteMultipleCoils {
                address,
                quantity,
                values,
            } => {
                let bits =
                    Bits::new(values, usize::from(quantity)).ok_or(Exception::IllegalDataValue)?;
                model.write_bits(unit, address, bits)
            }
            Request::WriteMultipleRegisters { address, values } => {
                let quantity = u16::try_from(values.len() / 2).unwrap_or(u16::MAX);
                let registers = self.registers_mut(quantity)?;
                for (register, pair) in registers.iter_mut().zip(values.chunks_exact(2)) {
                    *register = match *pair {
                        [high, low] => u16::from_be_bytes([high, low]),
                        _ => 0,
                    };
                }
                model.write_registers(unit, address, registers)
            }
            // Answered from the slave's own state or the model's identity.
            Request::ReturnQueryData { .. }
            | Request::Diagnostic { .. }
            | Request::ReportServerId
            | Request::ReadDeviceId { .. } => Ok(()),
        }
    }

    /// The first `quantity` scratch bits, cleared.
    fn bits_mut(&mut self, quantity: u16) -> Result<BitsMut<'_>, Exception> {
        if !matches!(self.scratch, Scratch::Bits(_)) {
            self.scratch = Scratch::Bits([0; BIT_BYTES]);
        }
        match &mut self.scratch {
            Scratch::Bits(bits) => BitsMut::new(bits, usize::from(quantity)),
            Scratch::Registers(_) => None,
        }
        .ok_or(Exception::ServerDeviceFailure)
    }

    /// The first `quantity` scratch registers, cleared.
    fn registers_mut(&mut self, quantity: u16) -> Result<&mut [u16], Exception> {
        if !matches!(self.scratch, Scratch::Registers(_)) {
            self.scratch = Scratch::Registers([0; REGISTERS]);
        }
        let registers = match &mut self.scratch {
            Scratch::Registers(registers) => registers.get_mut(..usize::from(quantity)),
            Scratch::Bits(_) => None,
        }
        .ok_or(Exception::ServerDeviceFailure)?;
        registers.fill(0);
        Ok(registers)
    }

    /// The normal reply to a carried-out request (Application Protocol §6); its length, or
    /// the exception to answer instead (04 if it does not fit, which cannot happen). Every
    /// reply starts with the unit and the function code (the frame's: the request's own),
    /// written once for all.
    fn encode(
        &self,
        unit: u8,
        function: u8,
        request: &Request<'_>,
        framing: Framing,
        model: &impl DataModel,
        out: &mut [u8],
    ) -> Result<usize, Exception> {
        let mut w = Writer::frame(out, framing, unit);
        w.byte(function);
        match *request {
            Request::ReadCoils { quantity, .. } | Request::ReadDiscreteInputs { quantity, .. } => {
                let bytes = match &self.scratch {
                    Scratch::Bits(bits) => bits.get(..usize::from(quantity).div_ceil(8)),
                    Scratch::Registers(_) => None,
                }
                .ok_or(Exception::ServerDeviceFailure)?;
                w.len8(bytes.len());
                w.bytes(bytes);
            }
            Request::ReadHoldingRegisters { quantity, .. }
            | Request::ReadInputRegisters { quantity, .. } => {
                let registers = match &self.scratch {
                    Scratch::Registers(registers) => registers.get(..usize::from(quantity)),
                    Scratch::Bits(_) => None,
                }
                .ok_or(Exception::ServerDeviceFailure)?;
                w.len8(2 * registers.len());
                for &register in registers {
                    w.u16(register);
                }
            }
            // FC05 and FC06 echo the request (§6.5, §6.6).
            Request::WriteSingleCoil { address, value } => {
                w.u16(address);
                w.u16(if value { pdu::COIL_ON } else { 0 });
            }
            Request::WriteSingleRegister { address, value } => {
                w.u16(address);
                w.u16(value);
            }
            Request::WriteMultipleCoils {
                address, quantity, ..
            } => {
                w.u16(address);
                w.u16(quantity);
            }
            Request::WriteMultipleRegisters { address, values } => {
                w.u16(address);
                w.len16(values.len() / 2);
            }
            Request::ReturnQueryData { data } => {
                w.u16(0);
                w.bytes(data);
            }
            Request::Diagnostic { sub, data } => {
                let value = match sub {
                    Diagnostic::DiagnosticRegister => model.diagnostic_register(unit),
                    _ => LineCounts::of(&self.counters)
                        .value(&self.cleared, sub)
                        .unwrap_or(data),
                };
                w.u16(sub.code());
                w.u16(value);
            }
            Request::ReportServerId => {
                // Server ID (the unit), run indicator, then "<product code> <revision>".
                let identity = model.identity(unit).ok_or(Exception::IllegalFunction)?;
                let (code, revision) = (identity.product_code, identity.revision);
                let run = if model.running(unit) { RUN_ON } else { RUN_OFF };
                w.len8(code.len() + revision.len() + 3);
                w.byte(unit);
                w.byte(run);
                w.bytes(code.as_bytes());
                w.byte(b' ');
                w.bytes(revision.as_bytes());
            }
            Request::ReadDeviceId { code, object } => {
                let identity = model.identity(unit).ok_or(Exception::IllegalFunction)?;
                ident::write_device_id(&mut w, &identity, code, object)?;
            }
        }
        w.finish().ok_or(Exception::ServerDeviceFailure)
    }
}

/// An exception reply (Application Protocol §7): unit, function | 0x80, code, CRC: 5 bytes
/// (on TCP: the MBAP header, function | 0x80, code: 9 bytes).
fn encode_exception(
    unit: u8,
    function: u8,
    exception: Exception,
    framing: Framing,
    out: &mut [u8],
) -> Option<usize> {
    let mut w = Writer::frame(out, framing, unit);
    w.byte(function | 0x80);
    w.byte(exception.code());
    w.finish()
}
