//! The §5 and §6-1 rules: round-robin polling with the host gap, time-outs, retries and
//! offline probes, resends, stops, a full queue, rejected replies, establishment.

use protocol::engine::*;
use protocol::line::Baud;
use protocol::memory::PointField;
use protocol::time::{Duration, Instant};
use protocol::*;

use crate::{answer, answer_delay, axis, config, events, next_frame, ready, reply};

/// One axis online (its first poll answered), `kind` submitted: the engine, the time and the
/// job.
fn online_with_job(kind: JobKind) -> (Engine, Instant, JobId) {
    let mut engine = Engine::new(config(1));
    let mut now = Instant(0);
    let poll = next_frame(&mut engine, &mut now);
    reply(&mut engine, &mut now, ready(&poll));
    let id = engine
        .submit(Job {
            axis: axis(0),
            kind,
        })
        .unwrap();
    (engine, now, id)
}

/// The result of job `id`, if an event since the last call reported it.
fn result_of(engine: &mut Engine, id: JobId) -> Option<Result<JobOutput, JobError>> {
    events(engine).into_iter().find_map(|e| match e {
        Event::JobDone { id: i, result, .. } if i == id => Some(result),
        _ => None,
    })
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

/// `reply_slack` lengthens every response time-out by itself, and only that: an answer late by
/// less than the slack is taken, the same answer without the slack comes after the time-out.
#[test]
fn reply_slack_extends_the_response_timeout() {
    let slack = Duration::from_millis(200);
    let trt = timing::frame_time(Baud::B115200).plus(timing::response_timeout(
        Baud::B115200,
        Rtim::MIN,
        false,
    ));
    for (with_slack, answered) in [(false, false), (true, true)] {
        let mut engine = Engine::new(Config {
            reply_slack: if with_slack {
                slack
            } else {
                Duration::from_millis(0)
            },
            ..config(1)
        });
        let mut now = Instant(0);
        let poll = next_frame(&mut engine, &mut now);
        let timeout = if with_slack { trt.plus(slack) } else { trt };
        assert_eq!(engine.poll(now), Output::Idle(Some(now + timeout)));
        // The answer arrives 100 ms after the plain time-out.
        now = now + trt.plus(Duration::from_millis(100));
        let _ = engine.poll(now);
        engine.receive(now, &ready(&poll).emit().to_bytes());
        let c = engine.axis(axis(0)).counters;
        assert_eq!(c.timeouts == 0, answered, "slack {with_slack}: {c:?}");
    }
}

#[test]
fn relative_move_is_never_resent_and_position_is_reread() {
    let (mut engine, mut now, id) = online_with_job(JobKind::MoveRelative(Pulses(800)));
    let m = next_frame(&mut engine, &mut now);
    assert_eq!(m.command, Command::MoveRelative(Pulses(800)));
    // No answer: the next frame is not another `m` but the job's read of where the axis is,
    // and the failure is reported only once that is known (PNOW fresh when CMST shows it).
    let next = next_frame(&mut engine, &mut now);
    assert_eq!(
        next.command,
        Command::ReadMemory {
            address: protocol::memory::PNOW
        }
    );
    assert_eq!(engine.axis(axis(0)).counters.retries, 0);
    assert_eq!(
        result_of(&mut engine, id),
        None,
        "not before the position is read"
    );
    let moved = Reply::Memory {
        axis: axis(0),
        code: MemoryCode::ReadMemory,
        value: 500,
    };
    reply(&mut engine, &mut now, moved);
    assert_eq!(engine.axis(axis(0)).position, Some(Pulses(500)));
    assert_eq!(
        result_of(&mut engine, id),
        Some(Err(JobError::OutcomeUnknown))
    );
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
    // The job's frames; polls may go between them (JOB_RUN), answered and left out.
    while sent.len() < 6 {
        let request = next_frame(&mut engine, &mut now);
        if !matches!(
            request.command,
            Command::Status | Command::ReadMemory { .. }
        ) {
            sent.push(request.command.code());
        }
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
    // Both axes answer their first polls and their position reads.
    let known =
        |e: &Engine| e.axis(axis(0)).position.is_some() && e.axis(axis(1)).position.is_some();
    for _ in 0..6 {
        if known(&engine) {
            break;
        }
        let request = next_frame(&mut engine, &mut now);
        reply(&mut engine, &mut now, answer(&request, &mut address));
    }
    assert!(known(&engine));
    // Axis 0's next poll times out: a retry is pending when the stop for axis 1 arrives.
    for _ in 0..4 {
        let request = next_frame(&mut engine, &mut now);
        if request == Request::new(axis(0), Command::Status) {
            break;
        }
        reply(&mut engine, &mut now, answer(&request, &mut address));
    }
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

/// A receiver may leave the rest of a started frame in its UART buffer until `frame_due`: then
/// the frame is complete and taken in one go, as if byte by byte.
#[test]
fn the_rest_of_a_started_answer_is_due_at_the_line_rate() {
    let mut engine = Engine::new(config(1));
    let mut now = Instant(0);
    let request = next_frame(&mut engine, &mut now);
    assert_eq!(
        engine.frame_due(),
        None,
        "nothing started: read the first byte at once"
    );
    let bytes = ready(&request).emit().to_bytes();
    now = now + answer_delay(&engine, request.axis);
    let char_time = timing::char_time(engine.line_baud());
    engine.receive(now, &bytes[..3]);
    let due = engine.frame_due().expect("a frame has started");
    assert_eq!(due, now + Duration(char_time.0 * 13));
    // Taken at that moment, the rest completes the answer.
    assert!(engine.receive(due, &bytes[3..]), "the answer completes");
    assert_eq!(engine.frame_due(), None);
    assert!(engine.axis(axis(0)).report.is_some());
}

/// A move that begins and ends between two status reports (the first status after its command
/// already shows it in position) counts as stopped too: its position is read again until two
/// reads agree, as after any other stop. The controller here reads one pulse short at first,
/// then where it rests.
#[test]
fn a_move_seen_only_in_position_is_read_again_until_it_rests() {
    let mut engine = Engine::new(config(1));
    let mut now = Instant(0);
    let mut address = 0;
    let mut pnow = 0i32;
    let mut reads_after_done = Vec::new();
    let mut done = false;
    let mut submitted = false;
    while now < Instant(2_000_000) {
        let request = next_frame(&mut engine, &mut now);
        let answer = match request.command {
            Command::ReadMemory { address } if address == memory::PNOW => {
                let value = pnow;
                // The job's read finds it one pulse short; it rests at -4 from then on.
                if submitted {
                    pnow = -4;
                }
                if done {
                    reads_after_done.push((now, value));
                }
                Reply::Memory {
                    axis: request.axis,
                    code: MemoryCode::ReadMemory,
                    value: value as u32,
                }
            }
            Command::MoveAbsolute(_) => {
                pnow = -3;
                ready(&request)
            }
            _ => answer(&request, &mut address),
        };
        reply(&mut engine, &mut now, answer);
        for event in events(&mut engine) {
            if let Event::JobDone { result, .. } = event {
                assert_eq!(result, Ok(JobOutput::Value(-3i32 as u32)));
                done = true;
            }
        }
        if !submitted && engine.axis(axis(0)).position.is_some() {
            engine
                .submit(Job {
                    axis: axis(0),
                    // It rests a pulse short of its target, in its band: a read at the
                    // target would end the reads at once (it rests there).
                    kind: JobKind::MoveAbsolute(Pulses(-5)),
                })
                .unwrap();
            submitted = true;
        }
    }
    assert!(done);
    assert_eq!(engine.axis(axis(0)).position, Some(Pulses(-4)));
    // Read until two agree: -4 (differs from -3), -4 (agrees); each 20 ms or more after the last.
    let values: Vec<i32> = reads_after_done.iter().map(|r| r.1).collect();
    assert_eq!(values, [-4, -4]);
    assert!(reads_after_done[1].0 .0 - reads_after_done[0].0 .0 >= 20_000);
}

/// A move that ends in an alarm reads where the axis stopped before the failure is reported;
/// when that read goes unanswered the failure reported is still the alarm, not the time-out.
#[test]
fn a_move_that_fails_reads_its_position_first_and_reports_the_first_failure() {
    let point = PositionNo::new(2).unwrap();
    let (mut engine, mut now, id) = online_with_job(JobKind::MoveToPoint(point, None));
    let q3 = next_frame(&mut engine, &mut now);
    assert!(matches!(q3.command, Command::MoveToPoint(_)));
    // Taken and moving (no PFIN); the status poll during the wait shows an error alarm.
    let mut moving = ready(&q3);
    if let Reply::Status { report, .. } = &mut moving {
        report.outputs = Outputs::ALM_N;
    }
    reply(&mut engine, &mut now, moving);
    let read_pnow = Command::ReadMemory {
        address: protocol::memory::PNOW,
    };
    let mut alarm_sent = false;
    loop {
        let frame = next_frame(&mut engine, &mut now);
        match frame.command {
            // The schedule's reads during the move are answered; after the alarm, the read is
            // the job's.
            c if c == read_pnow && alarm_sent => break,
            c if c == read_pnow => {
                let at = Reply::Memory {
                    axis: axis(0),
                    code: MemoryCode::ReadMemory,
                    value: 100,
                };
                reply(&mut engine, &mut now, at);
            }
            _ => {
                let mut status = ready(&frame);
                if let Reply::Status { report, .. } = &mut status {
                    report.alarm = AlarmCode(0xC8);
                    report.outputs = Outputs::NONE;
                }
                reply(&mut engine, &mut now, status);
                alarm_sent = true;
            }
        }
    }
    assert_eq!(
        result_of(&mut engine, id),
        None,
        "not before the position is read"
    );
    // The read is never answered: resent, then the axis is offline.
    let mut result = None;
    for _ in 0..10 {
        if let Some(r) = result_of(&mut engine, id) {
            result = Some(r);
            break;
        }
        let _ = next_frame(&mut engine, &mut now);
    }
    assert_eq!(result, Some(Err(JobError::Alarm(AlarmCode(0xC8)))));
}

/// §5: a frame whose answer was lost is sent again with nothing else to its axis between its
/// attempts, also when job frames have had their run (`JOB_RUN`) and polling would have a turn:
/// two axes' point writes back to back, every seventh frame's answer lost.
#[test]
fn a_lost_job_frame_s_attempts_have_nothing_else_to_its_axis_between_them() {
    let mut engine = Engine::new(config(2));
    let mut now = Instant(0);
    for _ in 0..2 {
        let poll = next_frame(&mut engine, &mut now);
        reply(&mut engine, &mut now, ready(&poll));
    }
    let mut address = 0;
    let mut owed: [Option<Command>; 2] = [None, None];
    let mut lost = 0;
    let mut jobs = 0;
    for i in 0..400 {
        for a in 0..2 {
            if engine.room(axis(a)) > 0 && jobs < 40 {
                let point = PositionNo::new(1 + (jobs % 9) as u8).unwrap();
                let field = [PointField::Velocity, PointField::Position][jobs % 2];
                let job = Job {
                    axis: axis(a),
                    kind: JobKind::WriteField {
                        point,
                        field,
                        value: 100 + jobs as u32,
                    },
                };
                if engine.submit(job).is_ok() {
                    jobs += 1;
                }
            }
        }
        let request = next_frame(&mut engine, &mut now);
        let a = usize::from(request.axis.get());
        // The resend (a W4's with its T4 first), not a poll of the axis.
        let poll = match request.command {
            Command::Status => true,
            Command::ReadMemory { address } => address == protocol::memory::PNOW,
            _ => false,
        };
        if let Some(lost) = owed[a].take() {
            assert!(
                !poll,
                "frame {i}: axis {a} polled between the attempts of {lost:?}"
            );
        }
        if i % 7 == 3 && !matches!(request.command, Command::Status | Command::CancelMotion) {
            owed[a] = Some(request.command);
            lost += 1;
            continue; // its answer lost: the next frame to this axis is its resend
        }
        reply(&mut engine, &mut now, answer(&request, &mut address));
    }
    assert!(
        jobs >= 10 && lost >= 20,
        "only {jobs} jobs, {lost} lost answers"
    );
}

/// A job frame's answer carries the axis' status as a poll's does (complete edition §3-1-2): the
/// axis is not polled again for it, its turn goes to the axes polled longer ago.
#[test]
fn a_job_frame_s_answer_counts_as_its_axis_status_poll() {
    let mut engine = Engine::new(config(3));
    let mut now = Instant(0);
    let mut address = 0;
    let mut exchange = |engine: &mut Engine, now: &mut Instant| {
        let request = next_frame(engine, now);
        reply(engine, now, answer(&request, &mut address));
        (request.axis.get(), request.command)
    };
    // Every axis online, its position read: round robin from here.
    while engine.axis(axis(2)).position.is_none() {
        exchange(&mut engine, &mut now);
    }
    while exchange(&mut engine, &mut now) != (2, Command::Status) {}
    // Axis 0 was polled longest ago; a job of its own answers for it.
    engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::Command(Command::Servo(true)),
        })
        .unwrap();
    assert_eq!(
        exchange(&mut engine, &mut now),
        (0, Command::Servo(true)),
        "the job frame"
    );
    let polls: Vec<_> = (0..3).map(|_| exchange(&mut engine, &mut now)).collect();
    assert_eq!(
        polls,
        [
            (1, Command::Status),
            (2, Command::Status),
            (0, Command::Status)
        ]
    );
}
