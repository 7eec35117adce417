//! `rc-sim`: simulated Robo Cylinder controllers in real time, behind a pseudo-terminal or a
//! loopback TCP socket, for a real bus master (the host-side gateway, the firmware under QEMU).
//!
//! ```text
//! $ rc-sim --pty --axes 2 --baud 115200 --rtim 3 --log
//! PTY /dev/pts/4
//! $ rc-sim --tcp 127.0.0.1:5485 --axes 0,1,5 --corrupt 0.01 --reconnect
//! TCP 127.0.0.1:5485
//! ```
//!
//! The first line on standard output says where to connect; `--log` prints every frame,
//! decoded, on standard error; a summary of the counters follows on standard error when the run
//! ends (SIGINT/SIGTERM, `--duration`, or the TCP client leaving). Exit status 0 after a clean
//! end, 1 on an I/O error, 2 on bad command-line input.
//!
//! `--control` takes faults on standard input while it runs, one a line, each answered `OK` or
//! `ERR why`: `silent 2 on|off` (axis 2 executes commands but never answers), `cut 2 on|off`
//! (the wire to axis 2 cut: it hears nothing and answers nothing, a move it makes goes on;
//! what the master sends it meanwhile is lost), `alarm 2 E0`, `power 2 500`, `where 2` (see
//! `rc_tools::sim::realtime::Control`). The log (`--log`) notes each as it is applied, e.g.
//! `-- control: Cut(Axis(2), false)`: the frames logged after that note are the ones the axis
//! hears.
//!
//! See `rc_tools::sim::realtime` for the clock mapping and the line-rate and break decisions,
//! summarised in `--help`.

use std::io::Write;
use std::net::SocketAddr;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use clap::{ArgGroup, Parser};
use nix::sys::signal::{self, SigHandler, Signal};
use protocol::line::Baud;
use protocol::{Axis, Rtim};
use rc_tools::sim::realtime::{
    bus_at_line, Control, Ended, Options, Pty, RealTime, TcpServer, Transport,
};
use rc_tools::sim::{BusConfig, Faults};

const ABOUT: &str = "\
Simulated IAI Robo Cylinder controllers on an RS485 bus, in real time, for a real bus master.

TRANSPORTS
  --pty        a pseudo-terminal: the first line on stdout is `PTY /dev/pts/N`, the master opens
               that path as its serial port (and may close and reopen it); runs until SIGINT,
               SIGTERM or --duration.
  --tcp ADDR   a loopback TCP socket (127.0.0.0/8 or ::1 only; port 0 picks one): the first
               line is `TCP 127.0.0.1:PORT`; raw bytes both ways, one client at a time; the run
               ends when the client disconnects, or with --reconnect the next client is served
               by the same bus.

LINE RATE AND BREAKS
  Controllers power up at --baud and --rtim (stored in their non-volatile memory) and so does
  the host side of the line: a master configured NOT to run the establishment procedure (§6-1,
  break + communication change) talks to them at once. Neither transport can carry a break
  (a Linux pseudo-terminal ignores tcsendbreak; raw TCP has no out-of-band signal), so a break
  from the master is never seen. On a pseudo-terminal the master's termios speed is followed
  when it changes (9600, 19200, 38400, 57600 or 115200 bit/s; --fixed-baud turns that off), and
  --slow-baud-is-break treats a switch to 9600 bit/s followed by 100 ms of silence as a break,
  which makes a master that does run the establishment procedure work (it switches to 9600
  bit/s right before its 200 ms break); a switch with a frame right after it (such as a probe
  of an offline axis at the power-up settings) is a plain rate change.

TIMING
  The simulator keeps exact wire timing internally (byte times, RTIM, collisions); the host's
  scheduling adds only delivery jitter (when received bytes reach the master), usually well
  under a millisecond.";

/// Simulated Robo Cylinder controllers in real time, behind a PTY or a loopback TCP socket.
#[derive(Parser, Debug)]
#[command(name = "rc-sim", version, long_about = ABOUT)]
#[command(group(ArgGroup::new("transport").required(true).args(["pty", "tcp"])))]
struct Cli {
    /// Serve the bus on a new pseudo-terminal.
    #[arg(long)]
    pty: bool,
    /// Serve the bus on a loopback TCP address, e.g. 127.0.0.1:5485.
    #[arg(long, value_name = "ADDR", value_parser = parse_loopback)]
    tcp: Option<SocketAddr>,
    /// TCP: after a disconnection, wait for the next client instead of exiting.
    #[arg(long)]
    reconnect: bool,
    /// The axes: a count (16 means 0-15), or a list of axes and ranges ("0,1,5", "2-4", "7,").
    #[arg(long, default_value = "1", value_parser = parse_axes)]
    axes: AxisList,
    /// The line rate of the controllers and the host at the start, bit/s.
    #[arg(long, default_value_t = 115_200, value_parser = parse_baud)]
    baud: u32,
    /// The controllers' RTIM at the start, ms (3-255).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u8).range(3..=255))]
    rtim: u8,
    /// Do not follow the pseudo-terminal's termios speed.
    #[arg(long)]
    fixed_baud: bool,
    /// Pseudo-terminal: a switch of the master's speed to 9600 bit/s, then 100 ms of silence, is
    /// a break.
    #[arg(long)]
    slow_baud_is_break: bool,
    /// The transceiver's receiver is always on: the master hears its own bytes.
    #[arg(long)]
    echo: bool,
    /// Seed of the random faults.
    #[arg(long, default_value_t = 0x5EED)]
    seed: u64,
    /// Probability that a byte is corrupted, both directions.
    #[arg(long, value_name = "P", value_parser = parse_probability)]
    corrupt: Option<f64>,
    /// Probability that a byte from the master is corrupted (overrides --corrupt).
    #[arg(long, value_name = "P", value_parser = parse_probability)]
    corrupt_host: Option<f64>,
    /// Probability that a byte from a controller is corrupted (overrides --corrupt).
    #[arg(long, value_name = "P", value_parser = parse_probability)]
    corrupt_reply: Option<f64>,
    /// Probability that a reply is dropped (never sent).
    #[arg(long, value_name = "P", value_parser = parse_probability, default_value_t = 0.0)]
    drop: f64,
    /// Probability that a reply is sent --delay-ms late.
    #[arg(long, value_name = "P", value_parser = parse_probability, default_value_t = 0.0)]
    delay: f64,
    /// How late a delayed reply is, ms.
    #[arg(long, value_name = "MS", default_value_t = 50)]
    delay_ms: u64,
    /// Probability of a burst of noise after each frame.
    #[arg(long, value_name = "P", value_parser = parse_probability, default_value_t = 0.0)]
    noise: f64,
    /// Noise bytes per burst, at most.
    #[arg(long, value_name = "N", default_value_t = 3)]
    noise_max: u8,
    /// Read faults to inject from standard input, one per line: `silent AXIS on|off` (it
    /// executes commands but never answers), `cut AXIS on|off` (its wire cut: it hears nothing,
    /// answers nothing, and a move in progress goes on), `alarm AXIS CODE` (hex, 80-FF),
    /// `power AXIS MS`, `where AXIS` (the log notes the axis' position); each is answered `OK`
    /// or `ERR why` on standard output.
    #[arg(long)]
    control: bool,
    /// Exit after this many seconds.
    #[arg(long, value_name = "SECS", value_parser = parse_seconds)]
    duration: Option<Duration>,
    /// Print every frame, decoded, with its time (s since the start) on standard error.
    #[arg(long)]
    log: bool,
    /// Write the event log to FILE: every command, reply and move start with its time in µs of
    /// CLOCK_MONOTONIC (`rc_tools::sim::realtime` events), for benchmarks.
    #[arg(long, value_name = "FILE")]
    events: Option<std::path::PathBuf>,
    /// Bytes take no time on the wire: a frame reaches the controllers (and a reply the master)
    /// whole, the moment it is sent, as through a pseudo-terminal or a USB adapter; the
    /// controllers still answer RTIM after a command.
    #[arg(long)]
    no_wire_time: bool,
}

#[derive(Clone, Debug)]
struct AxisList(Vec<Axis>);

fn parse_axes(text: &str) -> Result<AxisList, String> {
    let text = text.trim();
    if !text.contains([',', '-']) {
        let count: u8 = text
            .parse()
            .map_err(|_| format!("{text:?}: not a count of axes"))?;
        if !(1..=16).contains(&count) {
            return Err(format!("{count}: 1 to 16 axes"));
        }
        return Ok(AxisList((0..count).filter_map(Axis::new).collect()));
    }
    let mut axes = Vec::new();
    for part in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (first, last) = part.split_once('-').unwrap_or((part, part));
        let number = |s: &str| {
            s.trim()
                .parse::<u8>()
                .ok()
                .and_then(Axis::new)
                .ok_or_else(|| format!("{s:?}: an axis is 0-15"))
        };
        let (first, last) = (number(first)?, number(last)?);
        if first > last {
            return Err(format!("{part:?}: empty range"));
        }
        axes.extend((first.get()..=last.get()).filter_map(Axis::new));
    }
    axes.sort();
    axes.dedup();
    if axes.is_empty() {
        return Err("no axis".into());
    }
    Ok(AxisList(axes))
}

fn parse_baud(text: &str) -> Result<u32, String> {
    let bps: u32 = text.parse().map_err(|_| format!("{text:?}: not a rate"))?;
    Baud::from_bits_per_second(bps)
        .map(Baud::bits_per_second)
        .ok_or_else(|| {
            let rates: Vec<String> = Baud::ALL
                .iter()
                .map(|b| b.bits_per_second().to_string())
                .collect();
            format!("{bps}: the controllers support {}", rates.join(", "))
        })
}

fn parse_probability(text: &str) -> Result<f64, String> {
    let p: f64 = text
        .parse()
        .map_err(|_| format!("{text:?}: not a number"))?;
    if (0.0..=1.0).contains(&p) {
        Ok(p)
    } else {
        Err(format!("{p}: a probability is 0 to 1"))
    }
}

fn parse_loopback(text: &str) -> Result<SocketAddr, String> {
    let addr: SocketAddr = text
        .parse()
        .map_err(|_| format!("{text:?}: not an address such as 127.0.0.1:5485"))?;
    if addr.ip().is_loopback() {
        Ok(addr)
    } else {
        Err(format!(
            "{addr}: loopback addresses only (127.0.0.0/8, ::1)"
        ))
    }
}

fn parse_seconds(text: &str) -> Result<Duration, String> {
    text.parse::<f64>()
        .ok()
        .and_then(|secs| Duration::try_from_secs_f64(secs).ok())
        .ok_or_else(|| format!("{text:?}: not a number of seconds"))
}

/// `--control`: one line of standard input at a time, answered on standard output, until the
/// input ends or the simulation does.
fn read_controls(axes: &[Axis], sender: &std::sync::mpsc::Sender<Control>) {
    for line in std::io::stdin().lines() {
        let Ok(line) = line else { return };
        let answer = match Control::parse(&line) {
            Ok(control) => {
                if !axes.contains(&control.axis()) {
                    format!("ERR axis {} is not on the bus", control.axis().get())
                } else if sender.send(control).is_err() {
                    return;
                } else {
                    "OK".to_string()
                }
            }
            Err(why) => format!("ERR {why}"),
        };
        let mut out = std::io::stdout().lock();
        if writeln!(out, "{answer}")
            .and_then(|()| out.flush())
            .is_err()
        {
            return;
        }
    }
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: nix::libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(&cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("rc-sim: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: &Cli) -> std::io::Result<()> {
    let baud = Baud::from_bits_per_second(cli.baud)
        .ok_or_else(|| std::io::Error::other("unsupported rate"))?;
    let rtim = Rtim::new(cli.rtim).ok_or_else(|| std::io::Error::other("RTIM out of range"))?;
    let corrupt = cli.corrupt.unwrap_or(0.0);
    let faults = Faults {
        host_byte_corruption: cli.corrupt_host.unwrap_or(corrupt),
        reply_byte_corruption: cli.corrupt_reply.unwrap_or(corrupt),
        reply_drop: cli.drop,
        reply_delay: cli.delay,
        reply_delay_us: cli.delay_ms.saturating_mul(1_000),
        noise: cli.noise,
        noise_max_bytes: cli.noise_max,
    };
    let config = BusConfig {
        seed: cli.seed,
        faults,
        host_echo: cli.echo,
        host_baud: baud,
        wire_time: !cli.no_wire_time,
    };
    let options = Options {
        follow_baud: !cli.fixed_baud,
        slow_baud_is_break: cli.slow_baud_is_break,
        reconnect: cli.reconnect,
        duration: cli.duration,
        log: cli.log,
        ..Options::default()
    };

    let mut transport = match cli.tcp {
        Some(addr) => {
            let server = TcpServer::bind(addr)?;
            println!("TCP {}", server.local_addr()?);
            Transport::Tcp(server)
        }
        None => {
            let pty = Pty::open(baud)?;
            println!("PTY {}", pty.path().display());
            Transport::Pty(pty)
        }
    };
    std::io::stdout().flush()?;

    for sig in [Signal::SIGINT, Signal::SIGTERM] {
        // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
        unsafe { signal::signal(sig, SigHandler::Handler(on_signal)) }?;
    }

    let axes: Vec<String> = cli.axes.0.iter().map(|a| a.get().to_string()).collect();
    eprintln!(
        "rc-sim: axes {} at {} bit/s, RTIM {} ms",
        axes.join(","),
        cli.baud,
        cli.rtim
    );
    let mut realtime = RealTime::new(bus_at_line(config, &cli.axes.0, baud, rtim), options);
    if cli.control {
        let (sender, receiver) = std::sync::mpsc::channel();
        realtime.set_control(receiver);
        let axes = cli.axes.0.clone();
        std::thread::Builder::new()
            .name("control".into())
            .spawn(move || read_controls(&axes, &sender))?;
    }
    if let Some(path) = &cli.events {
        realtime.set_events(Box::new(std::fs::File::create(path)?));
    }
    let ended = realtime.run(&mut transport, &STOP)?;
    let why = match ended {
        Ended::Stopped => "stopped by a signal",
        Ended::Duration => "duration elapsed",
        Ended::Disconnected => "client disconnected",
    };
    eprintln!(
        "rc-sim: {why} after {:.3} s\nrc-sim: {:?}\nrc-sim: {:?}",
        realtime.bus().now() as f64 / 1e6,
        realtime.stats(),
        realtime.bus_stats()
    );
    Ok(())
}
