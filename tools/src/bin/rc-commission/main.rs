//! `rc-commission`: commission Robo Cylinder axes from a PC with a USB-RS485 adapter, instead of
//! IAI's Windows-only software. It drives the bus with the gateway's own bus master
//! (`protocol::engine`): the same time-outs, retries, establishment and jobs as the firmware.
//!
//! ```text
//! $ rc-commission --port /dev/ttyUSB0 scan
//! $ rc-commission --port /dev/ttyUSB0 --baud 9600 establish --to 115200
//! $ rc-commission --port /dev/ttyUSB0 --lead 6 --home motor move 0 --mm 25.5
//! $ rc-commission --port /dev/ttyUSB0 --lead 6 --home motor points write 0 --file table.csv --dry-run
//! $ rc-commission --port /dev/ttyUSB0 --lead 6 --home motor sniff
//! ```
//!
//! It works the same on a pseudo-terminal (`rc-sim --pty`), which is how it is tested. Exit
//! status 0 on success, 1 when the bus or an axis fails (the message says why), 2 for bad input.

mod line;
mod listen;
mod points;

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::{Parser, Subcommand, ValueEnum};
use protocol::engine::{Event, Job, JobKind, JobOutput, Link};
use protocol::line::Baud;
use protocol::memory::common;
use protocol::units::{Accel, Length, Speed};
use protocol::{Axis, AxisSet, PositionNo, Rtim};
use rc_tools::rcframe::units::{parse_axis, parse_point, ScaleArgs};

use crate::line::Line;

/// Commission IAI Robo Cylinder axes over RS485 from a PC (USB-RS485 adapter or pseudo-terminal).
#[derive(Parser, Debug)]
#[command(name = "rc-commission", version)]
struct Cli {
    /// The serial device: /dev/ttyUSB0, /dev/tty.usbserial-..., or a pseudo-terminal.
    #[arg(long, global = true, default_value = "/dev/ttyUSB0")]
    port: String,
    /// The bus rate the controllers run at now (factory setting: 9600).
    #[arg(long, global = true, default_value_t = 9600, value_parser = parse_baud)]
    baud: u32,
    /// The controllers' response delay RTIM, ms (factory setting: 255; sets the time-outs).
    #[arg(long, global = true, default_value_t = 255, value_parser = clap::value_parser!(u8).range(3..=255))]
    rtim: u8,
    #[command(flatten)]
    scale: ScaleArgs,
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Look for axes 0-15 at each rate (or at --rates), and show what answers.
    Scan {
        /// The rates to try, comma-separated (default: 9600,19200,38400,57600,115200).
        #[arg(long, value_delimiter = ',', value_parser = parse_baud)]
        rates: Vec<u32>,
    },
    /// The communication establishment (complete edition §6-1): a break, then every axis of
    /// --axes moved from its power-up settings to --to and RTIM 3 ms.
    Establish {
        /// The new rate.
        #[arg(long, value_parser = parse_baud)]
        to: u32,
        /// The axes, e.g. 0,1,2 (default: all 16).
        #[arg(long, value_delimiter = ',', value_parser = parse_axis)]
        axes: Vec<Axis>,
    },
    /// One axis' status: servo, homed, in position, alarm, position.
    Status {
        #[arg(value_parser = parse_axis)]
        axis: Axis,
    },
    /// Servo on or off.
    Servo {
        #[arg(value_parser = parse_axis)]
        axis: Axis,
        state: OnOff,
    },
    /// Home (toward --home's end), until the controller reports homing complete.
    Home {
        #[arg(value_parser = parse_axis)]
        axis: Axis,
    },
    /// Move to a position in mm (needs --lead and --home) or to a stored point.
    Move {
        #[arg(value_parser = parse_axis)]
        axis: Axis,
        /// Target position, mm.
        #[arg(long, conflicts_with = "point", allow_hyphen_values = true)]
        mm: Option<f64>,
        /// A stored point, 0-15.
        #[arg(long, value_parser = parse_point)]
        point: Option<PositionNo>,
        /// Speed, mm/s (with --mm; default: the controller's).
        #[arg(long, allow_negative_numbers = true)]
        speed: Option<f64>,
        /// Acceleration, G (with --speed).
        #[arg(long, default_value_t = 0.3, allow_negative_numbers = true)]
        accel: f64,
    },
    /// Jog: move by this many mm (negative toward home), as a relative move.
    Jog {
        #[arg(value_parser = parse_axis)]
        axis: Axis,
        /// Distance, mm.
        #[arg(allow_hyphen_values = true)]
        mm: f64,
    },
    /// Stop (cancel the remaining motion).
    Stop {
        #[arg(value_parser = parse_axis)]
        axis: Axis,
    },
    /// Reset an alarm (the servo goes off, as the controller requires).
    AlarmReset {
        #[arg(value_parser = parse_axis)]
        axis: Axis,
    },
    /// Read or write the point table (needs --lead and --home).
    Points {
        #[command(subcommand)]
        action: PointsCmd,
    },
    /// Listen without sending: decode every frame on the line (as `rcframe decode`), one JSON
    /// line each.
    Sniff {
        /// Stop after this many seconds (default: until interrupted).
        #[arg(long)]
        seconds: Option<f64>,
    },
}

#[derive(Subcommand, Debug)]
enum PointsCmd {
    /// Print the table (CSV), or write it to --file (TOML or CSV by its extension).
    Read {
        #[arg(value_parser = parse_axis)]
        axis: Axis,
        #[arg(long)]
        file: Option<PathBuf>,
    },
    /// Compare --file with the controller, print the differences and store the rows that differ
    /// (each compared again and verified; a row already stored is never rewritten).
    Write {
        #[arg(value_parser = parse_axis)]
        axis: Axis,
        #[arg(long)]
        file: PathBuf,
        /// Only print the differences.
        #[arg(long)]
        dry_run: bool,
        /// The axis' stroke, mm: positions beyond it are refused (as are positions beyond the
        /// soft limits the controller reports, and below 0).
        #[arg(long, value_name = "MM", allow_negative_numbers = true, value_parser = parse_stroke)]
        stroke: Option<Length>,
    },
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum OnOff {
    On,
    Off,
}

fn parse_baud(text: &str) -> Result<u32, String> {
    text.parse::<u32>()
        .ok()
        .and_then(Baud::from_bits_per_second)
        .map(Baud::bits_per_second)
        .ok_or_else(|| format!("{text:?}: a rate the controllers support (9600 ... 230400)"))
}

fn parse_stroke(text: &str) -> Result<Length, String> {
    let length = rc_tools::rcframe::units::parse_length(text)?;
    if length.0 <= 0 {
        return Err(format!("`{text}`: a stroke is a length, more than 0 mm"));
    }
    Ok(length)
}

fn baud(bps: u32) -> Result<Baud, String> {
    Baud::from_bits_per_second(bps).ok_or_else(|| format!("{bps}: unsupported rate"))
}

const JOB_LIMIT: Duration = Duration::from_secs(60);

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(&cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("rc-commission: {message}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: &Cli) -> Result<(), String> {
    let rtim = Rtim::new(cli.rtim).ok_or("RTIM 3-255")?;
    match &cli.command {
        Cmd::Scan { rates } => listen::scan(cli, rates, rtim),
        Cmd::Establish { to, axes } => establish(cli, *to, axes),
        Cmd::Sniff { seconds } => listen::sniff(cli, *seconds),
        Cmd::Status { axis } => {
            let mut line = connect(cli, *axis, rtim)?;
            status(&mut line, cli, *axis)
        }
        Cmd::Servo { axis, state } => {
            let on = matches!(state, OnOff::On);
            one_job(cli, *axis, rtim, JobKind::Servo(on))
        }
        Cmd::Home { axis } => {
            let home = cli
                .scale
                .home
                .ok_or("homing needs --home motor|non-motor")?;
            one_job(cli, *axis, rtim, JobKind::Home(home.into()))
        }
        Cmd::Move {
            axis,
            mm,
            point,
            speed,
            accel,
        } => {
            let kind = match (mm, point) {
                (_, Some(point)) => JobKind::MoveToPoint(*point, None),
                (Some(mm), None) => {
                    let scale = cli.scale.require_position()?;
                    let target = scale
                        .position_to_wire(Length(points_hundredths(*mm)?))
                        .map_err(|e| format!("{mm} mm: {e:?}"))?;
                    match speed {
                        None => JobKind::MoveAbsolute(target),
                        Some(speed) => JobKind::DirectMove {
                            target,
                            relative: false,
                            velocity: scale
                                .velocity(Speed(unsigned(*speed)?))
                                .map_err(|e| format!("{speed} mm/s: {e:?}"))?,
                            acceleration: scale
                                .acceleration(Accel(unsigned(*accel)?))
                                .map_err(|e| format!("{accel} G: {e:?}"))?,
                        },
                    }
                }
                (None, None) => return Err("move needs --mm or --point".into()),
            };
            one_job(cli, *axis, rtim, kind)
        }
        Cmd::Jog { axis, mm } => {
            let scale = cli.scale.require_position()?;
            let distance = scale
                .distance_to_wire(Length(points_hundredths(*mm)?))
                .map_err(|e| format!("{mm} mm: {e:?}"))?;
            one_job(cli, *axis, rtim, JobKind::MoveRelative(distance))
        }
        Cmd::Stop { axis } => one_job(cli, *axis, rtim, JobKind::Stop),
        Cmd::AlarmReset { axis } => one_job(cli, *axis, rtim, JobKind::AlarmReset),
        Cmd::Points { action } => match action {
            PointsCmd::Read { axis, file } => read_points(cli, *axis, rtim, file.as_deref()),
            PointsCmd::Write {
                axis,
                file,
                dry_run,
                stroke,
            } => write_points(cli, *axis, rtim, file, *dry_run, *stroke),
        },
    }
}

fn points_hundredths(mm: f64) -> Result<i32, String> {
    let h = (mm * 100.0).round();
    if h.is_finite() && h.abs() < 2e9 {
        Ok(h as i32)
    } else {
        Err(format!("{mm} mm: out of range"))
    }
}

fn unsigned(value: f64) -> Result<u32, String> {
    u32::try_from(i64::from(points_hundredths(value)?))
        .map_err(|_| format!("{value}: must be >= 0"))
}

/// A line to one axis at the given rate, once the axis has answered.
fn connect(cli: &Cli, axis: Axis, rtim: Rtim) -> Result<Line, String> {
    let rate = baud(cli.baud)?;
    let mut line = Line::open(&cli.port, rate, AxisSet::EMPTY.with(axis), rtim, false, 2)?;
    let limit = Duration::from_secs(5) + Duration::from_millis(3 * (300 + u64::from(cli.rtim)));
    line.run_until(limit, |l| l.settled(&[axis]))?;
    if line.engine.axis(axis).link != Link::Online {
        return Err(format!(
            "axis {}: no reply at {} bit/s (check the wiring, termination, the axis number and the baud rate; `scan` looks at every rate)",
            axis.get(),
            cli.baud
        ));
    }
    Ok(line)
}

fn one_job(cli: &Cli, axis: Axis, rtim: Rtim, kind: JobKind) -> Result<(), String> {
    let mut line = connect(cli, axis, rtim)?;
    let output = line.job(Job { axis, kind }, JOB_LIMIT)?;
    if let JobOutput::Status(report) = output {
        println!("axis {}: {}", axis.get(), report_text(&report));
    }
    status(&mut line, cli, axis)
}

fn report_text(report: &protocol::StatusReport) -> String {
    let alarm = if report.alarm.0 == 0 {
        "no alarm".to_string()
    } else {
        format!("alarm {:02X} {}", report.alarm.0, report.alarm.text())
    };
    format!(
        "servo {}, {}, {}, {alarm}",
        if report.status.servo() { "on" } else { "off" },
        if report.outputs.zfin() {
            "homed"
        } else {
            "not homed"
        },
        if report.outputs.pfin() {
            "in position"
        } else {
            "not in position"
        },
    )
}

fn status(line: &mut Line, cli: &Cli, axis: Axis) -> Result<(), String> {
    let report = line.job(
        Job {
            axis,
            kind: JobKind::Command(protocol::Command::Status),
        },
        JOB_LIMIT,
    )?;
    let JobOutput::Status(report) = report else {
        return Err(format!("axis {}: no status", axis.get()));
    };
    let pnow = line.job(
        Job {
            axis,
            kind: JobKind::Command(protocol::Command::ReadMemory {
                address: protocol::memory::PNOW,
            }),
        },
        JOB_LIMIT,
    )?;
    let position = match (pnow, cli.scale.position()) {
        (JobOutput::Value(v), Some(scale)) => {
            let mm = scale.position_from_wire(protocol::Pulses(v as i32));
            format!("{:.2} mm", f64::from(mm.0) / 100.0)
        }
        (JobOutput::Value(v), None) => format!(
            "{} pulses (raw {v:08X}; --lead and --home for mm)",
            v as i32
        ),
        _ => "unknown".into(),
    };
    println!(
        "axis {} at {} bit/s: {}, position {position}",
        axis.get(),
        line.baud().bits_per_second(),
        report_text(&report)
    );
    Ok(())
}

fn establish(cli: &Cli, to: u32, axes: &[Axis]) -> Result<(), String> {
    let axes: Vec<Axis> = if axes.is_empty() {
        (0..16).filter_map(Axis::new).collect()
    } else {
        axes.to_vec()
    };
    let set = axes.iter().fold(AxisSet::EMPTY, |s, &a| s.with(a));
    let mut line = Line::open(&cli.port, baud(to)?, set, Rtim::MIN, true, 2)?;
    let mut established = false;
    line.run_until(Duration::from_secs(10 + 2 * axes.len() as u64), |l| {
        established |= l.events().contains(&Event::Established);
        established && l.settled(&axes)
    })?;
    if !established {
        return Err("the establishment did not finish".into());
    }
    let mut failed = 0;
    for &axis in &axes {
        let online = line.engine.axis(axis).link == Link::Online;
        failed += usize::from(!online);
        println!(
            "axis {:>2}: {}",
            axis.get(),
            if online {
                format!("at {to} bit/s, RTIM 3 ms")
            } else {
                "no reply".into()
            }
        );
    }
    if failed == axes.len() {
        return Err(format!(
            "no axis answers at {to} bit/s after the establishment"
        ));
    }
    Ok(())
}

fn read_points(
    cli: &Cli,
    axis: Axis,
    rtim: Rtim,
    file: Option<&std::path::Path>,
) -> Result<(), String> {
    let scale = cli.scale.require_position()?;
    let mut line = connect(cli, axis, rtim)?;
    let mut rows = Vec::new();
    for n in 0..16u8 {
        let point = PositionNo::new(n).ok_or("point")?;
        if let JobOutput::Point(readback) = line.job(
            Job {
                axis,
                kind: JobKind::ReadPoint(point),
            },
            JOB_LIMIT,
        )? {
            rows.extend(points::Row::from_wire(n, &readback, &scale));
        }
    }
    let text = points::render(&rows, file)?;
    match file {
        Some(path) => {
            std::fs::write(path, text).map_err(|e| format!("{}: {e}", path.display()))?;
            println!(
                "axis {}: {} points written to {}",
                axis.get(),
                rows.len(),
                path.display()
            );
        }
        None => print!("{text}"),
    }
    Ok(())
}

/// The soft limits (LIML, LIMM) in effect: the execution area's copy of the common parameters.
fn soft_limits(
    line: &mut Line,
    axis: Axis,
) -> Result<(protocol::Pulses, protocol::Pulses), String> {
    let mut read = |address: protocol::Address| {
        let address = protocol::Address(protocol::memory::EXECUTION_OFFSET + address.0);
        match line.job(
            Job {
                axis,
                kind: JobKind::Command(protocol::Command::ReadMemory { address }),
            },
            JOB_LIMIT,
        )? {
            JobOutput::Value(v) => Ok(protocol::Pulses(v as i32)),
            _ => Err(format!("axis {}: no value", axis.get())),
        }
    };
    Ok((read(common::LIML)?, read(common::LIMM)?))
}

fn write_points(
    cli: &Cli,
    axis: Axis,
    rtim: Rtim,
    file: &std::path::Path,
    dry_run: bool,
    stroke: Option<Length>,
) -> Result<(), String> {
    let scale = cli.scale.require_position()?;
    let entries = points::read(file)?;
    let mut travel = points::Travel {
        stroke: stroke.map(|s| s.0),
        soft: None,
    };
    // What the file alone shows is reported even without a bus; with one, together with the
    // positions beyond the soft limits.
    let offline = points::check(&entries, file, &scale, &travel);
    let mut line = match connect(cli, axis, rtim) {
        Ok(line) => line,
        Err(e) => return offline.and(Err(e)),
    };
    match soft_limits(&mut line, axis) {
        Ok(soft) => {
            let (low, high) = points::soft_limits_mm(soft, &scale);
            println!("  axis {}: soft limits {low} to {high} mm", axis.get());
            travel.soft = Some(soft);
        }
        Err(e) if stroke.is_some() => {
            eprintln!("rc-commission: soft limits not read ({e}): positions checked against --stroke only");
        }
        Err(e) => {
            return Err(format!(
                "the soft limits LIMM/LIML, to check the positions against, not read ({e}); \
                 give the axis' stroke with --stroke MM"
            ))
        }
    }
    let stored = points::check(&entries, file, &scale, &travel)?;
    let mut changes = Vec::new();
    for (entry, &(point, data)) in entries.iter().zip(&stored) {
        let row = entry.row;
        let JobOutput::Point(current) = line.job(
            Job {
                axis,
                kind: JobKind::ReadPoint(point),
            },
            JOB_LIMIT,
        )?
        else {
            return Err(format!("point {}: no read-back", row.point));
        };
        if current.matches(&data) {
            println!("  point {:>2}: unchanged", row.point);
            continue;
        }
        let was = points::Row::from_wire(row.point, &current, &scale)
            .map_or("empty".to_string(), |r| r.describe());
        println!("~ point {:>2}: {was} -> {}", row.point, row.describe());
        changes.push((point, data));
    }
    if dry_run {
        println!(
            "dry run: {} of {} points would be stored",
            changes.len(),
            entries.len()
        );
        return Ok(());
    }
    for (point, data) in &changes {
        line.job(
            Job {
                axis,
                kind: JobKind::StorePoint {
                    point: *point,
                    data: *data,
                },
            },
            JOB_LIMIT,
        )?;
    }
    println!(
        "{} of {} points stored and verified",
        changes.len(),
        entries.len()
    );
    Ok(())
}
