//! The bus-master engine against the simulated controllers, in virtual time: establishment,
//! jobs end to end, and a dead axis that comes back.

use protocol::engine::*;
use protocol::jobs::PointData;
use protocol::line::Baud;
use protocol::units::{Accel, Length, Scale, Speed};
use protocol::*;
use rc_host::harness::Harness;
use rc_host::sim::{Bus, BusConfig};

const MS: u64 = 1000;
const S: u64 = 1_000_000;

fn axis(n: u8) -> Axis {
    Axis::new(n).unwrap()
}

/// `n` controllers fresh from power-up (9.6 kbit/s, RTIM 255 ms) and an engine that
/// establishes 115.2 kbit/s with RTIM 3 ms, run until established and every axis online.
fn established(n: u8) -> Harness {
    let axes: Vec<Axis> = (0..n).map(axis).collect();
    let bus = Bus::with_axes(BusConfig::default(), &axes);
    let engine = Engine::new(Config {
        axes: AxisSet::first(n),
        baud: Baud::B115200,
        rtim: Rtim::MIN,
        establish: true,
        ..Config::default()
    });
    let mut h = Harness::new(engine, bus);
    h.run_until_event(10 * S, |e| *e == Event::Established)
        .expect("establishment finishes");
    h.run_until(h.now + 200 * MS);
    for a in &axes {
        assert_eq!(h.engine.axis(*a).link, Link::Online, "axis {a:?}");
    }
    h
}

fn run_job(h: &mut Harness, job: Job, timeout: u64) -> Result<JobOutput, JobError> {
    let id = h.engine.submit(job).expect("queued");
    match h.run_until_event(
        timeout,
        |e| matches!(e, Event::JobDone { id: i, .. } if *i == id),
    ) {
        Some((_, Event::JobDone { result, .. })) => result,
        other => panic!("job {job:?} did not finish: {other:?}"),
    }
}

#[test]
fn establishment_brings_every_axis_to_115200_and_rtim_3() {
    let mut h = established(4);
    for a in 0..4 {
        let c = h.bus.controller(axis(a)).unwrap();
        assert_eq!((c.baud(), c.rtim_ms()), (Baud::B115200, 3));
    }
    // Polling now runs at the new rate: a status round trip is about 2 x 1.39 ms + 3 ms.
    let start = h.sent.len();
    h.run_until(h.now + 100 * MS);
    let polls = h.sent.len() - start;
    let per_transaction = 100 * MS / polls as u64;
    let limit = timing::transaction_time(Baud::B115200, Rtim::MIN).as_micros();
    assert!(
        per_transaction <= limit * 105 / 100,
        "{per_transaction} µs per poll vs {limit}"
    );
    assert!(h.engine.axis(axis(3)).counters.timeouts == 0);
}

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
            kind: JobKind::MoveToPoint(point),
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
fn a_silent_axis_goes_offline_and_rejoins_without_stalling_the_others() {
    let mut h = established(4);
    h.bus.set_silent(axis(2), true);
    h.run_until_event(2 * S, |e| *e == Event::Offline(axis(2)))
        .expect("offline");
    // Live axes keep being polled while axis 2 is probed at the reduced rate.
    let before = h.engine.axis(axis(0)).counters.replies;
    let probes_before = h.engine.axis(axis(2)).counters.frames_sent;
    h.run_until(h.now + 2 * S);
    let polled = h.engine.axis(axis(0)).counters.replies - before;
    let probes = h.engine.axis(axis(2)).counters.frames_sent - probes_before;
    // Three live axes at the wire limit get 2 s / (3 transactions) polls each. A dead axis costs
    // them a fast probe (one Trt, ~24 ms) every 500 ms and, every 5 s, one try at the power-up
    // settings (a ~310 ms time-out at 9.6 kbit/s, RTIM 255 ms).
    let rejoin_try = 310 * MS;
    let cycle = 3 * timing::transaction_time(Baud::B115200, Rtim::MIN).as_micros();
    let ideal = ((2 * S - rejoin_try) / cycle) as u32;
    assert!(
        polled * 100 >= ideal * 90,
        "axis 0 answered {polled} polls in 2 s, ideal {ideal}"
    );
    // Probes back off 20, 40, 80 ... 500 ms: at most 7 in 2 s, plus one try at 9.6 kbit/s.
    assert!(probes <= 8, "axis 2 probed {probes} times in 2 s");
    h.bus.set_silent(axis(2), false);
    h.run_until_event(2 * S, |e| *e == Event::Online(axis(2)))
        .expect("back online");
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
fn a_power_cycled_axis_rejoins_at_its_stored_rate_without_stalling_the_others() {
    let mut h = established(4);
    let cycled = axis(1);
    h.bus
        .schedule_power_cycle(cycled, h.now + 100 * MS, 50 * MS);
    h.run_until_event(2 * S, |e| *e == Event::Offline(cycled))
        .expect("offline after power cycle");
    let back = h.run_until_event(10 * S, |e| *e == Event::Online(cycled));
    assert!(back.is_some(), "rejoined");
    let c = h.bus.controller(cycled).unwrap();
    assert_eq!((c.baud(), c.rtim_ms()), (Baud::B115200, 3));
    // While it rejoined, axis 0 was never left unpolled for more than a few hundred ms.
    let polls: Vec<u64> = h
        .sent
        .iter()
        .filter(|(_, r)| r.axis == axis(0) && r.command == Command::Status)
        .map(|(t, _)| *t)
        .collect();
    let worst = polls.windows(2).map(|w| w[1] - w[0]).max().unwrap();
    assert!(
        worst < 400 * MS,
        "axis 0 waited {} ms between polls",
        worst / MS
    );
    // The others were never reset: no break after the initial establishment.
    assert_eq!(h.engine.bus_counters().establishments, 1);
    for a in [0, 2, 3] {
        assert_eq!(h.engine.axis(axis(a)).link, Link::Online);
    }
}

fn homed(n: u8) -> Harness {
    let mut h = established(n);
    for a in 0..n {
        let r = run_job(
            &mut h,
            Job {
                axis: axis(a),
                kind: JobKind::Home(HomeDirection::MotorEnd),
            },
            10 * S,
        );
        assert!(r.is_ok(), "home {a}: {r:?}");
    }
    h
}

#[test]
fn jog_runs_toward_the_stroke_end_until_stopped() {
    let mut h = homed(1);
    let end = Pulses(-1_000_000); // beyond the stroke: the controller clamps to its limit
    let jog = run_job(
        &mut h,
        Job {
            axis: axis(0),
            kind: JobKind::Jog(end),
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
    // The engine read the position of the moving axis along the way.
    assert!(h.engine.axis(axis(0)).position_at.is_some());
    assert_eq!(
        h.engine.axis(axis(0)).position.map(|p| i64::from(p.0)),
        Some(c.position())
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

/// Every injected fault kind, one at a time: the engine recovers and counts.
#[test]
fn each_fault_kind_is_survived_and_counted() {
    use rc_host::sim::Faults;
    let kinds = [
        (
            "corruption",
            Faults {
                host_byte_corruption: 0.01,
                reply_byte_corruption: 0.01,
                ..Faults::default()
            },
        ),
        (
            "drops",
            Faults {
                reply_drop: 0.05,
                ..Faults::default()
            },
        ),
        (
            "late",
            Faults {
                reply_delay: 0.05,
                reply_delay_us: 40 * MS,
                ..Faults::default()
            },
        ),
        (
            "noise",
            Faults {
                noise: 0.2,
                noise_max_bytes: 3,
                ..Faults::default()
            },
        ),
    ];
    for (name, faults) in kinds {
        let mut h = established(4);
        h.bus.set_faults(faults);
        h.run_until(h.now + 5 * S);
        let stats = h.bus.stats().clone();
        let totals = (0..4).fold((0, 0, 0, 0), |acc, a| {
            let c = h.engine.axis(axis(a)).counters;
            (
                acc.0 + c.timeouts,
                acc.1 + c.retries,
                acc.2 + c.bcc_errors,
                acc.3 + c.replies,
            )
        });
        let (timeouts, retries, bcc_errors, replies) = totals;
        // 4 axes for 5 s at the wire limit would be ~740 transactions. At 1 % per byte both
        // ways, 0.99^32 = 72.5 % of transactions are intact, a corrupted answer costs one more
        // transaction, a corrupted command a 26-ms Trt: about 380 answers are expected.
        assert!(
            replies > 300,
            "{name}: polling continued ({replies} replies)"
        );
        match name {
            "corruption" => {
                assert!(stats.replies_corrupted + stats.host_frames_corrupted > 0);
                assert!(bcc_errors > 0 && retries > 0, "{name}: {totals:?}");
            }
            // One time-out per lost answer; the last one may still be waiting for its Trt
            // when the run stops.
            "drops" => {
                let lost = stats.replies_dropped;
                assert!(
                    (lost.saturating_sub(1)..=lost).contains(&u64::from(timeouts)),
                    "{name}: {timeouts} time-outs for {lost} dropped replies"
                );
            }
            "late" => {
                let late = stats.replies_delayed;
                assert!(
                    (late.saturating_sub(1)..=late).contains(&u64::from(timeouts)),
                    "{name}: {timeouts} time-outs for {late} replies later than Trt"
                );
            }
            _ => {
                assert!(stats.noise_bytes > 0);
                assert_eq!(timeouts, 0, "{name}: noise between frames costs nothing");
            }
        }
        for a in 0..4 {
            assert_eq!(
                h.engine.axis(axis(a)).link,
                Link::Online,
                "{name}: axis {a}"
            );
        }
    }
}

#[test]
fn sixteen_axes_are_all_polled() {
    let mut h = established(16);
    let before: Vec<u32> = (0..16)
        .map(|a| h.engine.axis(axis(a)).counters.replies)
        .collect();
    h.run_until(h.now + S);
    for a in 0..16u8 {
        let polled = h.engine.axis(axis(a)).counters.replies - before[usize::from(a)];
        // 1 s / (16 x 6.8 ms) = 9.2 cycles.
        assert!(
            (8..=10).contains(&polled),
            "axis {a}: {polled} polls in 1 s"
        );
    }
}
