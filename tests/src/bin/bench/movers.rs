//! Scenario 5: four of 16 axes moving back and forth (the adaptive polling's targets): how soon
//! a completed move shows in what the PLC reads, how old the idle axes' status gets meanwhile,
//! and what one dead axis costs the live ones while the others move.

use protocol::engine::{Event, Job, JobId, JobKind, Link};
use protocol::line::Baud;
use protocol::status::Outputs;
use protocol::{Axis, Pulses};

use crate::measure::{all_axes, axis, config, cycles, established, Stats};
use crate::scenarios::{homed, start_homing};
use crate::{DEAD, MS, S, WARM_UP, WINDOW};

/// The moving axes: spread over the address range, so that none is next to another in a
/// round robin.
pub(crate) const MOVERS: [u8; 4] = [2, 6, 10, 14];
/// Their travel, in % of the stroke, when their moves are of different lengths: their moves then
/// end at moments that drift apart and together again, as on a machine.
pub(crate) const TRAVEL_PERCENT: [i32; 4] = [90, 75, 60, 45];

/// How the movers' moves relate.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum Ends {
    /// Travels of [`TRAVEL_PERCENT`]: the moves end apart, sometimes together.
    Staggered,
    /// All over 90 % of the stroke from the same start: every move of the four ends at the same
    /// moment (the worst case: the k-th of k is seen k transactions after the first at best).
    Together,
}

pub(crate) struct MoversResult {
    /// From the moment a move is complete on the controller (PFIN: in its band) to the moment
    /// the gateway holds a status report showing it (what DSS1 PEND and the PEND output read).
    pub(crate) complete: Stats,
    /// Times between successive status polls of each idle axis.
    pub(crate) idle_age: Stats,
    /// The longest time between successive status polls of any live axis.
    pub(crate) live_max: u64,
    pub(crate) moves: usize,
}

struct Mover {
    axis: Axis,
    job: Option<JobId>,
    submitted: u64,
    in_band_at: Option<u64>,
    seen: bool,
    toward_far: bool,
}

/// Scenario 5 at 115.2 kbit/s, RTIM 3 ms; with `dead`, axis [`DEAD`] silent throughout.
pub(crate) fn movers(dead: bool, ends: Ends) -> Result<MoversResult, String> {
    let mut h = established(config(Baud::B115200))?;
    let mut movers = Vec::new();
    for n in MOVERS {
        let a = axis(n)?;
        let id = start_homing(&mut h, a)?;
        movers.push(Mover {
            axis: a,
            job: Some(id),
            submitted: h.now,
            in_band_at: None,
            seen: true,
            toward_far: true,
        });
    }
    for m in &mut movers {
        homed(&mut h, m.job.take().ok_or("no home job")?)?;
    }
    let dead_axis = axis(DEAD)?;
    if dead {
        h.bus.set_silent(dead_axis, true);
        h.run_until_event(5 * S, |e| *e == Event::Offline(dead_axis))
            .ok_or("the silent axis never went offline")?;
    }
    h.run_until(h.now + WARM_UP);
    let stroke = h
        .bus
        .controller(movers[0].axis)
        .ok_or("no moving controller")?
        .config()
        .actuator
        .stroke;
    let stroke = i32::try_from(stroke).map_err(|_| "stroke too long")?;
    let near = -stroke / 20;
    let far = |i: usize| {
        let percent = match ends {
            Ends::Staggered => TRAVEL_PERCENT.get(i).copied().unwrap_or(90),
            Ends::Together => 90,
        };
        near - stroke / 100 * percent
    };

    let from = h.now;
    let mut complete = Vec::new();
    let mut done_seen = h.events.len();
    while h.now < from + WINDOW {
        let finished: Vec<JobId> = h.events[done_seen..]
            .iter()
            .filter_map(|(_, e)| match e {
                Event::JobDone { id, result, .. } => result.is_ok().then_some(*id),
                _ => None,
            })
            .collect();
        done_seen = h.events.len();
        for (i, m) in movers.iter_mut().enumerate() {
            let c = h.bus.controller(m.axis).ok_or("no moving controller")?;
            if m.in_band_at.is_none()
                && c.last_move_start()
                    .is_some_and(|start| start >= m.submitted)
            {
                m.in_band_at = c.profile().map(|p| p.in_band_at());
            }
            if let (Some(in_band), false) = (m.in_band_at, m.seen) {
                let state = h.engine.axis(m.axis);
                let shows = state
                    .report
                    .is_some_and(|r| r.outputs.contains(Outputs::PFIN));
                if let (true, Some(at)) = (shows, state.report_at) {
                    if at.0 >= in_band {
                        complete.push(at.0 - in_band);
                        m.seen = true;
                    }
                }
            }
            if m.job.is_some_and(|id| finished.contains(&id)) {
                m.job = None;
            }
            if m.job.is_none() && m.seen {
                let to = if m.toward_far { far(i) } else { near };
                m.toward_far = !m.toward_far;
                let id = h
                    .engine
                    .submit(Job {
                        axis: m.axis,
                        kind: JobKind::MoveAbsolute(Pulses(to)),
                    })
                    .map_err(|e| format!("move refused: {e:?}"))?;
                *m = Mover {
                    job: Some(id),
                    submitted: h.now,
                    in_band_at: None,
                    seen: false,
                    ..*m
                };
            }
        }
        h.run_until(h.now + MS);
    }
    let live: Vec<Axis> = all_axes()?
        .into_iter()
        .filter(|&a| !(dead && a == dead_axis))
        .collect();
    for &a in &live {
        if h.engine.axis(a).link != Link::Online {
            return Err(format!("live axis {} went offline", a.get()));
        }
    }
    let idle: Vec<Axis> = live
        .iter()
        .copied()
        .filter(|a| !MOVERS.contains(&a.get()))
        .collect();
    let live_cycles = cycles(&h.sent, &live, from, h.now);
    Ok(MoversResult {
        moves: complete.len(),
        complete: Stats::of(&complete)?,
        idle_age: Stats::of(&cycles(&h.sent, &idle, from, h.now))?,
        live_max: live_cycles.iter().copied().max().ok_or("no live cycle")?,
    })
}
