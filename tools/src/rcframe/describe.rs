//! Requests and replies as JSON objects: every field by name, millimetres when the scale options
//! allow, and the name of a documented memory address.

use crate::rcframe::units::{decimal, hex8, ScaleArgs};
use protocol::alarm::Level;
use protocol::memory;
use protocol::reply::MemoryCode;
use protocol::units::{Length, Scale};
use protocol::{
    Address, Buffered, Command, DataType, HomeDirection, Pulses, Reply, Request, ResetKind, Status,
    StatusReport, Transfer,
};
use protocol::{Inputs, Outputs};
use serde_json::{Map, Value};

/// A JSON object whose keys keep the order they were inserted in.
pub type Object = Map<String, Value>;

/// A command frame from the host.
pub fn request(request: &Request, scale: &ScaleArgs) -> Object {
    let mut obj = Object::new();
    obj.insert("axis".into(), u8::from(request.axis).into());
    obj.insert("direction".into(), "request".into());
    command_fields(&request.command, scale, &mut obj);
    obj
}

/// A response frame from a controller.
pub fn reply(reply: &Reply, scale: &ScaleArgs) -> Object {
    let mut obj = Object::new();
    obj.insert("axis".into(), u8::from(reply.axis()).into());
    obj.insert("direction".into(), "response".into());
    obj.insert("code".into(), reply.code().mnemonic().into());
    match *reply {
        Reply::Status { report, .. } => report_fields(&report, &mut obj),
        Reply::Memory { code, value, .. } => {
            obj.insert("value".into(), word(value));
            if code == MemoryCode::ReadMemory {
                position_fields(
                    Pulses::from_wire(value),
                    scale,
                    Position::Absolute,
                    &mut obj,
                );
            }
        }
    }
    obj
}

fn command_fields(command: &Command, scale: &ScaleArgs, obj: &mut Object) {
    obj.insert("code".into(), command.mnemonic().into());
    let mut put = |key: &str, value: Value| {
        obj.insert(key.into(), value);
    };
    match *command {
        Command::ReadMemory { address } | Command::SetWriteAddress { address } => {
            put("address", hex8(address.0).into());
            if let Some(name) = register(address) {
                put("register", name.into());
            }
        }
        Command::WriteMemory { value } => {
            put("data", word(value));
            position_fields(Pulses::from_wire(value), scale, Position::Absolute, obj);
        }
        Command::LoadToEdit(t) | Command::StoreFromEdit(t) => match t {
            Transfer::Point(point) => put("point", point.get().into()),
            Transfer::CommonParameters => put("common", true.into()),
        },
        Command::EditToExecution(data) => match data {
            DataType::PositionData => put("position_data", true.into()),
            DataType::CommonParameters => put("common", true.into()),
        },
        Command::MoveToPoint(point) => put("point", point.get().into()),
        Command::MoveAbsolute(p) => move_fields(p, scale, Position::Absolute, obj),
        Command::MoveRelative(p) => move_fields(p, scale, Position::Distance, obj),
        Command::CancelMotion | Command::Status | Command::ExecuteBuffered => {}
        Command::Buffer(b) => put("buffered", buffered(&b, scale).into()),
        Command::Home(home) => put("home", home_name(home).into()),
        Command::SetResponseDelay(rtim) => put("rtim", rtim.get().into()),
        Command::Servo(on) => put("servo", if on { "on" } else { "off" }.into()),
        Command::Reset(kind) => put("reset", reset_name(kind).into()),
        Command::SetVelocityAcceleration {
            velocity,
            acceleration,
        } => {
            put("vel", velocity.get().into());
            put("acc", acceleration.get().into());
            if let Some(scale) = scale.velocity() {
                put("mm_s", decimal(scale.speed(velocity).0));
                put("g", decimal(scale.accel(acceleration).0));
            }
        }
    }
}

fn buffered(buffered: &Buffered, scale: &ScaleArgs) -> Object {
    let mut obj = Object::new();
    match buffered.command() {
        Ok(inner) => command_fields(&inner, scale, &mut obj),
        Err(e) => {
            obj.insert("error".into(), e.to_string().into());
        }
    }
    obj
}

/// Whether a pulse value is a position from home or a signed distance (`m`).
#[derive(Clone, Copy)]
enum Position {
    Absolute,
    Distance,
}

/// `a` / `m`: the wire bits, then the pulses and millimetres.
fn move_fields(pulses: Pulses, scale: &ScaleArgs, kind: Position, obj: &mut Object) {
    obj.insert("pulses".into(), pulses.0.into());
    obj.insert("wire".into(), hex8(pulses.to_wire()).into());
    if let Some(mm) = millimetres(pulses, scale, kind) {
        obj.insert("mm".into(), decimal(mm.0));
    }
}

/// A 32-bit word read as pulses, and in mm when the scale is known.
fn position_fields(pulses: Pulses, scale: &ScaleArgs, kind: Position, obj: &mut Object) {
    obj.insert("pulses".into(), pulses.0.into());
    if let Some(mm) = millimetres(pulses, scale, kind) {
        obj.insert("mm".into(), decimal(mm.0));
    }
}

fn millimetres(pulses: Pulses, scale: &ScaleArgs, kind: Position) -> Option<Length> {
    let scale = scale.position()?;
    Some(match kind {
        Position::Absolute => Scale::position_from_wire(&scale, pulses),
        Position::Distance => Scale::distance_from_wire(&scale, pulses),
    })
}

/// A 32-bit word: hex as on the wire, and decimal.
fn word(value: u32) -> Value {
    let mut obj = Object::new();
    obj.insert("hex".into(), hex8(value).into());
    obj.insert("decimal".into(), value.into());
    obj.into()
}

fn home_name(home: HomeDirection) -> &'static str {
    match home {
        HomeDirection::MotorEnd => "motor",
        HomeDirection::NonMotorEnd => "non-motor",
    }
}

fn reset_name(kind: ResetKind) -> &'static str {
    match kind {
        ResetKind::AlarmReset => "alarm-reset",
        ResetKind::InitializeData => "init",
    }
}

/// Status, Alarm, IN and OUT of a direct response.
fn report_fields(report: &StatusReport, obj: &mut Object) {
    let status = flags(Status::NAMED, |f| report.status.contains(f));
    obj.insert("status".into(), status.into());
    obj.insert("alarm".into(), alarm(report).into());
    let mut inputs = flags(Inputs::NAMED, |f| report.inputs.contains(f));
    inputs.insert("pc".into(), report.inputs.pc().into());
    obj.insert("inputs".into(), inputs.into());
    let mut outputs = flags(Outputs::NAMED, |f| report.outputs.contains(f));
    outputs.insert("pm".into(), report.outputs.pm().into());
    obj.insert("outputs".into(), outputs.into());
    obj.insert("rejected".into(), report.rejected().into());
}

/// Every named bit of a byte, by its name in the vendor document.
fn flags<T: Copy>(named: &[(T, &str)], is_set: impl Fn(T) -> bool) -> Object {
    named
        .iter()
        .map(|&(flag, name)| (name.to_owned(), is_set(flag).into()))
        .collect()
}

fn alarm(report: &StatusReport) -> Object {
    let code = report.alarm;
    let mut obj = Object::new();
    obj.insert("code".into(), format!("{:02X}", code.0).into());
    let level = match code.level() {
        Level::Normal => "normal",
        Level::Warning => "warning",
        Level::Error => "error",
    };
    obj.insert("level".into(), level.into());
    obj.insert("text".into(), code.text().into());
    let brief = code.info().and_then(|info| info.brief_text);
    obj.insert("brief_text".into(), brief.into());
    obj
}

/// The name of a documented address (protocol::memory::name), marking execution-area mirrors.
fn register(address: Address) -> Option<String> {
    memory::name(address).map(|(name, area)| match area {
        memory::Area::Execution => format!("{name} (execution area)"),
        memory::Area::Common if memory::PointField::ALL.iter().any(|f| f.code() == name) => {
            format!("{name} (common)")
        }
        _ => name.to_owned(),
    })
}
