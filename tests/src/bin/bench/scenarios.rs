//! The four scenarios: status cycle, PLC request to wire, one dead axis, position age.

use protocol::engine::{Config, Event, Job, JobError, JobId, JobKind, JobOutput, Link};
use protocol::line::Baud;
use protocol::{Axis, Command, HomeDirection, Pulses, Request};
use rc_host::harness::Harness;
use rc_tools::sim::rng::Rng;

use crate::measure::{all_axes, axis, config, cycles, established, timeouts, transaction, Stats};
use crate::{AXES, DEAD, MOVER, MS, S, WARM_UP, WINDOW};

pub(crate) struct CycleResult {
    pub(crate) stats: Stats,
    pub(crate) limit: u64,
    pub(crate) frames: usize,
    pub(crate) timeouts: u32,
}

/// 1. The status cycle of 16 idle axes at `baud`.
pub(crate) fn status_cycle(baud: Baud) -> Result<CycleResult, String> {
    let mut h = established(config(baud))?;
    let from = h.now;
    let timeouts_before = timeouts(&h);
    let frames_before = h.sent.len();
    h.run_until(from + WINDOW);
    let axes = all_axes()?;
    let stats = Stats::of(&cycles(&h.sent, &axes, from, h.now))?;
    Ok(CycleResult {
        stats,
        limit: u64::from(AXES) * transaction(baud),
        frames: h.sent.len() - frames_before,
        timeouts: timeouts(&h) - timeouts_before,
    })
}

pub(crate) struct LatencyResult {
    pub(crate) stats: Stats,
    /// How far `run_until(arrival)` ran past the arrival time, at most.
    pub(crate) max_overshoot: u64,
    /// Polls sent between a request's submission and its frame, at most.
    pub(crate) max_frames_ahead: usize,
}

/// 2. PLC request to the first byte of its frame on the wire, 115.2 kbit/s.
pub(crate) fn request_latency(seed: u64, requests: u32) -> Result<LatencyResult, String> {
    let mut h = established(config(Baud::B115200))?;
    let mut rng = Rng::new(seed);
    let mut latencies = Vec::with_capacity(requests as usize);
    let mut max_overshoot = 0;
    let mut max_frames_ahead = 0;
    let command = Command::Servo(true);
    for i in 0..requests {
        let arrival = h.now + rng.below(20 * MS);
        h.run_until(arrival);
        max_overshoot = max_overshoot.max(h.now - arrival);
        let submitted = h.now;
        let target = axis(u8::try_from(rng.below(u64::from(AXES))).unwrap_or(0))?;
        let mark = h.sent.len();
        let id = h
            .engine
            .submit(Job {
                axis: target,
                kind: JobKind::Command(command),
            })
            .map_err(|e| format!("request {i}: submit refused: {e:?}"))?;
        let result = wait_job(&mut h, id, S)
            .ok_or_else(|| format!("request {i} (axis {}) never finished", target.get()))?;
        if let Err(e) = result {
            return Err(format!("request {i} (axis {}) failed: {e:?}", target.get()));
        }
        let (position, sent_at) = h.sent[mark..]
            .iter()
            .enumerate()
            .find(|(_, (_, r))| r.axis == target && r.command == command)
            .map(|(k, (t, _))| (k, *t))
            .ok_or_else(|| format!("request {i}: its frame was never sent"))?;
        max_frames_ahead = max_frames_ahead.max(position);
        latencies.push(sent_at - submitted);
    }
    Ok(LatencyResult {
        stats: Stats::of(&latencies)?,
        max_overshoot,
        max_frames_ahead,
    })
}

/// Run until job `id` finishes (or `timeout` µs pass); its result.
/// Home `axis` at the motor end (coordinates then run from 0 to -stroke): the job.
pub(crate) fn start_homing(h: &mut Harness, axis: Axis) -> Result<JobId, String> {
    h.engine
        .submit(Job {
            axis,
            kind: JobKind::Home(HomeDirection::MotorEnd),
        })
        .map_err(|e| format!("home refused: {e:?}"))
}

/// Wait for a homing job to succeed.
pub(crate) fn homed(h: &mut Harness, home: JobId) -> Result<(), String> {
    match wait_job(h, home, 30 * S) {
        Some(Ok(_)) => Ok(()),
        other => Err(format!("homing failed: {other:?}")),
    }
}

fn wait_job(h: &mut Harness, id: JobId, timeout: u64) -> Option<Result<JobOutput, JobError>> {
    let mine = |e: &Event| matches!(e, Event::JobDone { id: i, .. } if *i == id);
    // It may have finished within the step that submitted it.
    let done = h.events.iter().rev().find(|(_, e)| mine(e)).copied();
    let done = match done {
        Some(hit) => Some(hit),
        None => h.run_until_event(timeout, mine),
    };
    match done {
        Some((_, Event::JobDone { result, .. })) => Some(result),
        _ => None,
    }
}

pub(crate) struct DeadResult {
    pub(crate) stats: Stats,
    /// Live axes' cycles around the detection: from one cycle before the silence to just after
    /// the `Offline` event.
    pub(crate) transient: Stats,
    /// From the first unanswered poll to the `Offline` event.
    pub(crate) detection: u64,
    /// Frames sent to the dead axis in the window: status probes, and tries at the power-up
    /// settings (rejoin: any other command).
    pub(crate) probes: usize,
    pub(crate) rejoins: usize,
    /// The longest of those transactions: from the frame to the next frame on the bus.
    pub(crate) longest_try: u64,
    pub(crate) window: u64,
}

/// 3. One silent axis among 16 at 115.2 kbit/s, the engine configured with `config`.
pub(crate) fn dead_axis(config: Config) -> Result<DeadResult, String> {
    let mut h = established(config)?;
    let dead = axis(DEAD)?;
    let silent_at = h.now;
    h.bus.set_silent(dead, true);
    let (offline_at, _) = h
        .run_until_event(5 * S, |e| *e == Event::Offline(dead))
        .ok_or("the silent axis never went offline")?;
    let first_lost = h
        .sent
        .iter()
        .find(|(t, r)| *t >= silent_at && r.axis == dead)
        .map_or(silent_at, |(t, _)| *t);
    h.run_until(offline_at + WARM_UP);
    let live: Vec<Axis> = all_axes()?.into_iter().filter(|&a| a != dead).collect();
    let from = h.now;
    h.run_until(from + WINDOW);
    for &a in &live {
        if h.engine.axis(a).link != Link::Online {
            return Err(format!(
                "live axis {} went {:?}",
                a.get(),
                h.engine.axis(a).link
            ));
        }
    }
    let window: Vec<&(u64, Request)> = h.sent.iter().filter(|(t, _)| *t >= from).collect();
    let tries: Vec<(u64, Command)> = window
        .windows(2)
        .filter(|w| w[0].1.axis == dead)
        .map(|w| (w[1].0 - w[0].0, w[0].1.command))
        .collect();
    Ok(DeadResult {
        stats: Stats::of(&cycles(&h.sent, &live, from, h.now))?,
        transient: Stats::of(&cycles(
            &h.sent,
            &live,
            silent_at.saturating_sub(200 * MS),
            offline_at + 150 * MS,
        ))?,
        detection: offline_at - first_lost,
        probes: tries.iter().filter(|(_, c)| *c == Command::Status).count(),
        rejoins: tries.iter().filter(|(_, c)| *c != Command::Status).count(),
        longest_try: tries.iter().map(|(d, _)| *d).max().unwrap_or(0),
        window: h.now - from,
    })
}

pub(crate) struct AgeResult {
    pub(crate) stats: Stats,
    pub(crate) moves: u32,
    /// From the start of each move to its first position reply, at most.
    pub(crate) first_read: u64,
    /// The status cycle of the idle axes while the axis moves.
    pub(crate) cycle: Stats,
}

/// 4. The age of a moving axis' position, 115.2 kbit/s, 16 axes polled.
pub(crate) fn position_age() -> Result<AgeResult, String> {
    let mut h = established(config(Baud::B115200))?;
    let mover = axis(MOVER)?;
    let home = start_homing(&mut h, mover)?;
    homed(&mut h, home)?;
    // Homed at the motor end: coordinates run from 0 to -stroke. Travel most of the stroke.
    let stroke = h
        .bus
        .controller(mover)
        .ok_or("no moving controller")?
        .config()
        .actuator
        .stroke;
    let far = -i32::try_from(stroke).map_err(|_| "stroke too long")?
        + i32::try_from(stroke / 20).unwrap_or(0);
    let near = -i32::try_from(stroke / 20).unwrap_or(0);
    let mut ages = Vec::new();
    let mut first_read = 0;
    let moves = 6u32;
    let others: Vec<Axis> = all_axes()?.into_iter().filter(|&a| a != mover).collect();
    let mut cycle = Vec::new();
    for k in 0..moves {
        let to = if k % 2 == 0 { far } else { near };
        let seen = h.events.len();
        let id = h
            .engine
            .submit(Job {
                axis: mover,
                kind: JobKind::MoveAbsolute(Pulses(to)),
            })
            .map_err(|e| format!("move refused: {e:?}"))?;
        let submitted = h.now;
        let deadline = h.now + 30 * S;
        let mut first: Option<u64> = None;
        let mut moving_from: Option<u64> = None;
        loop {
            let done = h.events[seen..]
                .iter()
                .find(|(_, e)| matches!(e, Event::JobDone { id: i, .. } if *i == id));
            if let Some((_, Event::JobDone { result, .. })) = done {
                result.map_err(|e| format!("move {k} failed: {e:?}"))?;
                break;
            }
            if h.now >= deadline {
                return Err(format!("move {k} never finished"));
            }
            h.run_until(h.now + MS);
            let c = h.bus.controller(mover).ok_or("no moving controller")?;
            let start = match c.last_move_start() {
                Some(start) if c.moving() && start >= submitted => start,
                _ => continue,
            };
            moving_from.get_or_insert(start);
            let Some(at) = h.engine.axis(mover).position_at.map(|t| t.0) else {
                continue;
            };
            if at < start {
                continue; // No position read since this move began yet.
            }
            if first.is_none() {
                first = Some(at - start);
            }
            ages.push(h.now - at);
        }
        let first = first.ok_or(format!("move {k}: no position read while moving"))?;
        first_read = first_read.max(first);
        if let Some(start) = moving_from {
            cycle.extend(cycles(&h.sent, &others, start, h.now));
        }
    }
    Ok(AgeResult {
        stats: Stats::of(&ages)?,
        moves,
        first_read,
        cycle: Stats::of(&cycle)?,
    })
}
