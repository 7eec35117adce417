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
//! 5-6. Four moving axes (`movers`). 7. **Stop latency** through the whole gateway, per face
//!    (`stops`): source -> the axis' `d` on the wire, against issue 33's bound.
//!
//! ```text
//! cargo run --release -p rc-host --bin bench            # table
//! cargo run --release -p rc-host --bin bench -- --json  # one JSON object
//! ```
//!
//! [`Harness`]: rc_host::harness::Harness
//! [`timing::transaction_time`]: protocol::engine::timing::transaction_time

mod measure;
mod movers;
mod report;
mod scenarios;
mod stops;
mod table;

use std::process::ExitCode;

use clap::Parser;

use crate::report::run;
use crate::table::table;

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
    /// The firmware's CPU load measured on its ELF in QEMU (scripts/cpu-load.sh), percent, for
    /// the BENCH line (not measured here: the bench runs the engine on the host).
    #[arg(long)]
    cpu_load_percent: Option<f64>,
    /// That measurement's JSON object, kept in the BENCH line as it is.
    #[arg(long)]
    cpu_load_detail: Option<String>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(&args) {
        Ok(report) => {
            if args.json {
                println!("{}", report.json);
            } else {
                print!("{}", table(&report, &args));
                println!("BENCH {}", report.bench);
            }
            ExitCode::SUCCESS
        }
        Err(error) => {
            eprintln!("bench: {error}");
            ExitCode::FAILURE
        }
    }
}
