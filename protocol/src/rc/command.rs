//! Commands from the host (complete edition §4-1, §4-4; brief edition §4-2).
//!
//! A [`Request`] is an axis and a [`Command`]; [`Request::emit`] writes the 12 data characters and
//! [`Request::parse`] reads them back, rejecting anything the documents do not define.

use super::field::{Reader, Writer};
use crate::error::{Error, Field};
use crate::frame::{Frame, DATA_LEN};
use crate::types::{
    Acceleration, Address, Axis, DataType, HomeDirection, PositionNo, Pulses, ResetKind, Rtim,
    Transfer, Velocity,
};

/// The command character (Func-CHAR), which a valid response echoes (complete edition §5 rule 4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Code {
    /// `R` (R4): memory read.
    ReadMemory,
    /// `T` (T4): write addressing.
    SetWriteAddress,
    /// `W` (W4): memory write.
    WriteMemory,
    /// `Q` (Q1, Q2, Q3): transfers and move to point; all three answer `Q`.
    Transfer,
    /// `V` (V5): edit area to non-volatile memory.
    Store,
    /// `a`: absolute move.
    MoveAbsolute,
    /// `d`: cancel remaining motion.
    CancelMotion,
    /// `h`: buffer a command.
    Buffer,
    /// `m`: relative move.
    MoveRelative,
    /// `n`: status read.
    Status,
    /// `o`: home.
    Home,
    /// `p`: minimum response delay.
    SetResponseDelay,
    /// `q`: servo on/off.
    Servo,
    /// `r`: reset.
    Reset,
    /// `t`: execute buffered commands (broadcast).
    ExecuteBuffered,
    /// `v`: velocity and acceleration.
    SetVelocityAcceleration,
}

impl Code {
    /// Every code, in the order of the documents' command tables.
    pub const ALL: [Code; 16] = [
        Code::ReadMemory,
        Code::SetWriteAddress,
        Code::WriteMemory,
        Code::Transfer,
        Code::Store,
        Code::MoveAbsolute,
        Code::CancelMotion,
        Code::Buffer,
        Code::MoveRelative,
        Code::Status,
        Code::Home,
        Code::SetResponseDelay,
        Code::Servo,
        Code::Reset,
        Code::ExecuteBuffered,
        Code::SetVelocityAcceleration,
    ];

    /// The character on the wire.
    pub const fn to_char(self) -> u8 {
        match self {
            Code::ReadMemory => b'R',
            Code::SetWriteAddress => b'T',
            Code::WriteMemory => b'W',
            Code::Transfer => b'Q',
            Code::Store => b'V',
            Code::MoveAbsolute => b'a',
            Code::CancelMotion => b'd',
            Code::Buffer => b'h',
            Code::MoveRelative => b'm',
            Code::Status => b'n',
            Code::Home => b'o',
            Code::SetResponseDelay => b'p',
            Code::Servo => b'q',
            Code::Reset => b'r',
            Code::ExecuteBuffered => b't',
            Code::SetVelocityAcceleration => b'v',
        }
    }

    /// The name the documents use: `R4`, `T4`, `W4`, `Q` (Q1/Q2/Q3 all answer `Q`), `V5`, `a`...
    pub const fn mnemonic(self) -> &'static str {
        match self {
            Code::ReadMemory => "R4",
            Code::SetWriteAddress => "T4",
            Code::WriteMemory => "W4",
            Code::Transfer => "Q",
            Code::Store => "V5",
            Code::MoveAbsolute => "a",
            Code::CancelMotion => "d",
            Code::Buffer => "h",
            Code::MoveRelative => "m",
            Code::Status => "n",
            Code::Home => "o",
            Code::SetResponseDelay => "p",
            Code::Servo => "q",
            Code::Reset => "r",
            Code::ExecuteBuffered => "t",
            Code::SetVelocityAcceleration => "v",
        }
    }

    /// The code of a character, if it is one.
    pub fn from_char(c: u8) -> Option<Code> {
        Code::ALL.into_iter().find(|code| code.to_char() == c)
    }

    /// Memory commands answer with a 32-bit operand, not the status (complete edition §3-1-1).
    /// Q1/Q2/Q3 are memory commands but answer in the direct format, so this is false for them.
    pub const fn memory_function_number(self) -> Option<u8> {
        match self {
            Code::ReadMemory | Code::SetWriteAddress | Code::WriteMemory => Some(b'4'),
            Code::Store => Some(b'5'),
            _ => None,
        }
    }
}

/// A command, without its axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    /// R4 (§4-4-1): read the 32-bit word at `address`.
    ReadMemory {
        /// Address to read.
        address: Address,
    },
    /// T4 (§4-4-2): set the address the next W4 writes to.
    SetWriteAddress {
        /// Address in the edit area.
        address: Address,
    },
    /// W4 (§4-4-3): write a 32-bit word at the write address, which then increments.
    WriteMemory {
        /// The word.
        value: u32,
    },
    /// Q1 (§4-4-4): non-volatile memory to edit area.
    LoadToEdit(Transfer),
    /// Q2 (§4-4-5): edit area to execution area (with position data: a move).
    EditToExecution(DataType),
    /// Q3 (§4-4-6): move to a point-table position (homing first if ZFIN is off).
    MoveToPoint(PositionNo),
    /// V5 (§4-4-7): edit area to non-volatile memory. Wears the memory: 100,000 writes per area.
    StoreFromEdit(Transfer),
    /// `a` (§4-4-8): move to an absolute position.
    MoveAbsolute(Pulses),
    /// `d` (§4-4-9): cancel the remaining motion (target := present position).
    CancelMotion,
    /// `h` (§4-4-10): buffer a command until `t`.
    Buffer(Buffered),
    /// `m` (§4-4-11): move by a distance from the present target. Never resend on time-out.
    MoveRelative(Pulses),
    /// `n` (§4-4-12): read the status.
    Status,
    /// `o` (§4-4-13): home.
    Home(HomeDirection),
    /// `p` (§4-4-14): set the minimum response delay RTIM.
    SetResponseDelay(Rtim),
    /// `q` (§4-4-15): servo on (`true`) or off.
    Servo(bool),
    /// `r` (§4-4-16): reset.
    Reset(ResetKind),
    /// `t` (§4-4-17): every axis runs its buffered command; only the addressed axis answers.
    ExecuteBuffered,
    /// `v2` (§4-4-18): velocity and acceleration of the execution area.
    SetVelocityAcceleration {
        /// Velocity in 0.2 rpm.
        velocity: Velocity,
        /// Acceleration in 0.1 rpm/ms.
        acceleration: Acceleration,
    },
}

/// Characters of a command after the axis (11); `h` carries the first 10 of them.
const INFO_LEN: usize = DATA_LEN - 1;
/// Characters `h` carries (§4-4-10: the command with its last `0` removed).
const BUFFERED_LEN: usize = INFO_LEN - 1;

impl Command {
    /// The command character.
    pub const fn code(&self) -> Code {
        match self {
            Command::ReadMemory { .. } => Code::ReadMemory,
            Command::SetWriteAddress { .. } => Code::SetWriteAddress,
            Command::WriteMemory { .. } => Code::WriteMemory,
            Command::LoadToEdit(_) | Command::EditToExecution(_) | Command::MoveToPoint(_) => {
                Code::Transfer
            }
            Command::StoreFromEdit(_) => Code::Store,
            Command::MoveAbsolute(_) => Code::MoveAbsolute,
            Command::CancelMotion => Code::CancelMotion,
            Command::Buffer(_) => Code::Buffer,
            Command::MoveRelative(_) => Code::MoveRelative,
            Command::Status => Code::Status,
            Command::Home(_) => Code::Home,
            Command::SetResponseDelay(_) => Code::SetResponseDelay,
            Command::Servo(_) => Code::Servo,
            Command::Reset(_) => Code::Reset,
            Command::ExecuteBuffered => Code::ExecuteBuffered,
            Command::SetVelocityAcceleration { .. } => Code::SetVelocityAcceleration,
        }
    }

    /// The name the documents use: `Q1`, `Q2`, `Q3`, or the code's [`Code::mnemonic`].
    pub const fn mnemonic(&self) -> &'static str {
        match self {
            Command::LoadToEdit(_) => "Q1",
            Command::EditToExecution(_) => "Q2",
            Command::MoveToPoint(_) => "Q3",
            _ => self.code().mnemonic(),
        }
    }

    /// Whether `h` may buffer this command: Q2, Q3 and every direct command but `h` (§4-4-10).
    pub const fn bufferable(&self) -> bool {
        !matches!(
            self,
            Command::ReadMemory { .. }
                | Command::SetWriteAddress { .. }
                | Command::WriteMemory { .. }
                | Command::LoadToEdit(_)
                | Command::StoreFromEdit(_)
                | Command::Buffer(_)
        )
    }

    /// Whether the command can start motion (complete edition §4-1 notes 1, 3, 4).
    pub fn moves(&self) -> bool {
        match self {
            Command::EditToExecution(DataType::PositionData)
            | Command::MoveToPoint(_)
            | Command::MoveAbsolute(_)
            | Command::MoveRelative(_)
            | Command::Home(_)
            | Command::ExecuteBuffered => true,
            Command::Buffer(b) => b.moves,
            _ => false,
        }
    }

    /// Whether resending after a time-out could repeat a motion: `m` must never be resent
    /// (complete edition §5 (2)); `t` is confirmed by polling `n` instead (§5 (3)).
    pub fn resendable(&self) -> bool {
        match self {
            Command::MoveRelative(_) | Command::ExecuteBuffered => false,
            Command::Buffer(b) => b.resendable,
            _ => true,
        }
    }

    /// The 11 characters after the axis.
    fn write(&self, w: &mut Writer) {
        w.byte(self.code().to_char());
        match *self {
            Command::ReadMemory { address } | Command::SetWriteAddress { address } => {
                w.byte(b'4').hex(8, address.0)
            }
            Command::WriteMemory { value } => w.byte(b'4').hex(8, value),
            Command::LoadToEdit(t) => write_transfer(w.byte(b'1'), t),
            Command::EditToExecution(d) => w.byte(b'2').hex(2, d.code().into()),
            Command::MoveToPoint(p) => w.bytes(b"301").hex(2, p.get().into()),
            Command::StoreFromEdit(t) => write_transfer(w.byte(b'5'), t),
            Command::MoveAbsolute(p) | Command::MoveRelative(p) => w.hex(8, p.to_wire()),
            Command::CancelMotion | Command::Status | Command::ExecuteBuffered => w,
            Command::Buffer(b) => w.bytes(&b.chars),
            Command::Home(d) => w.hex(2, d.code().into()),
            Command::SetResponseDelay(rtim) => w.bytes(b"trw").hex(2, rtim.get().into()),
            Command::Servo(on) => w.byte(if on { b'1' } else { b'0' }),
            Command::Reset(kind) => w.hex(2, kind.code().into()),
            Command::SetVelocityAcceleration {
                velocity,
                acceleration,
            } => w
                .byte(b'2')
                .hex(4, velocity.get().into())
                .hex(4, acceleration.get().into()),
        };
    }

    /// Read the 11 characters after the axis.
    fn read(r: &mut Reader<'_>) -> Result<Command, Error> {
        let char = r.byte()?;
        let code = Code::from_char(char).ok_or(Error::UnknownCommand { code: [char, 0] })?;
        // Every layout is 11 characters; `zeros` is how many filler zeros close it.
        let (command, zeros) = match code {
            Code::ReadMemory | Code::SetWriteAddress | Code::WriteMemory => {
                function_number(r, char, b'4')?;
                let value = r.hex(8)?;
                let command = match code {
                    Code::ReadMemory => Command::ReadMemory {
                        address: Address(value),
                    },
                    Code::SetWriteAddress => Command::SetWriteAddress {
                        address: Address(value),
                    },
                    _ => Command::WriteMemory { value },
                };
                (command, 1)
            }
            Code::Transfer => {
                let num = r.byte()?;
                match num {
                    b'1' => (Command::LoadToEdit(read_transfer(r)?), 5),
                    b'2' => (
                        Command::EditToExecution(DataType::from_code(r.hex_u8()?)?),
                        7,
                    ),
                    b'3' => {
                        let typ = r.hex_u8()?;
                        if typ != 0x01 {
                            return Err(Field::TransferType.out_of_range(typ));
                        }
                        (Command::MoveToPoint(PositionNo::decode(r.hex_u8()?)?), 5)
                    }
                    _ => return Err(Error::UnknownCommand { code: [char, num] }),
                }
            }
            Code::Store => {
                function_number(r, char, b'5')?;
                (Command::StoreFromEdit(read_transfer(r)?), 5)
            }
            Code::MoveAbsolute => (Command::MoveAbsolute(Pulses::from_wire(r.hex(8)?)), 2),
            Code::MoveRelative => (Command::MoveRelative(Pulses::from_wire(r.hex(8)?)), 2),
            Code::CancelMotion => (Command::CancelMotion, 10),
            Code::Status => (Command::Status, 10),
            Code::ExecuteBuffered => (Command::ExecuteBuffered, 10),
            Code::Buffer => {
                let mut chars = [b'0'; BUFFERED_LEN];
                for slot in chars.iter_mut() {
                    *slot = r.byte()?;
                }
                let unchecked = Buffered {
                    chars,
                    moves: false,
                    resendable: false,
                };
                // The inner command must itself be valid and bufferable.
                let inner = unchecked.command()?;
                if !inner.bufferable() {
                    return Err(Field::BufferedCommand.out_of_range(inner.code().to_char()));
                }
                let buffered = Buffered {
                    moves: inner.moves(),
                    resendable: inner.resendable(),
                    ..unchecked
                };
                (Command::Buffer(buffered), 0)
            }
            Code::Home => (Command::Home(HomeDirection::from_code(r.hex_u8()?)?), 8),
            Code::SetResponseDelay => {
                r.literal(b"trw")?;
                let value = r.hex_u8()?;
                let rtim = Rtim::new(value).ok_or(Field::Rtim.out_of_range(value))?;
                (Command::SetResponseDelay(rtim), 5)
            }
            Code::Servo => {
                let flag = r.byte()?;
                let on = match flag {
                    b'0' => false,
                    b'1' => true,
                    _ => return Err(Field::Servo.out_of_range(flag)),
                };
                (Command::Servo(on), 9)
            }
            Code::Reset => (Command::Reset(ResetKind::from_code(r.hex_u8()?)?), 8),
            Code::SetVelocityAcceleration => {
                let vtyp = r.byte()?;
                if vtyp != b'2' {
                    return Err(Field::VelocityType.out_of_range(vtyp));
                }
                let v = r.hex_u16()?;
                let a = r.hex_u16()?;
                let velocity = Velocity::new(v).ok_or(Field::Velocity.out_of_range(v))?;
                let acceleration =
                    Acceleration::new(a).ok_or(Field::Acceleration.out_of_range(a))?;
                (
                    Command::SetVelocityAcceleration {
                        velocity,
                        acceleration,
                    },
                    1,
                )
            }
        };
        r.zeros(zeros)?;
        Ok(command)
    }
}

fn function_number(r: &mut Reader<'_>, char: u8, expected: u8) -> Result<(), Error> {
    let num = r.byte()?;
    if num == expected {
        Ok(())
    } else {
        Err(Error::UnknownCommand { code: [char, num] })
    }
}

fn write_transfer(w: &mut Writer, transfer: Transfer) -> &mut Writer {
    match transfer {
        Transfer::CommonParameters => w.bytes(b"0000"),
        Transfer::Point(p) => w.bytes(b"01").hex(2, p.get().into()),
    }
}

fn read_transfer(r: &mut Reader<'_>) -> Result<Transfer, Error> {
    let typ = r.hex_u8()?;
    let pos = r.hex_u8()?;
    match (typ, pos) {
        (0x00, 0x00) => Ok(Transfer::CommonParameters),
        (0x00, _) => Err(Field::PositionNo.out_of_range(pos)),
        (0x01, _) => Ok(Transfer::Point(PositionNo::decode(pos)?)),
        _ => Err(Field::TransferType.out_of_range(typ)),
    }
}

/// The command inside `h`: its 11 characters less the final `0` (complete edition §4-4-10).
///
/// Built only from a bufferable [`Command`] or a parsed frame, so it always holds a valid one.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Buffered {
    chars: [u8; BUFFERED_LEN],
    /// The inner command's [`Command::moves`] and [`Command::resendable`], known when it was
    /// built, so that asking does not decode it again (and the firmware needs no decoder).
    moves: bool,
    resendable: bool,
}

impl Buffered {
    /// Buffer `command`, if `h` may carry it (Q2, Q3, direct commands other than `h`).
    pub fn new(command: &Command) -> Option<Buffered> {
        if !command.bufferable() {
            return None;
        }
        let mut w = Writer::new();
        command.write(&mut w);
        let info = w.finish();
        let mut chars = [b'0'; BUFFERED_LEN];
        // The first 10 of its 11 characters (the last is the `0` that `h` drops).
        chars.copy_from_slice(info.get(..BUFFERED_LEN)?);
        Some(Buffered {
            chars,
            moves: command.moves(),
            resendable: command.resendable(),
        })
    }

    /// The buffered command.
    ///
    /// Never fails for a value built by [`Buffered::new`] or by parsing a frame; the `Result`
    /// is there because the check is a decode, and decoding is never assumed to succeed.
    pub fn command(&self) -> Result<Command, Error> {
        let mut data = [b'0'; DATA_LEN];
        // Data character 0 is the axis position; the buffered characters follow, then `0`.
        data.iter_mut()
            .skip(1)
            .zip(self.chars.iter())
            .for_each(|(slot, &c)| *slot = c);
        let mut r = Reader::new(&data);
        r.byte()?;
        Command::read(&mut r)
    }
}

impl core::fmt::Debug for Buffered {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.command() {
            Ok(command) => write!(f, "Buffered({command:?})"),
            Err(_) => write!(f, "Buffered({:02X?})", self.chars),
        }
    }
}

/// A command addressed to an axis: one frame from the host.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Request {
    /// The axis addressed (for `t`, the axis that answers for all).
    pub axis: Axis,
    /// The command.
    pub command: Command,
}

impl Request {
    /// `command` for `axis`.
    pub const fn new(axis: Axis, command: Command) -> Request {
        Request { axis, command }
    }

    /// The frame to send.
    pub fn emit(&self) -> Frame {
        let mut w = Writer::new();
        w.byte(self.axis.to_char());
        self.command.write(&mut w);
        Frame::from_data(w.finish())
    }

    /// Read a command frame, as a controller (or the simulator) would.
    pub fn parse(frame: &Frame) -> Result<Request, Error> {
        let mut r = Reader::new(frame.data());
        let axis = Axis::from_char(r.byte()?)?;
        let command = Command::read(&mut r)?;
        Ok(Request { axis, command })
    }
}
