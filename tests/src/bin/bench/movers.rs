//! Scenarios 5 and 6: four of 16 axes moving back and forth (the adaptive polling's targets): how
//! soon a completed move shows in what the PLC reads, how old the idle axes' status gets
//! meanwhile, and what one dead axis costs the live ones while the others move. Scenario 6 moves
//! to stored points (Q3, what POSR + CSTR and the PIO's strobe send) with every controller
//! answering sooner or later than the wire time the gateway counts on: a pseudo-terminal or a
//! USB adapter has no wire time, a slow converter adds some, and the figures are then taken
//! against the transaction time measured in the run.

use protocol::engine::{Event, Job, JobId, JobKind, Link, PointAim};
use protocol::line::Baud;
use protocol::memory::{flgp, PointField};
use protocol::status::Outputs;
use protocol::{Axis, PositionNo, Pulses, Rtim};

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

/// What the movers' controllers are told, and how they answer.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum Moves {
    /// `a` to a position, the controllers answering in the wire time (scenario 5).
    Absolute,
    /// Q3 to one of two stored points, whose positions the engine is given (as the gateway
    /// gives them from its cached rows), every controller answering after `real` ms where the
    /// engine counts on `assumed` (its RTIM).
    Points { assumed: u8, real: u8 },
}

/// Scenario 6's two paces: faster than the wire time the engine counts on (0.69 of it, as on a
/// pseudo-terminal, where a 6.8 ms transaction took 4.6 ms), and slower (1.59 times).
pub(crate) const FASTER: Moves = Moves::Points {
    assumed: 7,
    real: 3,
};
/// See [`FASTER`].
pub(crate) const SLOWER: Moves = Moves::Points {
    assumed: 3,
    real: 7,
};

pub(crate) struct MoversResult {
    /// From the moment a move is complete on the controller (PFIN: in its band) to the moment
    /// the gateway holds a status report showing it (what DSS1 PEND and the PEND output read).
    pub(crate) complete: Stats,
    /// Times between successive status polls of each idle axis.
    pub(crate) idle_age: Stats,
    /// The longest time between successive status polls of any live axis.
    pub(crate) live_max: u64,
    pub(crate) moves: usize,
    /// The time per transaction on the bus during the window, µs: the median time from one
    /// command to the next (the bus is always busy).
    pub(crate) transaction: f64,
}

struct Mover {
    axis: Axis,
    job: Option<JobId>,
    submitted: u64,
    in_band_at: Option<u64>,
    seen: bool,
    toward_far: bool,
}

/// Scenario 5 (and 6, with `moves`) at 115.2 kbit/s; with `dead`, axis [`DEAD`] silent
/// throughout.
pub(crate) fn movers(dead: bool, ends: Ends, moves: Moves) -> Result<MoversResult, String> {
    let mut engine_config = config(Baud::B115200);
    if let Moves::Points { assumed, .. } = moves {
        engine_config.rtim = Rtim::new(assumed).ok_or("RTIM out of range")?;
        // Answers sooner than the wire time it counts on: taken, as on a pseudo-terminal.
        engine_config.wire_timing = false;
    }
    let mut h = established(engine_config)?;
    if let Moves::Points { real, .. } = moves {
        for a in all_axes()? {
            h.bus
                .controller_mut(a)
                .ok_or("no controller")?
                .set_rtim_ms(real);
        }
    }
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
    // Every move at the velocity and acceleration the controllers start with, given as the PLC
    // gives it: a direct move is `v` then `a` (the PLC's direct-move registers), and a point's
    // row carries its own motion (what the PLC's point writes store: FLGP's motion bit), which
    // the gateway's cache knows. With either the gateway knows the acceleration time, which
    // its arrival estimate needs (engine::approach).
    let (velocity, acceleration) = h
        .bus
        .controller(movers[0].axis)
        .ok_or("no moving controller")?
        .memory()
        .exec_motion()
        .ok_or("velocity or acceleration out of range")?;
    // Scenario 6: the same two positions as points 1 and 2 of each mover.
    let (near_point, far_point) = (PositionNo::new(1), PositionNo::new(2));
    if let Moves::Points { .. } = moves {
        for (i, m) in movers.iter().enumerate() {
            let memory = h
                .bus
                .controller_mut(m.axis)
                .ok_or("no moving controller")?
                .memory_mut();
            for (index, at) in [(1usize, near), (2, far(i))] {
                let mut row = memory.exec.point;
                let field = |f| rc_tools::sim::memory::pi(f);
                *row.get_mut(field(PointField::Position))
                    .ok_or("no position field")? = Pulses(at).to_wire();
                *row.get_mut(field(PointField::Flags))
                    .ok_or("no flags field")? |= flgp::MOTION;
                *memory.nv.points.get_mut(index).ok_or("no point")? = row;
                *memory.nv.written.get_mut(index).ok_or("no point")? = true;
            }
        }
    }

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
                let point = if m.toward_far { far_point } else { near_point };
                m.toward_far = !m.toward_far;
                let kind = match (moves, point) {
                    (Moves::Points { .. }, Some(point)) => {
                        let aim = PointAim {
                            position: Pulses(to),
                            motion: Some((velocity, acceleration)),
                        };
                        JobKind::MoveToPoint(point, Some(aim))
                    }
                    _ => JobKind::DirectMove {
                        target: Pulses(to),
                        relative: false,
                        velocity,
                        acceleration,
                    },
                };
                let id = h
                    .engine
                    .submit(Job { axis: m.axis, kind })
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
    let sent: Vec<u64> = h
        .sent
        .iter()
        .map(|(t, _)| *t)
        .filter(|&t| t >= from)
        .collect();
    let gaps: Vec<u64> = sent.windows(2).map(|w| w[1] - w[0]).collect();
    Ok(MoversResult {
        transaction: Stats::of(&gaps)?.p50 as f64,
        moves: complete.len(),
        complete: Stats::of(&complete)?,
        idle_age: Stats::of(&cycles(&h.sent, &idle, from, h.now))?,
        live_max: live_cycles.iter().copied().max().ok_or("no live cycle")?,
    })
}
