//! The bus-master engine against a scripted bus, in virtual time: the §5 and §6-1 rules that
//! need no simulator. (End-to-end behaviour against the simulator lives in the host crate.)

use protocol::engine::*;
use protocol::line::Baud;
use protocol::memory::PointField;
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

#[test]
fn polls_every_configured_axis_round_robin_with_host_gap() {
    let mut engine = Engine::new(config(3));
    let mut now = Instant(0);
    let mut seen = vec![];
    let mut address = 0;
    while seen.len() < 9 {
        let request = next_frame(&mut engine, &mut now);
        let replied_at = now + answer_delay(&engine, request.axis);
        reply(&mut engine, &mut now, answer(&request, &mut address));
        assert_eq!(
            engine.poll(now),
            Output::Idle(Some(replied_at + timing::HOST_GAP))
        );
        seen.push((request.axis.get(), request.command));
    }
    // Status polls round-robin; each axis' position is read once after it first answers.
    let polls: Vec<u8> = seen
        .iter()
        .filter(|s| s.1 == Command::Status)
        .map(|s| s.0)
        .collect();
    assert_eq!(polls, [0, 1, 2, 0, 1, 2]);
    let reads: Vec<u8> = seen
        .iter()
        .filter(|s| s.1 != Command::Status)
        .map(|s| s.0)
        .collect();
    assert_eq!(reads, [0, 1, 2]);
    assert!(engine.axis(axis(2)).position.is_some());
    let online: Vec<_> = events(&mut engine)
        .into_iter()
        .filter(|e| matches!(e, Event::Online(_)))
        .collect();
    assert_eq!(online.len(), 3);
}

#[test]
fn timeout_is_trt_and_retries_then_offline_and_probes_slowly() {
    let mut engine = Engine::new(config(1));
    let mut now = Instant(0);
    let first = next_frame(&mut engine, &mut now);
    let sent_at = now;
    // Trt = 20 + RTIM 3 + 160/115.2 ms after the command's own 16 characters.
    let trt = timing::frame_time(Baud::B115200).plus(timing::response_timeout(
        Baud::B115200,
        Rtim::MIN,
        false,
    ));
    assert_eq!(engine.poll(now), Output::Idle(Some(sent_at + trt)));
    for attempt in 1..=2 {
        let resent = next_frame(&mut engine, &mut now);
        assert_eq!(resent, first, "retry {attempt}");
    }
    let offline_at = now + trt;
    let _ = engine.poll(offline_at);
    assert_eq!(engine.axis(axis(0)).link, Link::Offline);
    let c = engine.axis(axis(0)).counters;
    assert_eq!((c.frames_sent, c.timeouts, c.retries), (3, 3, 2));
    assert!(events(&mut engine).contains(&Event::Offline(axis(0))));
    // Probes back off: the first after FIRST_PROBE, then twice as long each time, up to
    // probe_interval (no retries for a probe).
    now = offline_at;
    let mut probes = vec![];
    for _ in 0..7 {
        let probe = next_frame(&mut engine, &mut now);
        assert_eq!(probe.command, Command::Status);
        probes.push(now);
    }
    let gaps: Vec<u64> = std::iter::once(probes[0].0 - offline_at.0)
        .chain(
            probes
                .windows(2)
                .map(|w| (w[1].0 - w[0].0) - trt.as_micros()),
        )
        .collect();
    assert_eq!(
        gaps,
        [20_000, 40_000, 80_000, 160_000, 320_000, 500_000, 500_000]
    );
}

#[test]
fn relative_move_is_never_resent_and_position_is_reread() {
    let mut engine = Engine::new(config(1));
    let mut now = Instant(0);
    let poll = next_frame(&mut engine, &mut now);
    reply(&mut engine, &mut now, ready(&poll));
    let id = engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::MoveRelative(Pulses(800)),
        })
        .unwrap();
    let m = next_frame(&mut engine, &mut now);
    assert_eq!(m.command, Command::MoveRelative(Pulses(800)));
    // No answer: the next frame is not another `m`.
    let next = next_frame(&mut engine, &mut now);
    assert_ne!(next.command, m.command);
    assert_eq!(engine.axis(axis(0)).counters.retries, 0);
    let done = events(&mut engine).into_iter().find_map(|e| match e {
        Event::JobDone { id: i, result, .. } if i == id => Some(result),
        _ => None,
    });
    assert_eq!(done, Some(Err(JobError::OutcomeUnknown)));
    assert_eq!(
        engine.axis(axis(0)).link,
        Link::Online,
        "one lost answer is not a dead axis"
    );
}

#[test]
fn w4_is_resent_after_its_t4() {
    let mut engine = Engine::new(config(1));
    let mut now = Instant(0);
    let poll = next_frame(&mut engine, &mut now);
    reply(&mut engine, &mut now, ready(&poll));
    let point = PositionNo::new(3).unwrap();
    let id = engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::WriteField {
                point,
                field: PointField::Velocity,
                value: 1000,
            },
        })
        .unwrap();
    let mut address = 0;
    let mut sent = vec![];
    let mut dropped_w4 = false;
    for _ in 0..6 {
        let request = next_frame(&mut engine, &mut now);
        sent.push(request.command.code());
        if matches!(request.command, Command::WriteMemory { .. }) && !dropped_w4 {
            dropped_w4 = true; // lose the first W4's answer
            continue;
        }
        reply(&mut engine, &mut now, answer(&request, &mut address));
    }
    assert_eq!(
        sent,
        [
            Code::Transfer,
            Code::SetWriteAddress,
            Code::WriteMemory,
            Code::SetWriteAddress,
            Code::WriteMemory,
            Code::Store
        ]
    );
    assert!(events(&mut engine).iter().any(|e| matches!(e,
        Event::JobDone { id: i, result: Ok(JobOutput::Value(1)), .. } if *i == id)));
}

#[test]
fn stop_goes_before_another_axis_retry_and_cancels_queued_jobs() {
    let mut engine = Engine::new(config(2));
    let mut now = Instant(0);
    let mut address = 0;
    // Both axes answer their first poll and their position read.
    for _ in 0..4 {
        let request = next_frame(&mut engine, &mut now);
        reply(&mut engine, &mut now, answer(&request, &mut address));
    }
    assert!(engine.axis(axis(0)).position.is_some() && engine.axis(axis(1)).position.is_some());
    // Axis 0's poll times out: a retry is pending when the stop for axis 1 arrives.
    let poll0 = next_frame(&mut engine, &mut now);
    assert_eq!(poll0.axis, axis(0));
    let home = engine
        .submit(Job {
            axis: axis(1),
            kind: JobKind::Home(HomeDirection::MotorEnd),
        })
        .unwrap();
    let _ = engine.poll(now + Duration::from_millis(100));
    now = now + Duration::from_millis(100);
    let stop = engine
        .submit(Job {
            axis: axis(1),
            kind: JobKind::Stop,
        })
        .unwrap();
    let d = next_frame(&mut engine, &mut now);
    assert_eq!((d.axis, d.command), (axis(1), Command::CancelMotion));
    reply(&mut engine, &mut now, ready(&d));
    let retry = next_frame(&mut engine, &mut now);
    assert_eq!((retry.axis, retry.command), (axis(0), Command::Status));
    let evs = events(&mut engine);
    assert!(evs.iter().any(|e| matches!(e,
        Event::JobDone { id, result: Err(JobError::Cancelled), .. } if *id == home)));
    assert!(evs.iter().any(|e| matches!(e,
        Event::JobDone { id, result: Ok(_), .. } if *id == stop)));
}

#[test]
fn full_queue_is_reported_not_dropped() {
    // One axis' share first: a full share refuses, other axes still get room.
    let mut engine = Engine::new(config(16));
    let job = |a: u8| Job {
        axis: axis(a),
        kind: JobKind::Servo(true),
    };
    for _ in 0..WAITING_PER_AXIS {
        engine.submit(job(0)).unwrap();
    }
    assert_eq!(engine.room(axis(0)), 0);
    assert_eq!(engine.submit(job(0)), Err(SubmitError::QueueFull));
    assert_eq!(engine.bus_counters().queue_full, 1);
    // Then the whole queue.
    let mut a = 1;
    while engine.queued() < QUEUE_LEN {
        engine.submit(job(a)).unwrap();
        if engine.room(axis(a)) == 0 {
            a += 1;
        }
    }
    assert_eq!(engine.room(axis(15)), 0);
    assert_eq!(engine.submit(job(15)), Err(SubmitError::QueueFull));
    assert_eq!(engine.bus_counters().queue_full, 2);
    let mut engine = Engine::new(config(1));
    assert_eq!(
        engine.submit(Job {
            axis: axis(5),
            kind: JobKind::Servo(true)
        }),
        Err(SubmitError::AxisDisabled)
    );
}

#[test]
fn wrong_axis_and_bad_bcc_are_never_accepted() {
    let mut engine = Engine::new(config(2));
    let mut now = Instant(0);
    let poll = next_frame(&mut engine, &mut now);
    assert_eq!(poll.axis, axis(0));
    // Axis 1 answers instead of axis 0, then a corrupted answer.
    let wrong = ready(&Request::new(axis(1), Command::Status));
    engine.receive(now, &wrong.emit().to_bytes());
    let mut corrupt = ready(&poll).emit().to_bytes();
    corrupt[5] ^= 0x01;
    engine.receive(now, &corrupt);
    let c = engine.axis(axis(0)).counters;
    assert_eq!((c.replies, c.bad_replies, c.bcc_errors), (0, 1, 1));
    assert_eq!(engine.axis(axis(0)).report, None);
    assert_eq!(engine.axis(axis(1)).report, None);
    // The right answer still completes the transaction.
    reply(&mut engine, &mut now, ready(&poll));
    assert_eq!(engine.axis(axis(0)).counters.replies, 1);
}

#[test]
fn establishment_follows_section_6_1() {
    let mut engine = Engine::new(Config {
        establish: true,
        ..config(2)
    });
    let mut now = Instant(0);
    let mut script = vec![];
    let mut address = 0;
    loop {
        match engine.poll(now) {
            Output::Line(action) => script.push(format!("{action:?}")),
            Output::Transmit(frame) => {
                let request = Request::parse(&frame).unwrap();
                script.push(format!(
                    "{}:{:?}",
                    request.axis.get(),
                    request.command.code()
                ));
                reply(&mut engine, &mut now, answer(&request, &mut address));
                if request.command == Command::Status {
                    break;
                }
            }
            Output::Idle(Some(t)) => now = t,
            Output::Idle(None) => panic!("idle"),
        }
    }
    let per_axis = |a: u8| {
        [
            "SetResponseDelay",
            "SetWriteAddress",
            "WriteMemory",
            "SetWriteAddress",
            "WriteMemory",
        ]
        .map(|c| format!("{a}:{c}"))
    };
    let mut expected = vec![
        "SetBaud(B9600)".to_string(),
        "BreakStart".to_string(),
        "BreakEnd".to_string(),
    ];
    expected.extend(per_axis(0));
    expected.extend(per_axis(1));
    expected.extend(
        [
            "CommChange",
            "CommChange",
            "CommChange",
            "SetBaud(B115200)",
            // Each axis answered during the procedure: its position is read once first.
            "0:ReadMemory",
            "1:ReadMemory",
            "0:Status",
        ]
        .map(String::from),
    );
    assert_eq!(script, expected);
    assert!(events(&mut engine).contains(&Event::Established));
    assert!(!engine.establishing());
}

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
