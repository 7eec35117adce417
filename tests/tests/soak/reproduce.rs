//! The rig of the reproductions: quiet controllers, and a stop while an answer is lost.

use protocol::engine::{Config, Engine, Event, Job, JobError, JobKind, JobOutput};
use protocol::AxisSet;
use protocol::{Command, HomeDirection, Request, Rtim};
use rc_host::harness::Harness;
use rc_tools::sim::{Bus, BusConfig, ControllerConfig};

use crate::{axis, BAUD, MS, S};

/// `n` quiet controllers already at 115.2 kbit/s and RTIM 3 ms, and an engine that knows it.
pub(crate) fn quiet(n: usize) -> Harness {
    let mut bus = Bus::new(BusConfig {
        host_baud: BAUD,
        ..BusConfig::default()
    });
    for k in 0..n {
        bus.add_controller(
            axis(k),
            ControllerConfig {
                stored_line: Some((BAUD, Rtim::MIN)),
                ..ControllerConfig::default()
            },
        );
    }
    let engine = Engine::new(Config {
        axes: AxisSet::first(u8::try_from(n).unwrap()),
        establish: false,
        ..Config::default()
    });
    let mut h = Harness::new(engine, bus);
    h.run_until(50 * MS);
    h
}

pub(crate) fn done(
    h: &Harness,
    id: protocol::engine::JobId,
) -> Option<Result<JobOutput, JobError>> {
    h.events.iter().find_map(|(_, e)| match e {
        Event::JobDone { id: i, result, .. } if *i == id => Some(*result),
        _ => None,
    })
}

pub(crate) fn run_until_sent(h: &mut Harness, found: impl Fn(&Request) -> bool) {
    let until = h.now + S;
    while h.now < until {
        let seen = h.sent.len();
        h.step(until);
        if h.sent[seen..].iter().any(|(_, r)| found(r)) {
            return;
        }
    }
    panic!("not sent");
}

/// The axis homed, silent while `command` reaches it (so that its answer is lost) and answering
/// again right after; then a stop while `command` waits for its answer. Returns
/// the index in `h.sent` and `h.events` from the stop on.
pub(crate) fn stop_while_unanswered(command: Command) -> (Harness, usize, usize) {
    let mut h = quiet(1);
    let home = h
        .engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::Home(HomeDirection::MotorEnd),
        })
        .unwrap();
    h.run_until(h.now + 5 * S);
    assert!(matches!(done(&h, home), Some(Ok(_))));
    let kind = match command {
        Command::MoveAbsolute(x) => JobKind::MoveAbsolute(x),
        Command::MoveRelative(d) => JobKind::MoveRelative(d),
        _ => unreachable!(),
    };
    h.engine
        .submit(Job {
            axis: axis(0),
            kind,
        })
        .unwrap();
    run_until_sent(&mut h, |r| r.command == command);
    // The controller takes the command 1.4 ms later and drops its answer.
    h.bus.set_silent(axis(0), true);
    h.run_until(h.now + 2 * MS);
    h.bus.set_silent(axis(0), false);
    let (sent, events) = (h.sent.len(), h.events.len());
    let stop = h
        .engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::Stop,
        })
        .unwrap();
    h.run_until(h.now + 2 * S);
    assert!(
        matches!(done(&h, stop), Some(Ok(_))),
        "{:?}",
        done(&h, stop)
    );
    (h, sent, events)
}
