//! The bus-master engine against a scripted bus, in virtual time: the §5 and §6-1 rules that
//! need no simulator. (End-to-end behaviour against the simulator lives in the host crate.)

mod off_bus;
mod regressions;
mod rules;

use protocol::engine::*;
use protocol::line::Baud;
use protocol::time::{Duration, Instant};
use protocol::*;

fn axis(n: u8) -> Axis {
    Axis::new(n).unwrap()
}

fn config(axes: u8) -> Config {
    Config {
        axes: AxisSet::first(axes),
        baud: Baud::B115200,
        rtim: Rtim::MIN,
        retries: 2,
        establish: false,
        ..Config::default()
    }
}

/// A status response: servo on, run, homed, PFIN, ZFIN, no alarm.
fn ready(request: &Request) -> Reply {
    Reply::Status {
        axis: request.axis,
        code: request.command.code(),
        report: StatusReport {
            status: Status::POWER | Status::SERVO | Status::RUN | Status::HOME,
            alarm: AlarmCode::NONE,
            inputs: Inputs::default(),
            outputs: Outputs::PFIN | Outputs::ZFIN | Outputs::ALM_N,
        },
    }
}

/// A controller that answers everything sensibly (memory commands echo/increment).
fn answer(request: &Request, write_address: &mut u32) -> Reply {
    let memory = |code, value| Reply::Memory {
        axis: request.axis,
        code,
        value,
    };
    match request.command {
        Command::ReadMemory { address } => memory(MemoryCode::ReadMemory, address.0),
        Command::SetWriteAddress { address } => {
            *write_address = address.0;
            memory(MemoryCode::SetWriteAddress, address.0)
        }
        Command::WriteMemory { .. } => {
            *write_address += 1;
            memory(MemoryCode::WriteMemory, *write_address)
        }
        Command::StoreFromEdit(_) => memory(MemoryCode::Store, 1),
        _ => ready(request),
    }
}

/// Drive the engine until it transmits, returning the request and the time it was sent.
fn next_frame(engine: &mut Engine, now: &mut Instant) -> Request {
    for _ in 0..1000 {
        match engine.poll(*now) {
            Output::Transmit(frame) => return Request::parse(&frame).unwrap(),
            Output::Line(_) => {}
            Output::Idle(Some(until)) => *now = until.max(*now),
            Output::Idle(None) => panic!("engine idle with nothing to do"),
        }
    }
    panic!("no frame")
}

/// When a real controller's answer would be complete: the command and the answer on the wire,
/// the axis' RTIM, and 1 ms of slack (an earlier frame cannot be the answer).
fn answer_delay(engine: &Engine, axis: Axis) -> Duration {
    let frame = timing::frame_time(engine.line_baud());
    let rtim = Duration::from_millis(u64::from(engine.axis(axis).rtim.get()));
    frame.plus(frame).plus(rtim).plus(Duration::from_millis(1))
}

fn reply(engine: &mut Engine, now: &mut Instant, reply: Reply) {
    *now = *now + answer_delay(engine, reply.axis());
    engine.receive(*now, &reply.emit().to_bytes());
}

fn events(engine: &mut Engine) -> Vec<Event> {
    std::iter::from_fn(|| engine.next_event()).collect()
}
