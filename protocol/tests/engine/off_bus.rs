//! Nothing to an axis off the bus (issue 33, item 7): once [`Engine::reconfigure`] takes an axis
//! off the bus, no frame goes to it any more, not even a stop (several gateways may share one
//! line through AXISBASE: the axis may be another master's now), and whatever the engine held
//! for it ends, its jobs reported, so that no CMST stays "taken". Each test failed before the fix.

use protocol::engine::*;
use protocol::line::Baud;
use protocol::time::{Duration, Instant};
use protocol::*;

use crate::{answer, axis, config, events, next_frame, reply};

/// Run the engine for `long` from `now`, every frame answered (the establishment that the
/// reconfiguration starts included): the frames sent.
fn run_for(engine: &mut Engine, now: &mut Instant, long: Duration) -> Vec<Request> {
    let end = *now + long;
    let mut address = 0;
    let mut sent = vec![];
    while *now < end {
        let request = next_frame(engine, now);
        sent.push(request);
        reply(engine, now, answer(&request, &mut address));
    }
    sent
}

/// The axes the frames went to.
fn to_axes(sent: &[Request]) -> AxisSet {
    sent.iter().map(|r| r.axis).collect()
}

/// `axes` online and their positions read, every frame answered.
fn all_known(engine: &mut Engine, now: &mut Instant, axes: AxisSet) {
    let mut address = 0;
    for _ in 0..32 {
        if axes.iter().all(|a| engine.axis(a).position.is_some()) {
            return;
        }
        let request = next_frame(engine, now);
        reply(engine, now, answer(&request, &mut address));
    }
    panic!("{axes:?} not known after 32 frames");
}

/// The case the `node` fuzz target found (axes {0, 2} -> {2}): a status poll to axis 0 was on
/// the wire when the bus was reconfigured without it; it timed out and its resend went to
/// axis 0, ahead of the establishment.
#[test]
fn a_poll_on_the_wire_when_its_axis_leaves_is_not_resent() {
    let mut engine = Engine::new(Config {
        axes: AxisSet(0b101),
        ..config(0)
    });
    let mut now = Instant(0);
    let poll = next_frame(&mut engine, &mut now);
    assert_eq!(poll, Request::new(axis(0), Command::Status));
    engine.reconfigure(AxisSet(0b100), Baud::B115200, Rtim::MIN);
    let sent = run_for(&mut engine, &mut now, Duration::from_millis(3_000));
    assert_eq!(to_axes(&sent), AxisSet(0b100), "{sent:?}");
    assert!(!engine.establishing(), "established with axis 2 alone");
}

/// A job's frame on the wire, jobs waiting behind it and a stop in its slot, on the two axes
/// that leave; the frame answered (`answered`) or lost. Every job and the stop are reported
/// cancelled at once, nothing is left pending, and only the axis that stays gets frames.
fn jobs_and_a_stop_end_when_their_axes_leave(answered: bool) {
    let mut engine = Engine::new(config(3));
    let mut now = Instant(0);
    all_known(&mut engine, &mut now, AxisSet(0b111));
    let submit = |engine: &mut Engine, n, kind| {
        engine.submit(Job {
            axis: axis(n),
            kind,
        })
    };
    let moving = submit(&mut engine, 0, JobKind::MoveAbsolute(Pulses(8_000))).unwrap();
    let mut address = 0;
    let a = loop {
        let request = next_frame(&mut engine, &mut now);
        if request.axis == axis(0) && request.command == Command::MoveAbsolute(Pulses(8_000)) {
            break request;
        }
        reply(&mut engine, &mut now, answer(&request, &mut address));
    };
    let waiting = [
        submit(&mut engine, 0, JobKind::MoveAbsolute(Pulses(0))).unwrap(),
        submit(&mut engine, 0, JobKind::ReadPoint(PositionNo::MIN)).unwrap(),
    ];
    let stop = submit(&mut engine, 2, JobKind::Stop).unwrap();
    events(&mut engine);

    engine.reconfigure(AxisSet(0b010), Baud::B115200, Rtim::MIN);
    let ended: Vec<_> = events(&mut engine)
        .into_iter()
        .filter_map(|e| match e {
            Event::JobDone { id, result, .. } => Some((id, result)),
            _ => None,
        })
        .collect();
    let mut ids = vec![moving, waiting[0], waiting[1], stop];
    ids.sort();
    let mut reported: Vec<_> = ended.iter().map(|(id, _)| *id).collect();
    reported.sort();
    assert_eq!(reported, ids, "each job once: {ended:?}");
    assert!(
        ended
            .iter()
            .all(|(_, result)| *result == Err(JobError::Cancelled)),
        "{ended:?}"
    );
    for id in ids {
        assert!(!engine.pending(id), "{id:?} still pending");
    }
    assert!(!engine.busy(axis(0)) && !engine.busy(axis(2)));
    assert_eq!(engine.queued(), 0);

    if answered {
        reply(&mut engine, &mut now, answer(&a, &mut address));
    }
    let sent = run_for(&mut engine, &mut now, Duration::from_millis(5_000));
    assert_eq!(to_axes(&sent), AxisSet(0b010), "{sent:?}");
    let later = events(&mut engine);
    assert!(
        later.iter().all(|e| match e {
            Event::Online(a) | Event::Offline(a) | Event::Status { axis: a, .. } => *a == axis(1),
            Event::JobDone { .. } => false,
            Event::Established => true,
        }),
        "nothing more of the axes that left: {later:?}"
    );
    assert_eq!(engine.expected_arrival(axis(0)), None);
}

#[test]
fn jobs_and_a_stop_end_when_their_axes_leave_the_frame_answered() {
    jobs_and_a_stop_end_when_their_axes_leave(true);
}

#[test]
fn jobs_and_a_stop_end_when_their_axes_leave_the_frame_lost() {
    jobs_and_a_stop_end_when_their_axes_leave(false);
}

/// A stop (`d`) on the wire when its axis leaves, its answer lost: it is not resent (a stop
/// keeps its own resend slot), and it is reported cancelled, once.
#[test]
fn a_stop_on_the_wire_when_its_axis_leaves_is_not_resent() {
    let mut engine = Engine::new(config(2));
    let mut now = Instant(0);
    all_known(&mut engine, &mut now, AxisSet(0b11));
    let stop = engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::Stop,
        })
        .unwrap();
    let d = next_frame(&mut engine, &mut now);
    assert_eq!(d, Request::new(axis(0), Command::CancelMotion));
    events(&mut engine);
    engine.reconfigure(AxisSet(0b10), Baud::B115200, Rtim::MIN);
    let sent = run_for(&mut engine, &mut now, Duration::from_millis(3_000));
    assert_eq!(to_axes(&sent), AxisSet(0b10), "{sent:?}");
    let done: Vec<_> = events(&mut engine)
        .into_iter()
        .filter(|e| matches!(e, Event::JobDone { .. }))
        .collect();
    assert_eq!(
        done,
        [Event::JobDone {
            id: stop,
            axis: axis(0),
            result: Err(JobError::Cancelled)
        }]
    );
}
