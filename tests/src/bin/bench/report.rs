//! The report: every scenario run, its rows against their limits, notes and the JSON object.

use protocol::engine::{timing, Config, Engine};
use protocol::line::Baud;
use protocol::time::Duration;
use serde_json::{json, Value};

use crate::measure::{config, round3, transaction, trt, Row};
use crate::movers::{movers, Ends, Moves, FASTER, MOVERS, SLOWER, TRAVEL_PERCENT};
use crate::scenarios::{dead_axis, position_age, request_latency, status_cycle};
use crate::stops::{stop_latency, Face};
use crate::{Args, AXES, DEAD, MOVER, MS, S, WINDOW};

pub(crate) struct Report {
    pub(crate) rows: Vec<Row>,
    pub(crate) notes: Vec<String>,
    pub(crate) json: Value,
    /// The headline figures against the adaptive-polling targets: `scripts/bench.sh`'s `BENCH`
    /// line.
    pub(crate) bench: Value,
}

/// The adaptive-polling targets (16 axes, 115.2 kbit/s, RTIM 3 ms): each figure's ratio.
const CYCLE_TARGET: f64 = 1.02;
const MOVE_COMPLETE_TARGET: f64 = 3.0;
const IDLE_AGE_TARGET: f64 = 2.0;
const DEAD_AXIS_TARGET: f64 = 1.5;
/// Issue 33's stop latency target: each stop within its bound (its face's delay, the transaction
/// on the wire, one transaction per stop ahead of it).
const STOP_TARGET: f64 = 1.0;
/// Stops per face in scenario 7.
const STOP_ROUNDS: u32 = 100;
/// The MCU's CPU load target, percent.
const CPU_LOAD_TARGET: f64 = 5.0;

pub(crate) fn run(args: &Args) -> Result<Report, String> {
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
            (ids[0], "mean", r.stats.mean, Some(CYCLE_TARGET)),
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

    // 5.
    let moving = movers(false, Ends::Staggered, Moves::Absolute)?;
    let together = movers(false, Ends::Together, Moves::Absolute)?;
    let with_dead = movers(true, Ends::Staggered, Moves::Absolute)?;
    let cycle_limit = (u64::from(AXES) * t115) as f64;
    let rows5 = [
        (
            "move_complete_p99",
            "move complete -> gateway, p99",
            moving.complete.p99 as f64,
            t115 as f64,
            "T",
            Some(MOVE_COMPLETE_TARGET),
        ),
        (
            "move_complete_together_p99",
            "move complete -> gateway, p99, four ending together",
            together.complete.p99 as f64,
            t115 as f64,
            "T",
            None,
        ),
        (
            "idle_age_p99",
            "idle axes' status age, p99",
            moving.idle_age.p99 as f64,
            cycle_limit,
            "16 x T",
            Some(IDLE_AGE_TARGET),
        ),
        (
            "dead_moving_max",
            "one dead axis: live axes' max status gap",
            with_dead.live_max as f64,
            moving.live_max as f64,
            "same, no dead",
            Some(DEAD_AXIS_TARGET),
        ),
    ];
    for (id, what, measured, limit, limit_is, target) in rows5 {
        rows.push(Row {
            id,
            scenario: "5 four moving",
            what: format!("115.2 kbit/s, 16 axes, {what}"),
            measured_us: measured,
            limit_us: limit,
            limit_is,
            target,
        });
    }
    notes.push(format!(
        "5. axes {MOVERS:?} move back and forth over {TRAVEL_PERCENT:?} % of the stroke for {} s: \
         {} moves seen complete (controller in its band -> a status report with PFIN in the \
         gateway: mean {:.0} us, max {} us; all four over 90 %, ending together: {} moves, mean \
         {:.0} us, p99 {} us); idle axes' status age max {} us; all live axes' longest status \
         gap {} us, {} us with axis {DEAD} dead ({} moves)",
        WINDOW / S,
        moving.moves,
        moving.complete.mean,
        moving.complete.max,
        together.moves,
        together.complete.mean,
        together.complete.p99,
        moving.idle_age.max,
        moving.live_max,
        with_dead.live_max,
        with_dead.moves,
    ));
    // 6.
    let mut paced = Vec::new();
    for (name, moves) in [("faster", FASTER), ("slower", SLOWER)] {
        let Moves::Points { assumed, real } = moves else {
            continue;
        };
        let result = movers(false, Ends::Staggered, moves)?;
        let measured = result.transaction;
        let nominal = timing::transaction_time(
            Baud::B115200,
            protocol::Rtim::new(assumed).ok_or("RTIM out of range")?,
        )
        .as_micros();
        let pace = format!("answers {real} ms after where {assumed} counted on");
        for (id, what, value, limit, limit_is, target) in [
            (
                if name == "faster" {
                    "point_complete_p99_faster"
                } else {
                    "point_complete_p99_slower"
                },
                "move to a point complete -> gateway, p99",
                result.complete.p99 as f64,
                measured,
                "measured T",
                MOVE_COMPLETE_TARGET,
            ),
            (
                if name == "faster" {
                    "point_idle_age_p99_faster"
                } else {
                    "point_idle_age_p99_slower"
                },
                "idle axes' status age, p99",
                result.idle_age.p99 as f64,
                f64::from(AXES) * measured,
                "16 x meas. T",
                IDLE_AGE_TARGET,
            ),
        ] {
            rows.push(Row {
                id,
                scenario: "6 four to points",
                what: format!("115.2 kbit/s, {pace}, {what}"),
                measured_us: value,
                limit_us: limit,
                limit_is,
                target: Some(target),
            });
        }
        notes.push(format!(
            "6. {name}: the controllers answer {real} ms after a command where the gateway counts on RTIM {assumed} ms: a transaction took {measured:.0} us, {:.2} of the nominal {nominal} us; {} moves to points 1 and 2 seen complete (mean {:.0} us, max {} us); idle axes' status age max {} us",
            measured / nominal as f64,
            result.moves,
            result.complete.mean,
            result.complete.max,
            result.idle_age.max,
        ));
        paced.push((name, result));
    }

    // 7.
    let mut stops = Vec::new();
    for face in Face::ALL {
        let r = stop_latency(face, args.seed, STOP_ROUNDS)?;
        for (suffix, label, value) in [
            ("p50", "p50", r.latency.p50),
            ("p99", "p99", r.latency.p99),
            ("max", "max", r.latency.max),
        ] {
            rows.push(Row {
                id: leak(format!("stop_{}_{suffix}", face.id())),
                scenario: "7 stop -> wire",
                what: format!("{}, 16 axes, 4 moving, {label}", face.id()),
                measured_us: value as f64,
                limit_us: t115 as f64,
                limit_is: "T",
                target: None,
            });
        }
        rows.push(Row {
            id: leak(format!("stop_{}_max_ratio", face.id())),
            scenario: "7 stop -> wire",
            what: format!(
                "{}, worst sample over its bound (delay + (1 + stops ahead) x T)",
                face.id()
            ),
            measured_us: r.ratio_milli.max as f64,
            limit_us: 1000.0,
            limit_is: "bound",
            target: Some(STOP_TARGET),
        });
        notes.push(format!(
            "7. {}: {} stops over {STOP_ROUNDS} rounds, latency mean {:.0} us, p50 {} us, p99 {} us, max {} us; at most {} stops went out ahead of one; worst sample {:.3} of its bound",
            face.id(),
            r.latency.n,
            r.latency.mean,
            r.latency.p50,
            r.latency.p99,
            r.latency.max,
            r.max_ahead,
            r.ratio_milli.max as f64 / 1000.0,
        ));
        stops.push(r);
    }
    let stop_json: Vec<Value> = stops
        .iter()
        .map(|r| {
            json!({
                "face": r.face.id(),
                "latency": r.latency.json(),
                "ratio_to_bound_milli": r.ratio_milli.json(),
                "max_stops_ahead": r.max_ahead,
            })
        })
        .collect();

    let cycle_ratio = alive.mean / cycle_limit;
    let mut figures = vec![
        ("cycle_ratio", cycle_ratio, CYCLE_TARGET),
        (
            "move_complete_p99_transactions",
            moving.complete.p99 as f64 / t115 as f64,
            MOVE_COMPLETE_TARGET,
        ),
        (
            "idle_status_age_p99_ratio",
            moving.idle_age.p99 as f64 / cycle_limit,
            IDLE_AGE_TARGET,
        ),
        (
            "dead_axis_max_ratio",
            with_dead.live_max as f64 / moving.live_max as f64,
            DEAD_AXIS_TARGET,
        ),
    ];
    // Scenario 6, against the transaction time measured in its run: the worse of its two paces.
    let worst = |f: fn(&crate::movers::MoversResult) -> f64| {
        paced.iter().map(|(_, r)| f(r)).fold(0.0, f64::max)
    };
    figures.push((
        "point_move_complete_p99_measured_transactions",
        worst(|r| r.complete.p99 as f64 / r.transaction),
        MOVE_COMPLETE_TARGET,
    ));
    figures.push((
        "point_idle_status_age_p99_measured_ratio",
        worst(|r| r.idle_age.p99 as f64 / (f64::from(AXES) * r.transaction)),
        IDLE_AGE_TARGET,
    ));
    figures.push((
        "stop_latency_max_ratio_to_bound",
        stops
            .iter()
            .map(|r| r.ratio_milli.max as f64 / 1000.0)
            .fold(0.0, f64::max),
        STOP_TARGET,
    ));
    let mut bench = serde_json::Map::new();
    let mut targets = serde_json::Map::new();
    let mut met = serde_json::Map::new();
    for (key, value, target) in figures {
        bench.insert(key.into(), json!(round3(value)));
        targets.insert(key.into(), json!(target));
        met.insert(key.into(), json!(value <= target));
    }
    match args.cpu_load_percent {
        Some(percent) => {
            bench.insert("cpu_load_percent".into(), json!(percent));
            let detail = args
                .cpu_load_detail
                .as_deref()
                .and_then(|text| serde_json::from_str::<Value>(text).ok())
                .unwrap_or(Value::Null);
            bench.insert("cpu_load".into(), detail);
        }
        None => {
            bench.insert("cpu_load_percent".into(), Value::Null);
            bench.insert(
                "cpu_load_note".into(),
                json!("not measured in this run: scripts/cpu-load.sh measures it on the firmware ELF in QEMU"),
            );
        }
    }
    targets.insert("cpu_load_percent".into(), json!(CPU_LOAD_TARGET));
    met.insert(
        "cpu_load_percent".into(),
        args.cpu_load_percent
            .map_or(Value::Null, |p| json!(p <= CPU_LOAD_TARGET)),
    );
    bench.insert("targets".into(), Value::Object(targets));
    bench.insert("met".into(), Value::Object(met));
    let bench = Value::Object(bench);

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
            "four_moving": {
                "axes": MOVERS,
                "moves": moving.moves,
                "travel_percent": TRAVEL_PERCENT,
                "move_complete": moving.complete.json(),
                "ending_together": {
                    "moves": together.moves,
                    "move_complete": together.complete.json(),
                },
                "idle_status_age": moving.idle_age.json(),
                "live_max_gap_us": moving.live_max,
                "with_dead_axis": {
                    "axis": DEAD,
                    "moves": with_dead.moves,
                    "live_max_gap_us": with_dead.live_max,
                },
            },
            "stop_latency": stop_json,
            "position_age": {
                "axis": MOVER,
                "moves": age.moves,
                "age": age.stats.json(),
                "first_read_max_us": age.first_read,
                "cycle_while_moving": age.cycle.json(),
            },
        },
    });
    Ok(Report {
        rows,
        notes,
        json,
        bench,
    })
}

/// A row id made at run time (the table's ids are `&'static str`; a bench run makes a few).
fn leak(id: String) -> &'static str {
    Box::leak(id.into_boxed_str())
}
