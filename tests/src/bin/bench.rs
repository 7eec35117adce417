//! `bench`: how close the bus master gets to what the wire allows, measured on the simulated bus
//! in virtual time.
//!
//! Everything runs in virtual time (µs) through [`Harness`]: the engine drives 16 simulated
//! controllers, no clock is read, and a run is a pure function of the seed, so the figures are
//! identical from run to run and from machine to machine. For each measurement the table shows
//! the measured value, the physical limit computed in the same run from
//! [`protocol::engine::timing`], their ratio, the target ratio and PASS/MISS. A benchmark
//! reports; it does not assert: the exit status is 0 whatever the figures, 1 only if the bench
//! itself could not run (the bus never established, a job never finished, ...).
//!
//! Set-up: 16 factory-fresh controllers (9.6 kbit/s, RTIM 255 ms after power-up) and an engine
//! with `Config::establish = true`, so every scenario starts with the real §6-1 establishment
//! procedure to the rate under test and RTIM 3 ms; measurements start after a warm-up.
//!
//! 1. **Status cycle**, 16 idle axes at 38.4 and 115.2 kbit/s: the time between successive
//!    status polls of the same axis, over 20 s, vs the wire limit 16 x T, where
//!    T = [`timing::transaction_time`] (command + RTIM + response + 1 ms host gap).
//! 2. **PLC request to wire**: 10,000 jobs (`q1` to an axis whose servo is on, a command polling
//!    never sends), each submitted at a random time (splitmix64, uniform 0-20 ms after the
//!    previous job finished, random axis) into the running 115.2 kbit/s bus; latency = time the
//!    job's frame starts on the wire - submit time, vs one transaction T and one Trt.
//! 3. **One dead axis** among 16 at 115.2 kbit/s: the live axes' cycle vs the all-alive cycle.
//! 4. **Position age** of a moving axis (time since its last R4 PNOW reply, sampled every 1 ms
//!    while it moves) while 16 axes are polled at 115.2 kbit/s, vs the status cycle.
//!
//! ```text
//! cargo run --release -p rc-host --bin bench            # table
//! cargo run --release -p rc-host --bin bench -- --json  # one JSON object
//! ```

use std::fmt::Write as _;
use std::process::ExitCode;

use clap::Parser;
use protocol::engine::{
    timing, Config, Engine, Event, Job, JobError, JobId, JobKind, JobOutput, Link,
};
use protocol::line::Baud;
use protocol::time::Duration;
use protocol::AxisSet;
use protocol::{Axis, Command, HomeDirection, Pulses, Request, Rtim};
use rc_host::harness::Harness;
use rc_host::sim::rng::Rng;
use rc_host::sim::{Bus, BusConfig};
use serde_json::{json, Value};

const MS: u64 = 1_000;
const S: u64 = 1_000_000;
/// Axes on the bus in every scenario.
const AXES: u8 = 16;
/// Virtual time measured in the cycle scenarios.
const WINDOW: u64 = 20 * S;
/// Virtual time run after establishment (or after a change) before measuring.
const WARM_UP: u64 = S;
/// The dead axis of scenario 3.
const DEAD: u8 = 7;
/// The moving axis of scenario 4.
const MOVER: u8 = 3;

#[derive(Parser, Debug)]
#[command(
    name = "bench",
    about = "Engine benchmark on the simulated bus, in virtual time (deterministic)"
)]
struct Args {
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
    /// Seed of the request arrival times and axes (scenario 2).
    #[arg(long, default_value_t = 0x0BE7_C0DE)]
    seed: u64,
    /// PLC requests in scenario 2.
    #[arg(long, default_value_t = 10_000, value_parser = clap::value_parser!(u32).range(1..))]
    requests: u32,
}

/// One line of the table: a measured value against a limit.
struct Row {
    id: &'static str,
    scenario: &'static str,
    what: String,
    measured_us: f64,
    limit_us: f64,
    /// What the limit is, in a few characters.
    limit_is: &'static str,
    /// The ratio measured / limit must not exceed this; `None`: informative.
    target: Option<f64>,
}

impl Row {
    fn ratio(&self) -> f64 {
        if self.limit_us > 0.0 {
            self.measured_us / self.limit_us
        } else {
            f64::NAN
        }
    }

    fn pass(&self) -> Option<bool> {
        self.target.map(|t| self.ratio() <= t)
    }
}

/// Distribution of a set of durations (µs).
#[derive(Clone, Copy, Debug, Default)]
struct Stats {
    n: usize,
    mean: f64,
    p50: u64,
    p99: u64,
    max: u64,
    min: u64,
}

impl Stats {
    fn of(values: &[u64]) -> Result<Stats, String> {
        if values.is_empty() {
            return Err("no samples".into());
        }
        let mut sorted = values.to_vec();
        sorted.sort_unstable();
        // Nearest rank: the smallest value with at least p of the samples at or below it.
        let rank = |p: f64| {
            let r = (p * sorted.len() as f64).ceil() as usize;
            sorted[r.clamp(1, sorted.len()) - 1]
        };
        Ok(Stats {
            n: sorted.len(),
            mean: sorted.iter().map(|&v| v as f64).sum::<f64>() / sorted.len() as f64,
            p50: rank(0.50),
            p99: rank(0.99),
            max: sorted[sorted.len() - 1],
            min: sorted[0],
        })
    }

    fn json(&self) -> Value {
        json!({
            "n": self.n,
            "mean_us": round3(self.mean),
            "min_us": self.min,
            "p50_us": self.p50,
            "p99_us": self.p99,
            "max_us": self.max,
        })
    }
}

fn round3(x: f64) -> f64 {
    (x * 1000.0).round() / 1000.0
}

fn axis(n: u8) -> Result<Axis, String> {
    Axis::new(n).ok_or_else(|| format!("no axis {n}"))
}

fn all_axes() -> Result<Vec<Axis>, String> {
    (0..AXES).map(axis).collect()
}

/// The engine configuration of every scenario: 16 axes, `baud`, RTIM 3 ms, establishment on,
/// everything else at its default.
fn config(baud: Baud) -> Config {
    Config {
        axes: AxisSet::first(AXES),
        baud,
        rtim: Rtim::MIN,
        establish: true,
        ..Config::default()
    }
}

/// 16 controllers fresh from power-up and an engine with `config`, run until established (at
/// `config.baud`, RTIM 3 ms), every axis online, and warmed up.
fn established(config: Config) -> Result<Harness, String> {
    let baud = config.baud;
    let axes = all_axes()?;
    let bus = Bus::with_axes(BusConfig::default(), &axes);
    let mut h = Harness::new(Engine::new(config), bus);
    h.run_until_event(120 * S, |e| *e == Event::Established)
        .ok_or_else(|| format!("{baud:?}: the bus never established"))?;
    h.run_until(h.now + WARM_UP);
    for &a in &axes {
        let link = h.engine.axis(a).link;
        if link != Link::Online {
            return Err(format!(
                "{baud:?}: axis {} is {link:?} after establishment",
                a.get()
            ));
        }
        let c = h
            .bus
            .controller(a)
            .ok_or_else(|| format!("no controller {}", a.get()))?;
        if (c.baud(), c.rtim_ms()) != (baud, Rtim::MIN.get()) {
            return Err(format!(
                "axis {} runs at {:?}/{} ms after establishment",
                a.get(),
                c.baud(),
                c.rtim_ms()
            ));
        }
    }
    Ok(h)
}

/// The times the status of `axis` was polled in `[from, to)`.
fn poll_times(sent: &[(u64, Request)], axis: Axis, from: u64, to: u64) -> Vec<u64> {
    sent.iter()
        .filter(|(t, r)| *t >= from && *t < to && r.axis == axis && r.command == Command::Status)
        .map(|(t, _)| *t)
        .collect()
}

/// Times between successive status polls of the same axis, for each of `axes`, in `[from, to)`.
fn cycles(sent: &[(u64, Request)], axes: &[Axis], from: u64, to: u64) -> Vec<u64> {
    axes.iter()
        .flat_map(|&a| {
            let times = poll_times(sent, a, from, to);
            times.windows(2).map(|w| w[1] - w[0]).collect::<Vec<_>>()
        })
        .collect()
}

fn timeouts(h: &Harness) -> u32 {
    Axis::all()
        .map(|a| h.engine.axis(a).counters.timeouts)
        .sum()
}

/// Wire limit of one transaction and of a 16-axis status cycle at `baud`, RTIM 3 ms (µs).
fn transaction(baud: Baud) -> u64 {
    timing::transaction_time(baud, Rtim::MIN).as_micros()
}

/// The response time-out Trt at `baud`, RTIM 3 ms (µs).
fn trt(baud: Baud) -> u64 {
    timing::response_timeout(baud, Rtim::MIN, false).as_micros()
}

// ------------------------------------------------------------------------------ scenarios

struct CycleResult {
    stats: Stats,
    limit: u64,
    frames: usize,
    timeouts: u32,
}

/// 1. The status cycle of 16 idle axes at `baud`.
fn status_cycle(baud: Baud) -> Result<CycleResult, String> {
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

struct LatencyResult {
    stats: Stats,
    /// How far `run_until(arrival)` ran past the arrival time, at most.
    max_overshoot: u64,
    /// Polls sent between a request's submission and its frame, at most.
    max_frames_ahead: usize,
}

/// 2. PLC request to the first byte of its frame on the wire, 115.2 kbit/s.
fn request_latency(seed: u64, requests: u32) -> Result<LatencyResult, String> {
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

struct DeadResult {
    stats: Stats,
    /// Live axes' cycles around the detection: from one cycle before the silence to just after
    /// the `Offline` event.
    transient: Stats,
    /// From the first unanswered poll to the `Offline` event.
    detection: u64,
    /// Frames sent to the dead axis in the window: status probes, and tries at the power-up
    /// settings (rejoin: any other command).
    probes: usize,
    rejoins: usize,
    /// The longest of those transactions: from the frame to the next frame on the bus.
    longest_try: u64,
    window: u64,
}

/// 3. One silent axis among 16 at 115.2 kbit/s, the engine configured with `config`.
fn dead_axis(config: Config) -> Result<DeadResult, String> {
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

struct AgeResult {
    stats: Stats,
    moves: u32,
    /// From the start of each move to its first position reply, at most.
    first_read: u64,
    /// The status cycle of the idle axes while the axis moves.
    cycle: Stats,
}

/// 4. The age of a moving axis' position, 115.2 kbit/s, 16 axes polled.
fn position_age() -> Result<AgeResult, String> {
    let mut h = established(config(Baud::B115200))?;
    let mover = axis(MOVER)?;
    let home = h
        .engine
        .submit(Job {
            axis: mover,
            kind: JobKind::Home(HomeDirection::MotorEnd),
        })
        .map_err(|e| format!("home refused: {e:?}"))?;
    match wait_job(&mut h, home, 30 * S) {
        Some(Ok(_)) => {}
        other => return Err(format!("homing failed: {other:?}")),
    }
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

// ------------------------------------------------------------------------------ report

struct Report {
    rows: Vec<Row>,
    notes: Vec<String>,
    json: Value,
}

fn run(args: &Args) -> Result<Report, String> {
    let mut rows = Vec::new();
    let mut notes = Vec::new();
    let engine_size = std::mem::size_of::<Engine>();

    // 1.
    let mut cycle_json = Vec::new();
    let mut alive_115 = None;
    for (baud, ids) in [
        (
            Baud::B38400,
            ["cycle_38k4_mean", "cycle_38k4_p99", "cycle_38k4_max"],
        ),
        (
            Baud::B115200,
            ["cycle_115k2_mean", "cycle_115k2_p99", "cycle_115k2_max"],
        ),
    ] {
        let r = status_cycle(baud)?;
        let kbit = f64::from(baud.bits_per_second()) / 1000.0;
        let limit = r.limit as f64;
        for (id, label, value, target) in [
            (ids[0], "mean", r.stats.mean, Some(1.05)),
            (ids[1], "p99", r.stats.p99 as f64, None),
            (ids[2], "max", r.stats.max as f64, None),
        ] {
            rows.push(Row {
                id,
                scenario: "1 status cycle",
                what: format!("{kbit} kbit/s, 16 idle axes, {label}"),
                measured_us: value,
                limit_us: limit,
                limit_is: "16 x T",
                target,
            });
        }
        notes.push(format!(
            "1. {kbit} kbit/s: T = {} us, Trt = {} us; {} cycles measured over {} s, {} frames, {} time-outs",
            transaction(baud),
            trt(baud),
            r.stats.n,
            WINDOW / S,
            r.frames,
            r.timeouts
        ));
        cycle_json.push(json!({
            "baud": baud.bits_per_second(),
            "transaction_us": transaction(baud),
            "limit_us": r.limit,
            "cycle": r.stats.json(),
            "frames": r.frames,
            "timeouts": r.timeouts,
        }));
        if baud == Baud::B115200 {
            alive_115 = Some(r.stats);
        }
    }
    let alive = alive_115.ok_or("no 115.2 kbit/s cycle")?;

    // 2.
    let t115 = transaction(Baud::B115200);
    let trt115 = trt(Baud::B115200);
    let lat = request_latency(args.seed, args.requests)?;
    for (id, label, value, limit, limit_is, target) in [
        ("latency_p50", "p50", lat.stats.p50, t115, "T", None),
        ("latency_p99", "p99", lat.stats.p99, t115, "T", Some(1.0)),
        ("latency_max", "max", lat.stats.max, t115, "T", None),
        ("latency_max_trt", "max", lat.stats.max, trt115, "Trt", None),
    ] {
        rows.push(Row {
            id,
            scenario: "2 request->wire",
            what: format!("115.2 kbit/s, {} requests, {label}", lat.stats.n),
            measured_us: value as f64,
            limit_us: limit as f64,
            limit_is,
            target,
        });
    }
    notes.push(format!(
        "2. latency mean {:.0} us, min {} us; at most {} frame(s) went out ahead of a request; \
         submit overshoot past the drawn arrival time: max {} us{}",
        lat.stats.mean,
        lat.stats.min,
        lat.max_frames_ahead,
        lat.max_overshoot,
        if lat.max_overshoot == 0 {
            " (exact)"
        } else {
            " (significant: latencies are measured from the actual submit time)"
        }
    ));

    // 3.
    let dead = dead_axis(config(Baud::B115200))?;
    let quiet = dead_axis(Config {
        // The first try happens at the first probe, in the warm-up; none in the window.
        rejoin_interval: Duration(u64::MAX),
        ..config(Baud::B115200)
    })?;
    for (id, label, value, limit, target) in [
        ("dead_mean", "mean", dead.stats.mean, alive.mean, Some(1.25)),
        (
            "dead_max",
            "max",
            dead.stats.max as f64,
            alive.max as f64,
            Some(1.25),
        ),
        (
            "dead_norejoin_mean",
            "mean, rejoin off",
            quiet.stats.mean,
            alive.mean,
            None,
        ),
        (
            "dead_norejoin_max",
            "max, rejoin off",
            quiet.stats.max as f64,
            alive.max as f64,
            None,
        ),
        (
            "dead_detection_max",
            "max while detecting",
            dead.transient.max as f64,
            alive.max as f64,
            None,
        ),
    ] {
        rows.push(Row {
            id,
            scenario: "3 one dead axis",
            what: format!("115.2 kbit/s, 15 live axes, {label}"),
            measured_us: value,
            limit_us: limit,
            limit_is: "all alive",
            target,
        });
    }
    let defaults = config(Baud::B115200);
    notes.push(format!(
        "3. axis {DEAD} silent: offline {:.1} ms after its first unanswered poll ((1 + {} retries) x (frame + Trt) = {:.1} ms); \
         in {} s: {} status probes and {} rejoin tries at 9.6 kbit/s/RTIM 255 ms (rejoin_interval {} ms), \
         the longest costing {:.1} ms of bus time; live-axis cycle p99 {:.1} ms (rejoin off: {} probes, p99 {:.1} ms); \
         15 x T = {:.1} ms",
        dead.detection as f64 / 1000.0,
        defaults.retries,
        (u64::from(defaults.retries) + 1) as f64
            * (timing::frame_time(Baud::B115200).as_micros() + trt115) as f64
            / 1000.0,
        dead.window / S,
        dead.probes,
        dead.rejoins,
        defaults.rejoin_interval.as_micros() / MS,
        dead.longest_try as f64 / 1000.0,
        dead.stats.p99 as f64 / 1000.0,
        quiet.probes,
        quiet.stats.p99 as f64 / 1000.0,
        (15 * t115) as f64 / 1000.0,
    ));

    // 4.
    let age = position_age()?;
    let status_limit = (u64::from(AXES) * t115) as f64;
    for (id, label, value) in [
        ("age_mean", "mean", age.stats.mean),
        ("age_p99", "p99", age.stats.p99 as f64),
        ("age_max", "max", age.stats.max as f64),
    ] {
        rows.push(Row {
            id,
            scenario: "4 position age",
            what: format!("115.2 kbit/s, 1 of 16 moving, {label}"),
            measured_us: value,
            limit_us: status_limit,
            limit_is: "16 x T",
            target: None,
        });
    }
    notes.push(format!(
        "4. axis {MOVER}: {} moves, {} samples (1/ms); first position read at most {} us after \
         a move started; idle axes' cycle while it moves: mean {:.0} us, max {} us \
         (17 x T = {} us: 16 polls + 1 R4)",
        age.moves,
        age.stats.n,
        age.first_read,
        age.cycle.mean,
        age.cycle.max,
        17 * t115
    ));

    let json = json!({
        "virtual_time": true,
        "seed": args.seed,
        "engine_size_bytes": engine_size,
        "setup": "16 simulated controllers from power-up (9.6 kbit/s, RTIM 255 ms); \
                  Config.establish = true to the rate under test, RTIM 3 ms",
        "rows": rows.iter().map(|r| json!({
            "id": r.id,
            "scenario": r.scenario,
            "what": r.what,
            "measured_us": round3(r.measured_us),
            "limit_us": round3(r.limit_us),
            "limit_is": r.limit_is,
            "ratio": round3(r.ratio()),
            "target_ratio": r.target,
            "pass": r.pass(),
        })).collect::<Vec<_>>(),
        "details": {
            "status_cycle": cycle_json,
            "request_latency": {
                "baud": 115_200,
                "transaction_us": t115,
                "trt_us": trt115,
                "latency": lat.stats.json(),
                "max_submit_overshoot_us": lat.max_overshoot,
                "max_frames_ahead": lat.max_frames_ahead,
            },
            "dead_axis": {
                "axis": DEAD,
                "window_us": dead.window,
                "cycle": dead.stats.json(),
                "during_detection": dead.transient.json(),
                "detection_us": dead.detection,
                "probes": dead.probes,
                "rejoin_tries": dead.rejoins,
                "longest_try_us": dead.longest_try,
                "rejoin_off": {
                    "cycle": quiet.stats.json(),
                    "probes": quiet.probes,
                    "rejoin_tries": quiet.rejoins,
                    "longest_try_us": quiet.longest_try,
                },
            },
            "position_age": {
                "axis": MOVER,
                "moves": age.moves,
                "age": age.stats.json(),
                "first_read_max_us": age.first_read,
                "cycle_while_moving": age.cycle.json(),
            },
        },
    });
    Ok(Report { rows, notes, json })
}

fn ms(us: f64) -> String {
    format!("{:.3} ms", us / 1000.0)
}

fn table(report: &Report, args: &Args) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Engine benchmark on the simulated bus (virtual time: identical every run; seed {:#x})",
        args.seed
    );
    let _ = writeln!(
        out,
        "Set-up: 16 controllers from power-up (9.6 kbit/s, RTIM 255 ms), Config.establish = true \
         to the rate under test, RTIM 3 ms; measured after a {} s warm-up.",
        WARM_UP / S
    );
    let _ = writeln!(
        out,
        "Engine RAM: size_of::<Engine>() = {} bytes\n",
        std::mem::size_of::<Engine>()
    );
    let header = [
        "scenario",
        "measurement",
        "measured",
        "limit",
        "limit is",
        "ratio",
        "target",
        "result",
    ];
    let cells: Vec<[String; 8]> = report
        .rows
        .iter()
        .map(|r| {
            [
                r.scenario.to_string(),
                r.what.clone(),
                ms(r.measured_us),
                ms(r.limit_us),
                r.limit_is.to_string(),
                format!("{:.3}", r.ratio()),
                r.target.map_or("-".into(), |t| format!("<= {t:.2}")),
                match r.pass() {
                    Some(true) => "PASS".into(),
                    Some(false) => "MISS".into(),
                    None => "info".into(),
                },
            ]
        })
        .collect();
    let mut width = header.map(str::len);
    for row in &cells {
        for (w, c) in width.iter_mut().zip(row) {
            *w = (*w).max(c.chars().count());
        }
    }
    let line = |cells: &[String]| {
        let mut s = String::new();
        for (i, (c, w)) in cells.iter().zip(width).enumerate() {
            // Text left, numbers right.
            if matches!(i, 2 | 3 | 5) {
                let _ = write!(s, "{c:>w$}  ");
            } else {
                let _ = write!(s, "{c:<w$}  ");
            }
        }
        s.trim_end().to_string()
    };
    let _ = writeln!(out, "{}", line(&header.map(String::from)));
    let _ = writeln!(
        out,
        "{}",
        width.map(|w| "-".repeat(w)).join("  ").trim_end()
    );
    for row in &cells {
        let _ = writeln!(out, "{}", line(row));
    }
    let _ = writeln!(
        out,
        "\nT = one transaction (command + RTIM + response + 1 ms host gap, timing::transaction_time); \
         Trt = response time-out (20 ms + RTIM + response)."
    );
    for note in &report.notes {
        let _ = writeln!(out, "{note}");
    }
    let (pass, miss) = report
        .rows
        .iter()
        .filter_map(Row::pass)
        .fold(
            (0, 0),
            |(p, m), ok| if ok { (p + 1, m) } else { (p, m + 1) },
        );
    let _ = writeln!(out, "\nTargets: {pass} PASS, {miss} MISS");
    out
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(&args) {
        Ok(report) => {
            if args.json {
                println!("{}", report.json);
            } else {
                print!("{}", table(&report, &args));
            }
            ExitCode::SUCCESS
        }
        Err(error) => {
            eprintln!("bench: {error}");
            ExitCode::FAILURE
        }
    }
}
