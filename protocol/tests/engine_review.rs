//! Regression tests from a review of the engine: each reproduced a bug (a cancelled move resent
//! after its stop, a W4 resent without its T4, an establishment that went on after a rejected
//! or lost T4, a parked frame that beat a stop, a rejoin paced by the probe back-off).

use protocol::engine::*;
use protocol::line::Baud;
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
/// the axis' RTIM, and 1 ms of slack.
fn reply(engine: &mut Engine, now: &mut Instant, reply: Reply) {
    let frame = timing::frame_time(engine.line_baud());
    let rtim = engine::Duration::from_millis(u64::from(engine.axis(reply.axis()).rtim.get()));
    *now = *now
        + frame
            .plus(frame)
            .plus(rtim)
            .plus(engine::Duration::from_millis(1));
    engine.receive(*now, &reply.emit().to_bytes());
}

fn online(engine: &mut Engine, now: &mut Instant, n: usize) {
    let mut address = 0;
    for _ in 0..n {
        let request = next_frame(engine, now);
        reply(engine, now, answer(&request, &mut address));
    }
}

/// R1: a Stop while a job's `a` is in flight; the `a` answer is lost. The `a` must not go out
/// again after the `d`.
#[test]
fn r1_cancelled_job_frame_is_not_resent_after_stop() {
    let mut engine = Engine::new(config(1));
    let mut now = Instant(0);
    online(&mut engine, &mut now, 2);
    engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::MoveAbsolute(Pulses(8000)),
        })
        .unwrap();
    let a = next_frame(&mut engine, &mut now);
    assert_eq!(a.command, Command::MoveAbsolute(Pulses(8000)));
    engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::Stop,
        })
        .unwrap();
    // the `a` answer is lost -> timeout
    let d = next_frame(&mut engine, &mut now);
    assert_eq!(d.command, Command::CancelMotion);
    reply(&mut engine, &mut now, ready(&d));
    let after = next_frame(&mut engine, &mut now);
    assert_ne!(
        after.command,
        Command::MoveAbsolute(Pulses(8000)),
        "the cancelled move was resent after the stop"
    );
}

/// R2: a single-frame W4 job (JobKind::Command) that times out is resent without a T4.
#[test]
fn r2_command_w4_resent_without_t4() {
    let mut engine = Engine::new(config(1));
    let mut now = Instant(0);
    online(&mut engine, &mut now, 2);
    engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::Command(Command::WriteMemory { value: 5 }),
        })
        .unwrap();
    let w = next_frame(&mut engine, &mut now);
    assert_eq!(w.command, Command::WriteMemory { value: 5 });
    let again = next_frame(&mut engine, &mut now);
    assert_ne!(
        again.command,
        Command::WriteMemory { value: 5 },
        "W4 resent without T4"
    );
}

/// R3: during establishment, a lost W4 answer: the W4 is resent without its T4.
#[test]
fn r3_establish_w4_resent_without_t4() {
    let mut engine = Engine::new(Config {
        establish: true,
        ..config(1)
    });
    let mut now = Instant(0);
    let mut address = 0u32;
    let mut sent = vec![];
    let mut dropped = false;
    for _ in 0..200 {
        match engine.poll(now) {
            Output::Transmit(frame) => {
                let r = Request::parse(&frame).unwrap();
                if !engine.establishing() {
                    break;
                }
                sent.push(r.command.code());
                if matches!(r.command, Command::WriteMemory { .. }) && !dropped {
                    dropped = true;
                    address += 1; // executed, answer lost
                    continue;
                }
                let rep = answer(&r, &mut address);
                reply(&mut engine, &mut now, rep);
            }
            Output::Line(_) => {}
            Output::Idle(Some(t)) => now = t.max(now),
            Output::Idle(None) => panic!("idle"),
        }
    }
    println!("{sent:?}");
    assert_eq!(
        &sent[..4],
        &[
            Code::SetResponseDelay,
            Code::SetWriteAddress,
            Code::WriteMemory,
            Code::SetWriteAddress
        ],
        "W4 resent directly: {sent:?}"
    );
}

/// R4: establishment: the T4 is rejected, yet the W4 follows (writes at the old address).
#[test]
fn r4_establish_continues_after_rejection() {
    let mut engine = Engine::new(Config {
        establish: true,
        ..config(1)
    });
    let mut now = Instant(0);
    let mut address = 0u32;
    let mut sent = vec![];
    for _ in 0..200 {
        match engine.poll(now) {
            Output::Transmit(frame) => {
                let r = Request::parse(&frame).unwrap();
                if !engine.establishing() {
                    break;
                }
                sent.push(r.command);
                let rep = if matches!(
                    r.command,
                    Command::SetWriteAddress { .. } | Command::SetResponseDelay(_)
                ) {
                    Reply::Status {
                        axis: r.axis,
                        code: r.command.code(),
                        report: StatusReport {
                            status: Status::REJECTED | Status::POWER,
                            alarm: AlarmCode(0x74),
                            inputs: Inputs::default(),
                            outputs: Outputs::default(),
                        },
                    }
                } else {
                    answer(&r, &mut address)
                };
                reply(&mut engine, &mut now, rep);
            }
            Output::Line(_) => {}
            Output::Idle(Some(t)) => now = t.max(now),
            Output::Idle(None) => panic!("idle"),
        }
    }
    println!("{sent:?} rtim={:?}", engine.axis(axis(0)).rtim);
    assert!(
        !sent
            .iter()
            .any(|c| matches!(c, Command::WriteMemory { .. })),
        "W4 sent after a rejected T4: {sent:?}"
    );
}

/// R5: a job frame parked in `pending` (waiting for a baud switch after a rejoin frame) goes out
/// after a Stop for that axis was submitted, before the `d`.
#[test]
fn r5_pending_job_frame_beats_stop() {
    let mut engine = Engine::new(Config {
        establish: true,
        ..config(2)
    });
    let mut now = Instant(0);
    let mut address = 0u32;
    let mut established = false;
    for _ in 0..100_000 {
        match engine.poll(now) {
            Output::Transmit(frame) => {
                let r = Request::parse(&frame).unwrap();
                if !established && !engine.establishing() {
                    established = true;
                }
                if engine.line_baud() == Baud::B9600 && established && r.axis == axis(1) {
                    // a rejoin frame to axis 1 at 9600: answer it
                    let rep = answer(&r, &mut address);
                    reply(&mut engine, &mut now, rep);
                    engine
                        .submit(Job {
                            axis: axis(0),
                            kind: JobKind::MoveAbsolute(Pulses(8000)),
                        })
                        .unwrap();
                    let out = engine.poll(now + engine::Duration::from_millis(2));
                    now = now + engine::Duration::from_millis(2);
                    println!("after rejoin frame: {out:?}");
                    engine
                        .submit(Job {
                            axis: axis(0),
                            kind: JobKind::Stop,
                        })
                        .unwrap();
                    let first = next_frame(&mut engine, &mut now);
                    println!("first frame after stop: {first:?}");
                    assert_eq!(
                        first.command,
                        Command::CancelMotion,
                        "the cancelled move went out before the stop"
                    );
                    return;
                }
                if established && r.axis == axis(1) {
                    continue;
                } // axis 1 silent at the bus rate
                let rep = answer(&r, &mut address);
                reply(&mut engine, &mut now, rep);
            }
            Output::Line(_) => {}
            Output::Idle(Some(t)) => now = t.max(now),
            Output::Idle(None) => panic!("idle"),
        }
    }
    panic!("no rejoin seen");
}

/// R6: one axis, offline, rejoining: how long between rejoin frames?
#[test]
fn r6_rejoin_pace_single_axis() {
    let mut engine = Engine::new(Config {
        establish: true,
        ..config(1)
    });
    let mut now = Instant(0);
    let mut address = 0u32;
    let mut established = false;
    let mut rejoin_times = vec![];
    let mut log = vec![];
    for _ in 0..100_000 {
        match engine.poll(now) {
            Output::Transmit(frame) => {
                let r = Request::parse(&frame).unwrap();
                if !established && !engine.establishing() {
                    established = true;
                }
                if established {
                    log.push((now.0 / 1000, engine.line_baud(), r.command.code()));
                }
                if engine.line_baud() == Baud::B9600 && established {
                    rejoin_times.push(now.0 / 1000);
                    let rep = answer(&r, &mut address);
                    reply(&mut engine, &mut now, rep);
                    if rejoin_times.len() == 5 {
                        break;
                    }
                    continue;
                }
                if established {
                    continue;
                }
                let rep = answer(&r, &mut address);
                reply(&mut engine, &mut now, rep);
            }
            Output::Line(_) => {}
            Output::Idle(Some(t)) => now = t.max(now),
            Output::Idle(None) => panic!("idle"),
        }
    }
    let gaps: Vec<u64> = rejoin_times.windows(2).map(|w| w[1] - w[0]).collect();
    let _ = log;
    // The first gap is the `p`'s own answer (RTIM still 255 ms at 9.6 kbit/s); after it, each
    // rejoin frame follows its predecessor's answer (~38 ms), not the probe back-off.
    assert!(gaps[0] < 300, "{gaps:?}");
    assert!(
        gaps[1..].iter().all(|&g| g < 60),
        "rejoin frames wait for the probe schedule: {gaps:?}"
    );
}
