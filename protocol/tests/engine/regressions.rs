//! Regressions found by review (R1-R6), each failed before its fix.

use protocol::engine::*;
use protocol::line::Baud;
use protocol::time::{Duration, Instant};
use protocol::*;

use crate::{answer, axis, config, next_frame, ready, reply};

// ---------------------------------------------------------------- regressions found by review (each failed before its fix)

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

/// Run the establishment procedure, answering each frame through `answer_with` (`None`: the
/// answer is lost); the commands sent, until polling starts.
fn establish_with(
    engine: &mut Engine,
    mut answer_with: impl FnMut(&Request, &mut u32) -> Option<Reply>,
) -> Vec<Command> {
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
                if let Some(rep) = answer_with(&r, &mut address) {
                    reply(engine, &mut now, rep);
                }
            }
            Output::Line(_) => {}
            Output::Idle(Some(t)) => now = t.max(now),
            Output::Idle(None) => panic!("idle"),
        }
    }
    sent
}

/// R3: during establishment, a lost W4 answer: the W4 was resent without its T4.
#[test]
fn r3_establish_w4_resent_without_t4() {
    let mut engine = Engine::new(Config {
        establish: true,
        ..config(1)
    });
    let mut dropped = false;
    let sent = establish_with(&mut engine, |r, address| {
        if matches!(r.command, Command::WriteMemory { .. }) && !dropped {
            dropped = true;
            *address += 1; // executed, answer lost
            return None;
        }
        Some(answer(r, address))
    });
    let codes: Vec<Code> = sent.iter().map(Command::code).collect();
    assert_eq!(
        &codes[..4],
        &[
            Code::SetResponseDelay,
            Code::SetWriteAddress,
            Code::WriteMemory,
            Code::SetWriteAddress
        ],
        "W4 resent directly: {codes:?}"
    );
}

/// R4: establishment: the T4 was rejected, yet the W4 followed (writing at the old address).
#[test]
fn r4_establish_continues_after_rejection() {
    let mut engine = Engine::new(Config {
        establish: true,
        ..config(1)
    });
    let sent = establish_with(&mut engine, |r, address| {
        Some(match r.command {
            Command::SetWriteAddress { .. } | Command::SetResponseDelay(_) => Reply::Status {
                axis: r.axis,
                code: r.command.code(),
                report: StatusReport {
                    status: Status::REJECTED | Status::POWER,
                    alarm: AlarmCode(0x74),
                    inputs: Inputs::default(),
                    outputs: Outputs::default(),
                },
            },
            _ => answer(r, address),
        })
    });
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
                    let out = engine.poll(now + Duration::from_millis(2));
                    now = now + Duration::from_millis(2);
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
    for _ in 0..100_000 {
        match engine.poll(now) {
            Output::Transmit(frame) => {
                let r = Request::parse(&frame).unwrap();
                if !established && !engine.establishing() {
                    established = true;
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
    // The first gap is the `p`'s own answer (RTIM still 255 ms at 9.6 kbit/s); after it, each
    // rejoin frame follows its predecessor's answer (~38 ms), not the probe back-off.
    assert!(gaps[0] < 300, "{gaps:?}");
    assert!(
        gaps[1..].iter().all(|&g| g < 60),
        "rejoin frames wait for the probe schedule: {gaps:?}"
    );
}
