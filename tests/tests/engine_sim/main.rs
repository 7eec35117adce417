//! The bus-master engine against the simulated controllers, in virtual time: establishment,
//! jobs end to end, and a dead axis that comes back.

mod jobs;
mod link;
mod pacing;

use protocol::engine::*;
use protocol::line::Baud;
use protocol::*;
use rc_host::harness::Harness;
use rc_tools::sim::{Bus, BusConfig};

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
