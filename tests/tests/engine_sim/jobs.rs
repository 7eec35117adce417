//! Jobs end to end: homing, moves, point writes with verify, rejections, stops, the
//! synchronized start, jog, servo and velocity, alarms and single-field writes.

use protocol::engine::point_jobs::PointData;
use protocol::engine::*;
use protocol::line::Baud;
use protocol::units::{Accel, Length, Scale, Speed};
use protocol::*;

use crate::{axis, established, homed, run_job, MS, S};

#[test]
fn home_then_absolute_move_then_point_write_with_verify() {
    let mut h = established(2);
    let home = run_job(
        &mut h,
        Job {
            axis: axis(1),
            kind: JobKind::Home(HomeDirection::MotorEnd),
        },
        10 * S,
    );
    assert!(home.is_ok(), "{home:?}");
    assert!(h.bus.controller(axis(1)).unwrap().homed());

    let scale = Scale::new(
        units::Lead::from_hundredths(1200).unwrap(),
        HomeDirection::MotorEnd,
    );
    let target = scale.position_to_wire(Length(25_00)).unwrap();
    let moved = run_job(
        &mut h,
        Job {
            axis: axis(1),
            kind: JobKind::MoveAbsolute(target),
        },
        10 * S,
    );
    assert!(moved.is_ok(), "{moved:?}");
    let c = h.bus.controller(axis(1)).unwrap();
    assert!(!c.moving());
    assert_eq!(c.position(), i64::from(target.0));

    let data = PointData {
        position: target,
        velocity: scale.velocity(Speed(50_00)).unwrap(),
        acceleration: scale.acceleration(Accel(30)).unwrap(),
        flags: PointData::FLAGS_MOTION_AND_BAND,
        band: scale.band_to_wire(Length(10)).unwrap(),
        max_acceleration: 0,
    };
    let point = PositionNo::new(7).unwrap();
    let written = run_job(
        &mut h,
        Job {
            axis: axis(1),
            kind: JobKind::WritePoint {
                point,
                data,
                verify: true,
            },
        },
        10 * S,
    );
    match written {
        Ok(JobOutput::Point(readback)) => assert!(readback.matches(&data)),
        other => panic!("{other:?}"),
    }
    // Move away, then to the point: Q3 7 brings it back to 25 mm.
    run_job(
        &mut h,
        Job {
            axis: axis(1),
            kind: JobKind::MoveAbsolute(Pulses(0)),
        },
        10 * S,
    )
    .unwrap();
    run_job(
        &mut h,
        Job {
            axis: axis(1),
            kind: JobKind::MoveToPoint(point, None),
        },
        10 * S,
    )
    .unwrap();
    assert_eq!(
        h.bus.controller(axis(1)).unwrap().position(),
        i64::from(target.0)
    );
}

#[test]
fn rejected_move_before_homing_reports_the_warning() {
    let mut h = established(1);
    let result = run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::MoveAbsolute(Pulses(-800)),
        },
        2 * S,
    );
    assert_eq!(result, Err(JobError::Rejected(AlarmCode(0x71))));
    let state = h.engine.axis(axis(0));
    assert_eq!(state.counters.rejections, 1);
    assert_eq!(
        state.last_error,
        Some(protocol::engine::LinkError::Rejected(AlarmCode(0x71)))
    );
}

#[test]
fn stop_cancels_a_move_in_progress() {
    let mut h = established(1);
    run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::Home(HomeDirection::MotorEnd),
        },
        10 * S,
    )
    .unwrap();
    let id = h
        .engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::MoveAbsolute(Pulses(-40_000)),
        })
        .unwrap();
    h.run_until(h.now + 300 * MS);
    assert!(h.bus.controller(axis(0)).unwrap().moving());
    let stop = run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::Stop,
        },
        S,
    );
    assert!(stop.is_ok(), "{stop:?}");
    assert!(h.events.iter().any(|(_, e)| matches!(e,
        Event::JobDone { id: i, result: Err(JobError::Cancelled), .. } if *i == id)));
    h.run_until(h.now + 500 * MS);
    let c = h.bus.controller(axis(0)).unwrap();
    assert!(!c.moving());
    assert!(c.position() > -40_000, "stopped short of the target");
}

#[test]
fn synchronized_start_moves_two_axes_at_the_same_instant() {
    let mut h = established(3);
    for a in [0, 2] {
        run_job(
            &mut h,
            Job {
                axis: axis(a),
                kind: JobKind::Home(HomeDirection::MotorEnd),
            },
            10 * S,
        )
        .unwrap();
    }
    for (a, target) in [(0, -8_000), (2, -12_000)] {
        let buffered = Buffered::new(&Command::MoveAbsolute(Pulses(target))).unwrap();
        let r = run_job(
            &mut h,
            Job {
                axis: axis(a),
                kind: JobKind::Command(Command::Buffer(buffered)),
            },
            S,
        );
        assert!(r.is_ok(), "{r:?}");
        assert!(h.bus.controller(axis(a)).unwrap().buffered().is_some());
    }
    let set = AxisSet::default().with(axis(0)).with(axis(2));
    let started = run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::StartBuffered(set),
        },
        5 * S,
    );
    assert!(started.is_ok(), "{started:?}");
    let (c0, c2) = (
        h.bus.controller(axis(0)).unwrap(),
        h.bus.controller(axis(2)).unwrap(),
    );
    assert!(c0.buffered().is_none() && c2.buffered().is_none());
    assert!(c0.last_move_start().is_some_and(|t| t > 0));
    assert_eq!(
        c0.last_move_start(),
        c2.last_move_start(),
        "one t starts both"
    );
    // Exactly one `t` went out.
    let ts = h
        .sent
        .iter()
        .filter(|(_, r)| r.command == Command::ExecuteBuffered)
        .count();
    assert_eq!(ts, 1);
}

#[test]
fn jog_runs_toward_the_stroke_end_until_stopped() {
    let mut h = homed(1);
    let end = Pulses(-1_000_000); // beyond the stroke: the controller clamps to its limit
    let jog = run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::Jog {
                end,
                velocity: Velocity::new(2000).unwrap(),
                acceleration: Acceleration::new(30).unwrap(),
            },
        },
        S,
    );
    assert!(jog.is_ok(), "a jog is done once accepted: {jog:?}");
    h.run_until(h.now + 400 * MS);
    let moving_at = h.bus.controller(axis(0)).unwrap().position();
    assert!(h.bus.controller(axis(0)).unwrap().moving());
    run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::Stop,
        },
        S,
    )
    .unwrap();
    h.run_until(h.now + 500 * MS);
    let c = h.bus.controller(axis(0)).unwrap();
    assert!(!c.moving());
    assert!(c.position() < moving_at, "it kept jogging until the stop");
    // The engine read the position of the moving axis along the way, and once more when the
    // stop was seen complete. `d` overshoots and settles back (§4-4-9), and the controller says
    // PEND once in band, so that read is within the in-position band of where it settles.
    assert!(h.engine.axis(axis(0)).position_at.is_some());
    let read = h
        .engine
        .axis(axis(0))
        .position
        .map(|p| i64::from(p.0))
        .unwrap();
    let band = i64::from(c.memory().exec_field(protocol::memory::PointField::Band));
    assert!(
        (read - c.position()).abs() <= band,
        "read {read}, settled at {}, band {band}",
        c.position()
    );
}

#[test]
fn servo_off_on_and_velocity_setting() {
    let mut h = homed(1);
    run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::Servo(false),
        },
        S,
    )
    .unwrap();
    assert!(!h.bus.controller(axis(0)).unwrap().servo());
    assert!(!h.engine.axis(axis(0)).report.unwrap().status.servo());
    let refused = run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::MoveAbsolute(Pulses(-800)),
        },
        S,
    );
    assert_eq!(refused, Err(JobError::Rejected(AlarmCode(0x70))), "RUN off");
    run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::Servo(true),
        },
        S,
    )
    .unwrap();
    let velocity = Velocity::new(1000).unwrap();
    let acceleration = Acceleration::new(50).unwrap();
    run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::SetMotion {
                velocity,
                acceleration,
            },
        },
        S,
    )
    .unwrap();
    let read = run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::Command(Command::ReadMemory {
                address: Address(0x7C04),
            }),
        },
        S,
    );
    assert_eq!(
        read,
        Ok(JobOutput::Value(1000)),
        "VCMD of the execution area"
    );
}

#[test]
fn an_alarm_fails_the_waiting_move_and_alarm_reset_clears_it() {
    let mut h = homed(1);
    let id = h
        .engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::MoveAbsolute(Pulses(-60_000)),
        })
        .unwrap();
    h.run_until(h.now + 200 * MS);
    h.bus.inject_alarm(axis(0), AlarmCode(0xD8)).unwrap();
    let done = h.run_until_event(
        2 * S,
        |e| matches!(e, Event::JobDone { id: i, .. } if *i == id),
    );
    assert!(
        matches!(
            done,
            Some((
                _,
                Event::JobDone {
                    result: Err(JobError::Alarm(AlarmCode(0xD8))),
                    ..
                }
            ))
        ),
        "{done:?}"
    );
    let report = h.engine.axis(axis(0)).report.unwrap();
    assert!(report.outputs.alarm_active());
    assert_eq!(report.outputs.abbreviated_alarm(), Some(0x0B));
    let reset = run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::AlarmReset,
        },
        S,
    );
    assert!(reset.is_ok(), "{reset:?}");
    h.run_until(h.now + 100 * MS);
    assert_eq!(h.bus.controller(axis(0)).unwrap().alarm(), AlarmCode::NONE);
    assert!(!h
        .engine
        .axis(axis(0))
        .report
        .unwrap()
        .outputs
        .alarm_active());
}

#[test]
fn single_field_write_and_read_back() {
    let mut h = established(1);
    let point = PositionNo::new(2).unwrap();
    let field = protocol::memory::PointField::Velocity;
    let v5 = run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::WriteField {
                point,
                field,
                value: 2222,
            },
        },
        2 * S,
    );
    assert!(
        matches!(v5, Ok(JobOutput::Value(count)) if count >= 1),
        "{v5:?}"
    );
    match run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::ReadPoint(point),
        },
        2 * S,
    ) {
        Ok(JobOutput::Point(readback)) => assert_eq!(readback.get(field), 2222),
        other => panic!("{other:?}"),
    }
}

/// Adaptive polling (engine `schedule`, `approach`): four movers among 16 axes are each seen
/// in position within a few transactions of the moment they are (instead of up to a whole cycle
/// later: polled in turn, four movers are each seen every four transactions at best, behind
/// their own position reads and the others' commands), their arrivals are estimated from their
/// targets, acceleration times and a position read before they get there, and the idle axes'
/// status age stays within two cycles meanwhile. Moves as the PLC gives them: `v` then `a`, at
/// the velocity and acceleration the controllers start with.
#[test]
fn moves_are_seen_complete_soon_after_they_are_in_band_and_idle_axes_keep_their_bound() {
    let mut h = established(16);
    let movers = [axis(2), axis(6), axis(10), axis(14)];
    for mover in movers {
        let r = run_job(
            &mut h,
            Job {
                axis: mover,
                kind: JobKind::Home(HomeDirection::MotorEnd),
            },
            30 * S,
        );
        assert!(r.is_ok(), "{r:?}");
    }
    let controller = h.bus.controller(movers[0]).unwrap();
    let (velocity, acceleration) = controller.memory().exec_motion().unwrap();
    let transaction = timing::transaction_time(Baud::B115200, Rtim::MIN).as_micros();
    let cycle = 16 * transaction;
    let from = h.now;
    for round in 0..4 {
        // Over 90, 75, 60 and 45 % of the stroke and back: they end at different moments, now
        // and then close together.
        let stroke = h
            .bus
            .controller(movers[0])
            .unwrap()
            .config()
            .actuator
            .stroke as i32;
        let near = -stroke / 20;
        let targets = [90, 75, 60, 45].map(|percent| {
            if round % 2 == 0 {
                near - stroke / 100 * percent
            } else {
                near
            }
        });
        let mut watch = Vec::new();
        for (mover, to) in movers.into_iter().zip(targets) {
            let before = h.bus.controller(mover).unwrap().last_move_start();
            h.engine
                .submit(Job {
                    axis: mover,
                    kind: JobKind::DirectMove {
                        target: Pulses(to),
                        relative: false,
                        velocity,
                        acceleration,
                    },
                })
                .unwrap();
            // (estimated, in band at, seen at)
            watch.push((mover, before, false, None::<u64>, None::<u64>));
        }
        while watch.iter().any(|w| w.4.is_none()) {
            h.run_until(h.now + MS);
            assert!(
                h.now < from + 120 * S,
                "round {round}: moves never seen complete"
            );
            for (mover, before, estimated, in_band, seen) in &mut watch {
                let c = h.bus.controller(*mover).unwrap();
                let start = c.last_move_start();
                let Some(start) = start.filter(|_| start != *before) else {
                    continue;
                };
                *in_band = c.profile().map(|p| p.in_band_at()).or(*in_band);
                *estimated |= h.engine.expected_arrival(*mover).is_some();
                let state = h.engine.axis(*mover);
                let pfin = state
                    .report
                    .is_some_and(|r| r.outputs.contains(status::Outputs::PFIN));
                if seen.is_none() && pfin && state.report_at.is_some_and(|at| at.0 > start) {
                    *seen = state.report_at.map(|at| at.0);
                }
            }
        }
        for (mover, _, estimated, in_band, seen) in watch {
            let (in_band, seen) = (in_band.unwrap(), seen.unwrap());
            assert!(
                estimated,
                "round {round}, {mover:?}: the arrival was estimated before it"
            );
            let late = (seen as f64 - in_band as f64) / transaction as f64;
            assert!(
                seen >= in_band && seen - in_band <= 3 * transaction,
                "round {round}, {mover:?}: in band at {in_band} us, seen at {seen} us ({late:.1} T)"
            );
        }
        // Every move job done before the next round.
        h.run_until(h.now + 100 * MS);
    }
    for a in (0..16).map(axis).filter(|a| !movers.contains(a)) {
        let polls: Vec<u64> = h
            .sent
            .iter()
            .filter(|(t, r)| *t >= from && r.axis == a && r.command == Command::Status)
            .map(|(t, _)| *t)
            .collect();
        let gap = polls.windows(2).map(|w| w[1] - w[0]).max().unwrap();
        assert!(
            gap <= 2 * cycle + 2 * transaction,
            "idle axis {a:?}: status {gap} us apart (> 2 cycles)"
        );
    }
}

/// A home job is done with its position read after ZFIN: a PLC that reads PNOW when the home
/// command's status says done gets 0, not where the axis was before or during homing (the job
/// once ended on the status that showed ZFIN, before any read of the new position).
#[test]
fn a_home_job_ends_with_the_homed_position_read() {
    // The first round from where the controller powered up, the second from away from home.
    let mut h = established(1);
    let a = axis(0);
    for _ in 0..2 {
        let home = run_job(
            &mut h,
            Job {
                axis: a,
                kind: JobKind::Home(HomeDirection::MotorEnd),
            },
            20 * S,
        );
        assert!(home.is_ok(), "{home:?}");
        let state = h.engine.axis(a);
        assert_eq!(state.position, Some(Pulses(0)), "PNOW when the job is done");
        let homed_at = state.report_at.expect("a status showed ZFIN");
        assert!(
            state.position_at.is_some_and(|at| at >= homed_at),
            "read after the status that showed the axis homed"
        );
        run_job(
            &mut h,
            Job {
                axis: a,
                kind: JobKind::MoveAbsolute(Pulses(-1_000)),
            },
            10 * S,
        )
        .unwrap();
    }
}

/// A move is done when the axis enters its position band (PFIN), and the job's position read
/// comes then, while the axis still travels the rest of the band. The engine reads the stopped
/// axis again until two reads agree, so that the position it keeps (PNOW for the PLC) is where
/// the axis rests, not where it was seen in position.
#[test]
fn a_stopped_axis_position_is_read_again_until_it_rests() {
    let mut h = homed(1);
    let a = axis(0);
    let stroke = h.bus.controller(a).unwrap().config().actuator.stroke as i32;
    let target = Pulses(-stroke / 2);
    // A gentle deceleration: the rest of the band takes tens of ms.
    run_job(
        &mut h,
        Job {
            axis: a,
            kind: JobKind::DirectMove {
                target,
                relative: false,
                velocity: Velocity::new(2_000).unwrap(),
                acceleration: Acceleration::new(5).unwrap(),
            },
        },
        10 * S,
    )
    .unwrap();
    let at_done = h.engine.axis(a).position.expect("the job read it");
    assert_ne!(
        at_done, target,
        "the case this test is about: the read that ended the job is short of the target"
    );
    h.run_until(h.now + 500 * MS);
    assert_eq!(h.bus.controller(a).unwrap().position(), i64::from(target.0));
    assert_eq!(
        h.engine.axis(a).position,
        Some(target),
        "read once it rests"
    );
}

/// A short buffered move, started by a `t` and over before a status poll of its axis shows it
/// moving (the answers in between lost), still has its position read: each axis a `t` starts counts as moving until a status
/// says otherwise (the firmware soak found PNOW left where the axis stood before the move).
#[test]
fn a_synchronized_start_reads_where_its_axes_came_to_rest() {
    let mut h = established(2);
    for a in 0..2 {
        let home = Job {
            axis: axis(a),
            kind: JobKind::Home(HomeDirection::MotorEnd),
        };
        run_job(&mut h, home, 10 * S).unwrap();
    }
    // Axis 1 a few pulses only: its move is over within a millisecond or two.
    for (a, target) in [(0, -8_000), (1, -20)] {
        let buffered = Buffered::new(&Command::MoveAbsolute(Pulses(target))).unwrap();
        let job = Job {
            axis: axis(a),
            kind: JobKind::Command(Command::Buffer(buffered)),
        };
        run_job(&mut h, job, S).unwrap();
    }
    h.run_until(h.now + 200 * MS);
    let set = AxisSet::default().with(axis(0)).with(axis(1));
    let start = Job {
        axis: axis(0),
        kind: JobKind::StartBuffered(set),
    };
    h.engine.submit(start).unwrap();
    // Axis 1's answers lost while its move runs (as a noisy bus does): the next status it
    // answers shows it standing.
    let until = h.now + S;
    while h.now < until
        && !h
            .sent
            .iter()
            .any(|(_, r)| r.command == Command::ExecuteBuffered)
    {
        h.step(until);
    }
    h.bus.set_silent(axis(1), true);
    h.run_until(h.now + 30 * MS);
    h.bus.set_silent(axis(1), false);
    h.run_until(h.now + 2 * S);
    let c = h.bus.controller(axis(1)).unwrap();
    assert_eq!(c.position(), -20, "axis 1 moved");
    assert_eq!(
        h.engine.axis(axis(1)).position,
        Some(Pulses(-20)),
        "its position read after the move"
    );
}

/// An `m` whose answer is lost may have moved the axis (§5 (2)): the job fails with the outcome
/// unknown after reading the position, and that read can come while the axis still moves. A
/// short move then ends before the axis' next status poll (it is idle to the schedule, polled
/// every cycle or so), so no status ever shows it moving, and the read mid-move stayed PNOW for
/// good (the firmware soak in CI: an axis at rest 10.58 mm from its PNOW). The lost answer now
/// counts as a move commanded: the next status that shows the axis standing has it read again
/// until it rests.
#[test]
fn a_relative_move_whose_answer_is_lost_reads_where_the_axis_came_to_rest() {
    let mut h = established(16);
    let a = axis(0);
    run_job(
        &mut h,
        Job {
            axis: a,
            kind: JobKind::Home(HomeDirection::MotorEnd),
        },
        10 * S,
    )
    .unwrap();
    h.run_until(h.now + 300 * MS);
    let from = h.bus.controller(a).unwrap().position();
    let id = h
        .engine
        .submit(Job {
            axis: a,
            kind: JobKind::DirectMove {
                target: Pulses(-250),
                relative: true,
                velocity: Velocity::new(10_000).unwrap(),
                acceleration: Acceleration::new(100).unwrap(),
            },
        })
        .unwrap();
    until_sent(&mut h, |r| matches!(r.command, Command::MoveRelative(_)));
    // The `m`'s answer lost; the axis answers again from the next frame on (the job's read).
    h.bus.set_silent(a, true);
    until_next_frame(&mut h);
    h.bus.set_silent(a, false);
    let result = h.run_until_event(
        h.now + S,
        |e| matches!(e, Event::JobDone { id: i, .. } if *i == id),
    );
    assert!(
        matches!(
            result,
            Some((
                _,
                Event::JobDone {
                    result: Err(JobError::OutcomeUnknown),
                    ..
                }
            ))
        ),
        "{result:?}"
    );
    let read = h.engine.axis(a).position.expect("the job read it").0;
    let c = h.bus.controller(a).unwrap();
    assert!(
        c.moving() && i64::from(read) != from,
        "the case this test is about: the job's read came while the axis moved ({read}, from {from})"
    );
    // Its status polls lost until the move is over (a noisy bus), fewer of them than take it
    // offline: the first status it answers shows it standing.
    h.bus.set_silent(a, true);
    let until = h.now + S;
    while h.now < until && h.bus.controller(a).unwrap().moving() {
        h.step(until);
    }
    h.bus.set_silent(a, false);
    h.run_until(h.now + 2 * S);
    assert!(
        !h.events.iter().any(|(_, e)| *e == Event::Offline(a)),
        "the case this test is about: the axis stayed online (going online reads the position)"
    );
    let rest = h.bus.controller(a).unwrap().position();
    assert_eq!(rest, from - 250, "the axis moved");
    assert_eq!(
        h.engine.axis(a).position,
        Some(Pulses(rest as i32)),
        "read again once it rests"
    );
}

/// A stop asked for while a move is on the wire cancels the move's job, and the move is not
/// resent when its answer is lost (the stop goes next). The axis took it all the same: a short
/// move is over when the stop's answer comes, which shows the axis standing. The lost answer
/// counts as a move commanded, so that this status has the position read where the axis came
/// to rest.
#[test]
fn a_move_whose_answer_is_lost_as_a_stop_cancels_it_reads_where_the_axis_came_to_rest() {
    let mut h = homed(1);
    let a = axis(0);
    h.run_until(h.now + 300 * MS);
    let from = h.bus.controller(a).unwrap().position();
    let target = Pulses(from as i32 - 30);
    h.engine
        .submit(Job {
            axis: a,
            kind: JobKind::MoveAbsolute(target),
        })
        .unwrap();
    until_sent(&mut h, |r| matches!(r.command, Command::MoveAbsolute(_)));
    h.bus.set_silent(a, true);
    h.engine
        .submit(Job {
            axis: a,
            kind: JobKind::Stop,
        })
        .unwrap();
    until_next_frame(&mut h);
    assert_eq!(h.sent.last().unwrap().1.command, Command::CancelMotion);
    h.bus.set_silent(a, false);
    assert!(
        !h.bus.controller(a).unwrap().moving(),
        "the case this test is about: the move is over when the stop goes"
    );
    h.run_until(h.now + 2 * S);
    let rest = h.bus.controller(a).unwrap().position();
    assert_eq!(rest, i64::from(target.0), "the axis moved");
    assert_eq!(
        h.engine.axis(a).position,
        Some(Pulses(rest as i32)),
        "read where it rests"
    );
}

/// Two homed axes with a move buffered on each: axis 0 a long one, axis 1 a few pulses (over
/// within a millisecond or two of the `t`, before any status poll of it can show it moving).
fn two_axes_with_moves_buffered() -> rc_host::harness::Harness {
    let mut h = homed(2);
    for (a, target) in [(0, -8_000), (1, -20)] {
        let buffered = Buffered::new(&Command::MoveAbsolute(Pulses(target))).unwrap();
        let job = Job {
            axis: axis(a),
            kind: JobKind::Command(Command::Buffer(buffered)),
        };
        run_job(&mut h, job, S).unwrap();
    }
    h.run_until(h.now + 200 * MS);
    assert_eq!(h.engine.axis(axis(1)).position, Some(Pulses(0)));
    h
}

/// Step until a frame matching `is` has gone out (at most a second).
fn until_sent(h: &mut rc_host::harness::Harness, is: impl Fn(&Request) -> bool) {
    let until = h.now + S;
    while h.now < until && !h.sent.iter().any(|(_, r)| is(r)) {
        h.step(until);
    }
    assert!(h.sent.iter().any(|(_, r)| is(r)), "the frame went out");
}

/// Step until the engine has sent one more frame (at most a second).
fn until_next_frame(h: &mut rc_host::harness::Harness) {
    let (sent, until) = (h.sent.len(), h.now + S);
    while h.now < until && h.sent.len() == sent {
        h.step(until);
    }
    assert!(h.sent.len() > sent, "a frame went out");
}

/// The other axis of a synchronized start came to rest where the engine keeps its position.
fn assert_axis_1_read_at_rest(h: &mut rc_host::harness::Harness) {
    h.run_until(h.now + 2 * S);
    assert_eq!(
        h.bus.controller(axis(1)).unwrap().position(),
        -20,
        "axis 1 moved"
    );
    assert_eq!(
        h.engine.axis(axis(1)).position,
        Some(Pulses(-20)),
        "axis 1's position read after its move"
    );
}

/// A `t` whose answer is lost is not resent (§5 (3)) and its job fails; every axis it may have
/// started counts as moving until a status says otherwise.
#[test]
fn a_synchronized_start_whose_answer_is_lost_reads_where_its_axes_came_to_rest() {
    let mut h = two_axes_with_moves_buffered();
    let set = AxisSet::default().with(axis(0)).with(axis(1));
    let id = h
        .engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::StartBuffered(set),
        })
        .unwrap();
    until_sent(&mut h, |r| r.command == Command::ExecuteBuffered);
    h.bus.set_silent(axis(0), true);
    until_next_frame(&mut h);
    h.bus.set_silent(axis(0), false);
    assert!(h.events.iter().any(|(_, e)| matches!(e,
        Event::JobDone { id: i, result: Err(JobError::Timeout), .. } if *i == id)));
    assert_axis_1_read_at_rest(&mut h);
}

/// A stop of the `t`'s axis asked for while the `t` is on the wire cancels the start's job
/// (`Origin::Cancelled`), and the `t`'s answer then moves no job on: the other axes it started
/// are never marked as started (the answered `t` of a job that runs does that, `started`).
#[test]
fn a_synchronized_start_whose_job_a_stop_cancels_on_the_wire_reads_where_its_axes_came_to_rest() {
    let mut h = two_axes_with_moves_buffered();
    let set = AxisSet::default().with(axis(0)).with(axis(1));
    h.engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::StartBuffered(set),
        })
        .unwrap();
    until_sent(&mut h, |r| r.command == Command::ExecuteBuffered);
    h.engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::Stop,
        })
        .unwrap();
    // Axis 1's answers lost while its move runs (the `d` goes first anyway).
    h.bus.set_silent(axis(1), true);
    h.run_until(h.now + 30 * MS);
    h.bus.set_silent(axis(1), false);
    assert_axis_1_read_at_rest(&mut h);
}

/// A `t` its own axis rejects (its buffered move refused: RUN off, an alarm) still reaches the
/// other axes, which run what they buffered (§4-4-17); the rejection moves no axis on to
/// `started`.
#[test]
fn a_synchronized_start_its_axis_rejects_reads_where_the_other_axes_came_to_rest() {
    let mut h = two_axes_with_moves_buffered();
    run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::Servo(false),
        },
        S,
    )
    .unwrap();
    h.run_until(h.now + 200 * MS);
    let set = AxisSet::default().with(axis(0)).with(axis(1));
    let id = h
        .engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::StartBuffered(set),
        })
        .unwrap();
    until_sent(&mut h, |r| r.command == Command::ExecuteBuffered);
    // Axis 1's answers lost while its move runs (a noisy bus): the next status it answers
    // shows it standing.
    h.bus.set_silent(axis(1), true);
    h.run_until(h.now + 30 * MS);
    h.bus.set_silent(axis(1), false);
    assert!(
        h.events.iter().any(|(_, e)| matches!(e,
            Event::JobDone { id: i, result: Err(JobError::Rejected(AlarmCode(0x70))), .. } if *i == id)),
        "RUN off"
    );
    assert_axis_1_read_at_rest(&mut h);
}

/// A resendable move (`a`, `o`, Q3) whose first answer is lost is resent, and only a lost last
/// attempt counts as a move commanded. A stop asked for after the first attempt timed out and
/// before the resend went (the resend waits behind another axis' stop here; arrival polls of
/// other movers also go before job frames) cancels the job: the resend never goes, the axis
/// took the first attempt, and the stop's answer shows it standing.
#[test]
fn a_move_whose_answer_is_lost_and_a_stop_comes_before_its_resend_reads_where_the_axis_came_to_rest(
) {
    let mut h = homed(2);
    let a = axis(0);
    h.run_until(h.now + 300 * MS);
    let from = h.bus.controller(a).unwrap().position();
    let target = Pulses(from as i32 - 30);
    h.engine
        .submit(Job {
            axis: a,
            kind: JobKind::MoveAbsolute(target),
        })
        .unwrap();
    until_sent(&mut h, |r| matches!(r.command, Command::MoveAbsolute(_)));
    h.bus.set_silent(a, true);
    // Another axis' stop, asked for while the `a` is on the wire: it goes when the `a` times
    // out, before the resend.
    h.engine
        .submit(Job {
            axis: axis(1),
            kind: JobKind::Stop,
        })
        .unwrap();
    until_next_frame(&mut h);
    let (_, last) = *h.sent.last().unwrap();
    assert_eq!((last.axis, last.command), (axis(1), Command::CancelMotion));
    h.bus.set_silent(a, false);
    h.engine
        .submit(Job {
            axis: a,
            kind: JobKind::Stop,
        })
        .unwrap();
    h.run_until(h.now + 2 * S);
    let moves = h
        .sent
        .iter()
        .filter(|(_, r)| matches!(r.command, Command::MoveAbsolute(_)))
        .count();
    assert_eq!(moves, 1, "the case this test is about: never resent");
    let rest = h.bus.controller(a).unwrap().position();
    assert_eq!(rest, i64::from(target.0), "the axis moved");
    assert_eq!(
        h.engine.axis(a).position,
        Some(Pulses(rest as i32)),
        "read where it rests"
    );
}

/// A `t` whose answer is lost marks every configured axis as maybe moving, an offline one
/// too: that one answers no status that would clear the mark, so it counts as moving for good,
/// and rejoin tries wait until no axis moves (`Config::rejoin_while_moving` off): a
/// power-cycled axis never rejoins.
#[test]
fn a_synchronized_start_whose_answer_is_lost_does_not_keep_an_offline_axis_from_rejoining() {
    let mut h = established(3);
    let cycled = axis(2);
    h.bus.schedule_power_cycle(cycled, h.now + 10 * MS, 2 * S);
    h.run_until_event(2 * S, |e| *e == Event::Offline(cycled))
        .expect("offline after its power went");
    let id = h
        .engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::StartBuffered(AxisSet::default().with(axis(0))),
        })
        .unwrap();
    until_sent(&mut h, |r| r.command == Command::ExecuteBuffered);
    h.bus.set_silent(axis(0), true);
    until_next_frame(&mut h);
    h.bus.set_silent(axis(0), false);
    assert!(h.events.iter().any(|(_, e)| matches!(e,
        Event::JobDone { id: i, result: Err(JobError::Timeout), .. } if *i == id)));
    let back = h.run_until_event(15 * S, |e| *e == Event::Online(cycled));
    assert!(back.is_some(), "rejoined once powered again");
}
