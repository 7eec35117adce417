//! `rt-bench`: the gateway on a PC (`rc-gateway-host`) against 16 simulated controllers
//! (`rc-sim`) over pseudo-terminals, in real time, driven by a Modbus RTU master as a PLC
//! program would drive it (`scripts/bench.sh`). What the virtual-time benchmark (`bench`)
//! cannot show: a transport without wire time (the simulator's `--no-wire-time`: a frame
//! arrives whole the moment it is written, as through a pseudo-terminal or a USB adapter, and
//! a controller answers RTIM after it), the gateway's real loop and the host's scheduling.
//!
//! Four movers (axes 0, 5, 10, 15) go back and forth over 40 mm (about 290 ms a move), their
//! starts 20 ms apart so that their ends come together, in rounds: the next round starts when
//! the PLC has read PEND of all four. Direct moves (0x9900) and moves to points (rows 1 and 2
//! written through the gateway, then POSR and CSTR), with the controllers answering at RTIM
//! 3 ms (the gateway's assumption) and at 7 ms (slower than it counts on). Then a few stops
//! (DRG1 STP) given mid-move.
//!
//! Measured from the simulator's event log against the mean transaction time T of the same
//! run: INBAND -> the first status reply showing PFIN, per mover, in T (target p99 <= 3 T);
//! each idle axis' time between status polls, in cycles of 16 T (target p99 <= 2); and the
//! time from the PLC's stop write to the `d` reaching the controller, in ms.
//!
//! ```text
//! rt-bench [--seconds 20] [--only direct_rtim3] [--json]
//! ```
//! Exit status 0 when every run was measured (whether the targets are met is in the output:
//! `BENCH_RT {...}`), 1 when a run could not be made, 2 on a wrong argument (an `--only` that
//! names no run measures nothing, so it is refused rather than reported as met).

mod analyse;
#[allow(dead_code)]
#[path = "../../../../tools/src/bin/rcgw/link.rs"]
mod link;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, Stdio};
use std::time::{Duration, Instant};

use analyse::{figures, percentiles, Figures};
use link::{Gw, Link};
use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;
use protocol::plc::{map, DEFAULT_GATEWAY_UNIT};
use rc_tools::sim::realtime::monotonic_us;
use serialport::Parity;

/// The movers: spread over the address range, as a machine's would be.
const MOVERS: [u8; 4] = [0, 5, 10, 15];
const AXES: u8 = 16;
/// The two ends of every move, 0.01 mm: 40 mm apart.
const NEAR: u32 = 1_000;
const FAR: u32 = 5_000;
/// 200 mm/s at 0.30 G: about 290 ms for 40 mm.
const SPEED: u32 = 20_000;
const ACCEL: u16 = 30;
const BAND: u32 = 10;
/// Between the movers' starts.
const STAGGER: Duration = Duration::from_millis(20);
/// Stops given after the window, each this long after a round's last start.
const STOPS: usize = 8;
const STOP_AFTER: Duration = Duration::from_millis(100);
/// DRG1 values (docs/plc.md): SON; SON + HOME; SON + CSTR; SON + STP.
const SON: u16 = 0x1000;
const SON_HOME: u16 = 0x1010;
const SON_CSTR: u16 = 0x1008;
const SON_STP: u16 = 0x1020;
/// DSS1 bits: PEND, HEND.
const PEND: u16 = 1 << 3;
const HEND: u16 = 1 << 4;

/// The target of each figure.
const COMPLETE_P99_T: f64 = 3.0;
const IDLE_P99_CYCLES: f64 = 2.0;

#[derive(Clone, Copy, PartialEq, Eq)]
enum Moves {
    Direct,
    Points,
}

#[derive(Clone, Copy)]
struct Case {
    moves: Moves,
    /// The controllers' RTIM, ms (the gateway counts on 3).
    rtim: u8,
}

const CASES: [Case; 4] = [
    Case {
        moves: Moves::Direct,
        rtim: 3,
    },
    Case {
        moves: Moves::Points,
        rtim: 3,
    },
    Case {
        moves: Moves::Direct,
        rtim: 7,
    },
    Case {
        moves: Moves::Points,
        rtim: 7,
    },
];

impl Case {
    fn name(&self) -> String {
        let moves = match self.moves {
            Moves::Direct => "direct",
            Moves::Points => "points",
        };
        format!("{moves}_rtim{}", self.rtim)
    }
}

/// A child process that is stopped (SIGINT, then waited for) when dropped.
struct Process(Child);

impl Drop for Process {
    fn drop(&mut self) {
        if let Ok(pid) = i32::try_from(self.0.id()) {
            let _ = kill(Pid::from_raw(pid), Signal::SIGINT);
        }
        let deadline = Instant::now() + Duration::from_secs(5);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Start `program` (beside this binary) and read the word after `prefix` on its first line.
fn spawn(
    program: &str,
    args: &[&str],
    log: &Path,
    prefix: &str,
) -> Result<(Process, String), String> {
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    let path = exe.with_file_name(program);
    let err = std::fs::File::create(log).map_err(|e| format!("{}: {e}", log.display()))?;
    let mut child = Command::new(&path)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(err)
        .spawn()
        .map_err(|e| {
            format!(
                "{}: {e} (build it: cargo build --release -p rc-tools)",
                path.display()
            )
        })?;
    let stdout = child.stdout.take().ok_or("no stdout")?;
    let process = Process(child);
    let mut line = String::new();
    BufReader::new(stdout)
        .read_line(&mut line)
        .map_err(|e| format!("{program}: {e}"))?;
    let word = line
        .strip_prefix(prefix)
        .map(|w| w.trim().to_string())
        .ok_or_else(|| format!("{program} said {line:?} (log {})", log.display()))?;
    Ok((process, word))
}

fn fail(e: link::Fail) -> String {
    e.to_string()
}

/// Read `address` of `axis` until `done` holds of it, for at most `limit`.
fn wait_for(
    gw: &mut Gw,
    axes: &[u8],
    address: u16,
    limit: Duration,
    done: impl Fn(u16) -> bool,
) -> Result<(), String> {
    let deadline = Instant::now() + limit;
    let mut left: Vec<u8> = axes.to_vec();
    while !left.is_empty() {
        if Instant::now() > deadline {
            return Err(format!(
                "axes {left:?}: register {address:#06x} not as expected after {limit:?}"
            ));
        }
        let mut still = Vec::new();
        for &a in &left {
            let unit = gw.axis_unit(a);
            let ok = matches!(gw.try_read(unit, address, 1).map_err(fail)?, Ok(v) if v.first().is_some_and(|&v| done(v)));
            if !ok {
                still.push(a);
            }
        }
        left = still;
    }
    Ok(())
}

fn hi(v: u32) -> u16 {
    (v >> 16) as u16
}
fn lo(v: u32) -> u16 {
    v as u16
}

/// The first six words of a direct move and of a position-table row alike: position, band and
/// speed to `to`, each 32 bits, high word first.
fn motion(to: u32) -> [u16; 6] {
    [hi(to), lo(to), hi(BAND), lo(BAND), hi(SPEED), lo(SPEED)]
}

/// Start axis `a`'s move to `far` or near.
fn start(gw: &mut Gw, moves: Moves, a: u8, far: bool) -> Result<(), String> {
    let unit = gw.axis_unit(a);
    match moves {
        Moves::Direct => {
            let to = if far { FAR } else { NEAR };
            let [p0, p1, b0, b1, s0, s1] = motion(to);
            let regs = [p0, p1, b0, b1, s0, s1, ACCEL];
            gw.write(unit, map::DIRECT, &regs).map_err(fail)
        }
        Moves::Points => {
            gw.write(unit, map::POSR, &[if far { 2 } else { 1 }])
                .map_err(fail)?;
            gw.write(unit, map::DRG1, &[SON_CSTR]).map_err(fail)?;
            gw.write(unit, map::DRG1, &[SON]).map_err(fail)
        }
    }
}

/// One round: every mover started, STAGGER apart, toward `far` or near; then `between` runs
/// (the stop phase gives a stop there); returns once PEND of every mover reads 1 (or after
/// `settle` when given, for rounds with a stop).
fn round(
    gw: &mut Gw,
    moves: Moves,
    far: bool,
    mut between: impl FnMut(&mut Gw) -> Result<(), String>,
    settle: Option<Duration>,
) -> Result<(), String> {
    let first = Instant::now();
    for (i, &a) in MOVERS.iter().enumerate() {
        let at = first + STAGGER * i as u32;
        while Instant::now() < at {
            std::thread::sleep(Duration::from_micros(500));
        }
        start(gw, moves, a, far)?;
    }
    between(gw)?;
    match settle {
        Some(d) => {
            std::thread::sleep(d);
            Ok(())
        }
        None => wait_for(gw, &MOVERS, map::DSS1, Duration::from_secs(5), |v| {
            v & PEND != 0
        }),
    }
}

/// One run of `case`: the processes, homing, the window's rounds, the stops; the figures.
fn run(case: Case, window: Duration, dir: &Path) -> Result<Figures, String> {
    let events = dir.join(format!("{}.events", case.name()));
    let events_arg = events.to_string_lossy().to_string();
    let rtim = case.rtim.to_string();
    let (_sim, bus) = spawn(
        "rc-sim",
        &[
            "--pty",
            "--axes",
            "16",
            "--baud",
            "115200",
            "--rtim",
            &rtim,
            "--fixed-baud",
            "--no-wire-time",
            "--events",
            &events_arg,
        ],
        &dir.join(format!("{}.sim.log", case.name())),
        "PTY ",
    )?;
    let (_gateway, plc) = spawn(
        "rc-gateway-host",
        &[
            "--plc-pty",
            "--bus",
            &bus,
            "--axes",
            "16",
            "--no-establish",
            "--watchdog-ms",
            "0",
            "--no-control",
        ],
        &dir.join(format!("{}.gateway.log", case.name())),
        "PLC ",
    )?;
    let link = Link::rtu(&plc, 115_200, Parity::None).map_err(fail)?;
    let mut gw = Gw {
        link,
        unit: DEFAULT_GATEWAY_UNIT,
        base: 1,
    };
    let all: Vec<u8> = (0..AXES).collect();
    wait_for(&mut gw, &all, map::LINK, Duration::from_secs(15), |v| {
        v == 1
    })?;
    let drg1 = map::DRG1;
    for &a in &MOVERS {
        let unit = gw.axis_unit(a);
        for value in [SON, SON_HOME, SON] {
            gw.write(unit, drg1, &[value]).map_err(fail)?;
        }
    }
    wait_for(&mut gw, &MOVERS, map::DSS1, Duration::from_secs(30), |v| {
        v & HEND != 0
    })?;
    if case.moves == Moves::Points {
        for &a in &MOVERS {
            let unit = gw.axis_unit(a);
            for (point, to) in [(1u16, NEAR), (2, FAR)] {
                let mut row = [0u16; 16];
                row[..6].copy_from_slice(&motion(to));
                row[10] = ACCEL;
                row[11] = ACCEL;
                let address = protocol::plc::table::BASE + protocol::plc::table::ROW_LEN * point;
                gw.write(unit, address, &row).map_err(fail)?;
                gw.read_wait(unit, address, 16, Duration::from_secs(3))
                    .map_err(fail)?;
            }
        }
    }
    // A first round to the near end, outside the window.
    round(&mut gw, case.moves, false, |_| Ok(()), None)?;
    let from = monotonic_us();
    let started = Instant::now();
    let mut far = true;
    while started.elapsed() < window {
        round(&mut gw, case.moves, far, |_| Ok(()), None)?;
        far = !far;
    }
    let to = monotonic_us();
    let mut stops = Vec::new();
    for k in 0..STOPS {
        let a = MOVERS[k % MOVERS.len()];
        round(
            &mut gw,
            case.moves,
            far,
            |gw| {
                std::thread::sleep(STOP_AFTER);
                let unit = gw.axis_unit(a);
                stops.push((monotonic_us(), a));
                gw.write(unit, drg1, &[SON_STP]).map_err(fail)?;
                std::thread::sleep(Duration::from_millis(50));
                gw.write(unit, drg1, &[SON]).map_err(fail)
            },
            Some(Duration::from_millis(600)),
        )?;
        far = !far;
    }
    drop(gw);
    drop(_gateway);
    drop(_sim);
    let text =
        std::fs::read_to_string(&events).map_err(|e| format!("{}: {e}", events.display()))?;
    figures(&text, (from, to), &MOVERS, AXES, &stops)
}

fn json_run(case: Case, f: &Figures) -> serde_json::Value {
    let per_axis: Vec<serde_json::Value> = f
        .complete
        .iter()
        .map(|(a, v)| {
            let [p50, p99, max] = percentiles(v);
            serde_json::json!({"axis": a, "moves": v.len(), "p50_t": p50, "p99_t": p99, "max_t": max})
        })
        .collect();
    let [_, idle_p99, idle_max] = percentiles(&f.idle_all());
    let [stop_p50, _, stop_max] = percentiles(&f.stops_us);
    let [status, reads, commands, idle_share] = f.mix.per_move();
    serde_json::json!({
        "run": case.name(),
        "transaction_ms": f.transaction_us / 1e3,
        "complete_per_axis": per_axis,
        "complete_worst_p99_t": f.worst_mover_p99(),
        "idle_age_p99_cycles": idle_p99,
        "idle_age_max_cycles": idle_max,
        "stop_p50_ms": stop_p50 / 1e3,
        "stop_max_ms": stop_max / 1e3,
        "stops_lost": f.stops_lost,
        "per_move": {
            "status_polls": status,
            "position_reads": reads,
            "other_commands": commands,
        },
        "idle_status_share": idle_share,
    })
}

fn main() -> ExitCode {
    let mut seconds = 20u64;
    let mut json = false;
    let mut only: Option<String> = None;
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--seconds" => match args.next().and_then(|s| s.parse().ok()) {
                Some(s) => seconds = s,
                None => {
                    eprintln!("rt-bench: --seconds needs a number");
                    return ExitCode::from(2);
                }
            },
            "--json" => json = true,
            "--only" => only = args.next(),
            _ => {
                eprintln!("usage: rt-bench [--seconds N] [--only RUN] [--json]");
                return ExitCode::from(2);
            }
        }
    }
    let dir = PathBuf::from(std::env::var("CARGO_TARGET_DIR").unwrap_or_else(|_| "target".into()))
        .join("rt-bench");
    if let Err(e) = std::fs::create_dir_all(&dir) {
        eprintln!("rt-bench: {}: {e}", dir.display());
        return ExitCode::FAILURE;
    }
    if let Some(o) = only
        .as_ref()
        .filter(|o| !CASES.iter().any(|c| c.name() == **o))
    {
        let names: Vec<String> = CASES.iter().map(Case::name).collect();
        eprintln!("rt-bench: no run {o} (runs: {})", names.join(", "));
        return ExitCode::from(2);
    }
    let mut runs = Vec::new();
    let (mut worst_complete, mut worst_idle): (f64, f64) = (0.0, 0.0);
    let mut lost = 0;
    for case in CASES {
        if only.as_ref().is_some_and(|o| *o != case.name()) {
            continue;
        }
        match run(case, Duration::from_secs(seconds), &dir) {
            Ok(f) => {
                if !json {
                    print!("{}", f.table(&case.name()));
                }
                worst_complete = worst_complete.max(f.worst_mover_p99());
                worst_idle = worst_idle.max(percentiles(&f.idle_all())[1]);
                lost += f.stops_lost;
                runs.push(json_run(case, &f));
            }
            Err(e) => {
                eprintln!("rt-bench: {}: {e} (logs in {})", case.name(), dir.display());
                return ExitCode::FAILURE;
            }
        }
    }
    let summary = serde_json::json!({
        "complete_worst_p99_t": worst_complete,
        "complete_target_p99_t": COMPLETE_P99_T,
        "complete_met": worst_complete <= COMPLETE_P99_T,
        "idle_age_worst_p99_cycles": worst_idle,
        "idle_age_target_p99_cycles": IDLE_P99_CYCLES,
        "idle_met": worst_idle <= IDLE_P99_CYCLES,
        "stops_lost": lost,
        "runs": runs,
    });
    println!("BENCH_RT {summary}");
    ExitCode::SUCCESS
}
