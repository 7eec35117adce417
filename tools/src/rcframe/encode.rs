//! `rcframe encode`: build any command frame from its code and options.
//!
//! Each command of the documents is a subcommand named by its code (`n`, `Q3`, `R4`, ...). The
//! ones `h` may buffer are a separate enum, `Bufferable`, so that `h` takes exactly those.

use crate::rcframe::units::{
    decimal, parse_accel, parse_axis, parse_hex_u32, parse_lead, parse_length, parse_point,
    parse_pulses, parse_raw_u16, parse_rtim, parse_speed, Home, ScaleArgs,
};
use clap::{Args, Subcommand, ValueEnum};
use protocol::frame::COMM_CHANGE;
use protocol::units::{Accel, Lead, Length, Scale, Speed};
use protocol::{
    Acceleration, Address, Axis, Buffered, Command, DataType, PositionNo, Pulses, Request,
    ResetKind, Rtim, Transfer, Velocity,
};

/// `rcframe encode <axis> <command> [options]`.
#[derive(Args, Debug)]
pub struct EncodeArgs {
    /// Axis 0-15: one hex digit (C; upper case, as a-f are command names) or a decimal number (12); not needed for `enq`
    #[arg(value_parser = parse_axis)]
    axis: Option<Axis>,
    #[command(subcommand)]
    command: Cmd,
    /// Print the whole 16-byte frame as hex bytes (02 ... 03)
    #[arg(long, global = true)]
    hex: bool,
}

/// Every command.
#[derive(Subcommand, Debug)]
enum Cmd {
    /// R4: read the 32-bit word at an address
    #[command(name = "R4")]
    R4(AddressArgs),
    /// T4: set the address the next W4 writes to
    #[command(name = "T4")]
    T4(AddressArgs),
    /// W4: write a 32-bit word at the write address
    #[command(name = "W4")]
    W4(WordArgs),
    /// Q1: non-volatile memory to edit area (a point-table row or the common parameters)
    #[command(name = "Q1")]
    Q1(TransferArgs),
    /// V5: edit area to non-volatile memory (wears it: ~100,000 writes)
    #[command(name = "V5")]
    V5(TransferArgs),
    /// h: buffer a command until `t` (Q2, Q3 or a direct command other than h)
    #[command(name = "h")]
    H {
        #[command(subcommand)]
        inner: Bufferable,
    },
    #[command(flatten)]
    Direct(Bufferable),
    /// The communication-change broadcast STX + 14 ENQ + ETX (always printed as hex)
    #[command(name = "enq")]
    Enq,
}

/// The commands `h` may buffer (complete edition §4-4-10).
#[derive(Subcommand, Debug)]
enum Bufferable {
    /// Q2: edit area to execution area (position data starts a move)
    #[command(name = "Q2")]
    Q2(DataTypeArgs),
    /// Q3: move to a point-table position
    #[command(name = "Q3")]
    Q3 {
        /// Position number 0-15
        #[arg(long, value_parser = parse_point)]
        point: PositionNo,
    },
    /// a: move to an absolute position
    #[command(name = "a")]
    A(PositionArgs),
    /// d: cancel the remaining motion
    #[command(name = "d")]
    D,
    /// m: move by a distance (--mm is signed: + is away from home)
    #[command(name = "m")]
    M(PositionArgs),
    /// n: read the status
    #[command(name = "n")]
    N,
    /// o: home
    #[command(name = "o")]
    O {
        /// The end to home to
        #[arg(long, value_enum)]
        home: Home,
    },
    /// p: set the minimum response delay RTIM
    #[command(name = "p")]
    P {
        /// Milliseconds, 3-255
        #[arg(long, value_parser = parse_rtim)]
        rtim: Rtim,
    },
    /// q: servo on or off
    #[command(name = "q")]
    Q {
        #[arg(value_enum)]
        state: OnOff,
    },
    /// r: alarm reset or data initialisation
    #[command(name = "r")]
    R {
        #[arg(value_enum)]
        kind: Reset,
    },
    /// t: every axis runs its buffered command (only the addressed one answers)
    #[command(name = "t")]
    T,
    /// v: velocity and acceleration of the execution area
    #[command(name = "v")]
    V(VelocityArgs),
}

#[derive(Args, Debug)]
struct AddressArgs {
    /// Address in hex (e.g. 7400 for PNOW)
    #[arg(long, value_parser = parse_hex_u32)]
    address: u32,
}

#[derive(Args, Debug)]
#[group(required = true, multiple = false)]
struct TransferArgs {
    /// Point-table row 0-15
    #[arg(long, value_parser = parse_point)]
    point: Option<PositionNo>,
    /// The common parameters
    #[arg(long)]
    common: bool,
}

#[derive(Args, Debug)]
#[group(required = true, multiple = false)]
struct DataTypeArgs {
    /// Position data (the axis moves)
    #[arg(long)]
    position_data: bool,
    /// The common parameters
    #[arg(long)]
    common: bool,
}

#[derive(Args, Debug)]
struct PositionArgs {
    /// Pulses: signed decimal, or 0x and the 32 bits on the wire
    #[arg(long, allow_hyphen_values = true, value_parser = parse_pulses,
          conflicts_with = "mm", required_unless_present = "mm")]
    pulses: Option<Pulses>,
    /// Millimetres, up to 2 decimals (needs --lead and --home)
    #[arg(long, allow_hyphen_values = true, value_parser = parse_length, requires_all = ["lead", "home"])]
    mm: Option<Length>,
    #[command(flatten)]
    scale: ScaleArgs,
}

#[derive(Args, Debug)]
struct WordArgs {
    /// The word in hex
    #[arg(long, value_parser = parse_hex_u32, conflicts_with = "mm", required_unless_present = "mm")]
    data: Option<u32>,
    /// A position in mm, up to 2 decimals (needs --lead and --home)
    #[arg(long, allow_hyphen_values = true, value_parser = parse_length, requires_all = ["lead", "home"])]
    mm: Option<Length>,
    #[command(flatten)]
    scale: ScaleArgs,
}

#[derive(Args, Debug)]
struct VelocityArgs {
    /// Raw velocity in 0.2 rpm (decimal or 0x hex)
    #[arg(long, value_parser = parse_raw_u16, conflicts_with = "mm_s", required_unless_present = "mm_s")]
    vel: Option<u16>,
    /// Raw acceleration in 0.1 rpm/ms (decimal or 0x hex)
    #[arg(long, value_parser = parse_raw_u16, conflicts_with = "g", required_unless_present = "g")]
    acc: Option<u16>,
    /// Speed in mm/s, up to 2 decimals (needs --lead)
    #[arg(long = "mm-s", value_parser = parse_speed, requires = "lead")]
    mm_s: Option<Speed>,
    /// Acceleration in G, up to 2 decimals (needs --lead)
    #[arg(long, value_parser = parse_accel, requires = "lead")]
    g: Option<Accel>,
    /// Screw lead in mm
    #[arg(long, value_parser = parse_lead)]
    lead: Option<Lead>,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum OnOff {
    On,
    Off,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Reset {
    /// r03: clear the alarm (servo off)
    AlarmReset,
    /// r02: load the shipped defaults
    Init,
}

/// The line to print: 14 characters, or the 16 bytes as hex.
pub fn run(args: &EncodeArgs) -> Result<String, String> {
    if let Cmd::Enq = args.command {
        return Ok(hex_bytes(&COMM_CHANGE));
    }
    let axis = args
        .axis
        .ok_or("give the axis before the command (e.g. `rcframe encode 0 n`)")?;
    let frame = Request::new(axis, command(&args.command)?).emit();
    Ok(if args.hex {
        hex_bytes(&frame.to_bytes())
    } else {
        String::from_utf8_lossy(&frame.to_text()).into_owned()
    })
}

/// Bytes as upper-case hex pairs separated by spaces.
pub fn hex_bytes(bytes: &[u8]) -> String {
    let pairs: Vec<String> = bytes.iter().map(|b| format!("{b:02X}")).collect();
    pairs.join(" ")
}

fn command(cmd: &Cmd) -> Result<Command, String> {
    Ok(match cmd {
        Cmd::R4(a) => Command::ReadMemory {
            address: Address(a.address),
        },
        Cmd::T4(a) => Command::SetWriteAddress {
            address: Address(a.address),
        },
        Cmd::W4(w) => Command::WriteMemory { value: word(w)? },
        Cmd::Q1(t) => Command::LoadToEdit(transfer(t)),
        Cmd::V5(t) => Command::StoreFromEdit(transfer(t)),
        Cmd::H { inner } => {
            let inner = direct(inner)?;
            Command::Buffer(Buffered::new(&inner).ok_or("h cannot buffer this command")?)
        }
        Cmd::Enq => return Err("enq is not a command frame".to_owned()),
        Cmd::Direct(b) => direct(b)?,
    })
}

fn direct(cmd: &Bufferable) -> Result<Command, String> {
    Ok(match cmd {
        Bufferable::Q2(d) => Command::EditToExecution(if d.position_data {
            DataType::PositionData
        } else {
            DataType::CommonParameters
        }),
        Bufferable::Q3 { point } => Command::MoveToPoint(*point),
        Bufferable::A(p) => Command::MoveAbsolute(pulses(p, Scale::position_to_wire)?),
        Bufferable::D => Command::CancelMotion,
        Bufferable::M(p) => Command::MoveRelative(pulses(p, Scale::distance_to_wire)?),
        Bufferable::N => Command::Status,
        Bufferable::O { home } => Command::Home((*home).into()),
        Bufferable::P { rtim } => Command::SetResponseDelay(*rtim),
        Bufferable::Q { state } => Command::Servo(matches!(state, OnOff::On)),
        Bufferable::R { kind } => Command::Reset(match kind {
            Reset::AlarmReset => ResetKind::AlarmReset,
            Reset::Init => ResetKind::InitializeData,
        }),
        Bufferable::T => Command::ExecuteBuffered,
        Bufferable::V(v) => velocity_acceleration(v)?,
    })
}

type ToWire = fn(&Scale, Length) -> Result<Pulses, protocol::units::UnitError>;

/// The pulses given, or the millimetres converted by `to_wire` (position or distance).
fn pulses(args: &PositionArgs, to_wire: ToWire) -> Result<Pulses, String> {
    match (args.pulses, args.mm) {
        (Some(pulses), _) => Ok(pulses),
        (None, Some(mm)) => convert(&args.scale, mm, to_wire),
        (None, None) => Err("give --pulses or --mm".to_owned()),
    }
}

fn word(args: &WordArgs) -> Result<u32, String> {
    match (args.data, args.mm) {
        (Some(data), _) => Ok(data),
        (None, Some(mm)) => convert(&args.scale, mm, Scale::position_to_wire).map(Pulses::to_wire),
        (None, None) => Err("give --data or --mm".to_owned()),
    }
}

fn convert(scale: &ScaleArgs, mm: Length, to_wire: ToWire) -> Result<Pulses, String> {
    to_wire(&scale.require_position()?, mm)
        .map_err(|e| format!("{} mm cannot be sent: {e:?}", decimal(mm.0)))
}

fn transfer(args: &TransferArgs) -> Transfer {
    match args.point {
        Some(point) if !args.common => Transfer::Point(point),
        _ => Transfer::CommonParameters,
    }
}

fn velocity_acceleration(args: &VelocityArgs) -> Result<Command, String> {
    let scale = args
        .lead
        .map(|lead| Scale::new(lead, protocol::HomeDirection::MotorEnd));
    let scale = || scale.ok_or("--mm-s and --g need --lead");
    let velocity = match (args.vel, args.mm_s) {
        (Some(raw), _) => Velocity::new(raw).ok_or(format!(
            "velocity {raw:#X} is above the maximum {:#X}",
            Velocity::MAX.get()
        ))?,
        (None, Some(speed)) => scale()?
            .velocity(speed)
            .map_err(|e| format!("speed cannot be sent: {e:?}"))?,
        (None, None) => return Err("give --vel or --mm-s".to_owned()),
    };
    let acceleration = match (args.acc, args.g) {
        (Some(raw), _) => Acceleration::new(raw).ok_or(format!(
            "acceleration {raw:#X} is not {:#X}-{:#X}",
            Acceleration::MIN.get(),
            Acceleration::MAX.get()
        ))?,
        (None, Some(accel)) => scale()?
            .acceleration(accel)
            .map_err(|e| format!("acceleration cannot be sent: {e:?}"))?,
        (None, None) => return Err("give --acc or --g".to_owned()),
    };
    Ok(Command::SetVelocityAcceleration {
        velocity,
        acceleration,
    })
}
