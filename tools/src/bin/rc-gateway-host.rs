//! `rc-gateway-host`: the gateway (the firmware's engine and Modbus/PLC logic) on a PC, between
//! a Modbus RTU master and simulated or real Robo Cylinder controllers.
//!
//! ```text
//! $ rc-gateway-host --plc-pty --sim 3 --points
//! PLC /dev/pts/5
//! $ rc-gateway-host --plc /dev/ttyUSB0 --plc-baud 38400 --bus /dev/ttyUSB1 --axes 2
//! PLC /dev/ttyUSB0
//! $ rc-gateway-host --modbus-tcp 127.0.0.1:5020 --sim 2
//! TCP 127.0.0.1:5020
//! ```
//!
//! See `rc_tools::host` for the loop and its timing limits; `--help` for the options, the
//! control lines and the exit status.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::{ArgGroup, Parser, ValueEnum};
use nix::sys::signal::{self, SigHandler, Signal};
use protocol::line::Baud;
use protocol::units::{Lead, Length};
use protocol::AxisSet;
use protocol::HomeDirection;
use rc_tools::host::{BusLine, Ended, Host, Level, Options, Parity, PlcLine, TcpOptions};

const ABOUT: &str = "\
The Robo Cylinder gateway on a PC: the firmware's bus master and Modbus register map, between a
Modbus RTU master (the PLC) and simulated or real IAI controllers on RS485.

LINES
  PLC side:  --plc-pty        a new pseudo-terminal; a Modbus master program opens it
             --plc PATH       a serial device, raw, 8 data bits, 1 stop bit, --plc-parity
             --modbus-tcp ADDR:PORT
                              Modbus TCP (alone, or beside --plc/--plc-pty); port 0 takes a
                              free one; --tcp-allow A[,B..] lists the clients allowed (up to
                              4; none: anyone)
  Bus side:  --sim N          N simulated controllers (axes 0..N-1) in this process, already at
                              --bus-baud and RTIM 3 ms (no establishment procedure)
             --bus PATH       an RS485 adapter; the establishment procedure (break, set-up at
                              9.6 kbit/s, communication change) runs first unless
                              --no-establish; --axes says which axes are on the bus
  The first line on standard output is `PLC <device>`: the device the Modbus master opens; with
  --modbus-tcp a line `TCP <address>:<port>` follows it (or is the first, with no serial line).
  Units: axis n is Modbus unit n + 1; the gateway itself is --unit (63; 1-247, not an axis' unit).
  On TCP, unit 0xFF (and 0) is the gateway unit; a unit nobody serves gets exception 0A.

CONTROL LINES (standard input)
  On by default with --sim, off with --bus (--control / --no-control). One command per line;
  each gets exactly one JSON line on standard output:
    alarm <axis> <hex>    raise an alarm (80-FF) on a simulated axis, e.g. `alarm 0 D8`
    stats                 per axis: frames sent by command, CMST/CMER, link; with --sim also
                          what the simulator sees (frames received, moving, position...);
                          the gateway's FAILSAFE and the Modbus slave's counters
    stop-input on|off     the gateway's stop input (as the PIO *STP safety input)
    restart               restart the gateway as a reset does (with --dfu: the bootloader runs;
                          no Modbus request needed, so a trial can be left unconfirmed)
    quit                  end the run
    help                  the list
  With control lines enabled, the end of standard input ends the run like `quit` (so give
  --no-control when standard input is /dev/null or the run is a background job).

EXIT
  SIGINT, SIGTERM, `quit` or the end of standard input (with control lines) end the run: exit
  status 0. 1 on an I/O error of a line, 2 on bad command-line input. The axes are not stopped
  on exit (a real bus keeps running its last commands).

TIMING
  Bytes are stamped when read, not when they crossed the wire: the Modbus t1.5 gap check is off
  (as in the firmware), t3.5 is that of --plc-baud, and a controller's answer is accepted as
  soon as it arrives (no earliest-answer bound: a pseudo-terminal has no wire time). A USB adapter's latency timer (FTDI: 16 ms)
  can split a frame: set it to 1 ms.";

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum Home {
    /// Home at the motor end (the documents' default).
    Motor,
    /// Home at the far (non-motor) end.
    Far,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum ParityArg {
    None,
    Even,
    Odd,
}

/// The Robo Cylinder gateway on a PC (Modbus RTU PLC side, RS485 bus side).
#[derive(Parser, Debug)]
#[command(name = "rc-gateway-host", version, long_about = ABOUT)]
#[command(group(ArgGroup::new("plc_side").required(true).multiple(true).args(["plc_pty", "plc", "modbus_tcp"])))]
#[command(group(ArgGroup::new("serial_plc").args(["plc_pty", "plc"])))]
#[command(group(ArgGroup::new("bus_side").required(true).args(["sim", "bus"])))]
struct Cli {
    /// PLC side: a new pseudo-terminal (its path is the first line on stdout).
    #[arg(long)]
    plc_pty: bool,
    /// PLC side: a serial device.
    #[arg(long, value_name = "PATH")]
    plc: Option<PathBuf>,
    /// PLC side: Modbus TCP on this address and port (port 0: any free one; the address
    /// listened on is printed as `TCP <address>:<port>`).
    #[arg(long, value_name = "ADDR:PORT")]
    modbus_tcp: Option<std::net::SocketAddr>,
    /// --modbus-tcp: the clients allowed to connect, up to 4 IPv4 addresses (none: anyone).
    #[arg(
        long,
        value_name = "A[,B..]",
        value_delimiter = ',',
        requires = "modbus_tcp"
    )]
    tcp_allow: Vec<std::net::Ipv4Addr>,
    /// The PLC line's rate, bit/s (sets the Modbus t3.5).
    #[arg(long, default_value_t = 115_200, value_name = "BPS")]
    plc_baud: u32,
    /// The PLC line's parity (serial device only).
    #[arg(long, value_enum, default_value_t = ParityArg::None)]
    plc_parity: ParityArg,
    /// Bus side: N simulated controllers, axes 0..N-1 (1-16).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u8).range(1..=16))]
    sim: Option<u8>,
    /// Bus side: an RS485 adapter.
    #[arg(long, value_name = "PATH")]
    bus: Option<PathBuf>,
    /// --bus: the axes on the bus, a count (2 = axes 0 and 1) or a list ("0,1,5", "2-4").
    #[arg(long, default_value = "1", value_parser = parse_axes)]
    axes: AxisSetArg,
    /// --bus: skip the establishment procedure (the controllers already run at --bus-baud,
    /// RTIM 3 ms).
    #[arg(long)]
    no_establish: bool,
    /// --bus: the adapter's receiver hears the gateway's own transmissions.
    #[arg(long)]
    echo: bool,
    /// The RS485 line rate, bit/s (9600, 19200, 38400, 57600 or 115200).
    #[arg(long, default_value_t = 115_200, value_name = "BPS", value_parser = parse_bus_baud)]
    bus_baud: u32,
    /// --sim: store point 1 = 20 mm and point 3 = 40 mm on every axis.
    #[arg(long)]
    points: bool,
    /// The gateway's own Modbus unit, 1-247 (not an axis' unit: axis n is unit n + 1).
    #[arg(long, default_value_t = protocol::plc::DEFAULT_GATEWAY_UNIT, value_parser = parse_unit)]
    unit: u8,
    /// The PLC watchdog, ms (0 = off, else 50-60000).
    #[arg(long, default_value_t = protocol::plc::DEFAULT_WATCHDOG_MS, value_name = "MS")]
    watchdog_ms: u16,
    /// Screw lead of every axis, mm.
    #[arg(long, default_value = "8", value_name = "MM", allow_negative_numbers = true,
          value_parser = parse_hundredths)]
    lead_mm: u32,
    /// Stroke of every axis, mm.
    #[arg(long, default_value = "100", value_name = "MM", allow_negative_numbers = true,
          value_parser = parse_hundredths)]
    stroke_mm: u32,
    /// Home end of every axis.
    #[arg(long, value_enum, default_value_t = Home::Motor)]
    home: Home,
    /// Log Modbus traffic and bus commands (not the polls), decoded, on standard error.
    #[arg(long)]
    log: bool,
    /// Log the bus polls (status, position reads) too.
    #[arg(long)]
    log_polls: bool,
    /// Read control lines on standard input (the default with --sim).
    #[arg(long, overrides_with = "no_control")]
    control: bool,
    /// Ignore standard input (the default with --bus).
    #[arg(long, overrides_with = "control")]
    no_control: bool,
    /// The board's flash in this file (the whole flash of --board-id's board: the L475's 1 MiB,
    /// the F429's 2 MiB; created erased, at rc-boot's layout and in the board's erase and write
    /// units), with a bootloader: `rcgw update` sends a signed image into its DFU partition, a
    /// restart (RESTART, FACTORY, the `restart` control line) runs embassy-boot's prepare_boot
    /// on it (a marked image swapped in on trial, an unconfirmed trial rolled back) and the
    /// gateway then runs the version of the image in ACTIVE.
    #[arg(long, value_name = "PATH")]
    dfu: Option<PathBuf>,
    /// --dfu: the public key (32 raw bytes, `rcgw key new`'s NAME.pub) the firmware verifies
    /// images with. Default: the public TEST key (a warning is printed).
    #[arg(long, value_name = "PATH.pub", requires = "dfu")]
    update_key: Option<PathBuf>,
    /// --dfu: the board, l475 (0x0475) or f429 (0x0429; the NUCLEO-F429ZI), or its id (decimal,
    /// or hex with 0x): an image must name it, and it chooses the flash's layout (another id is
    /// refused).
    #[arg(long, default_value = "0x0475", value_name = "ID", value_parser = parse_board, requires = "dfu")]
    board_id: u16,
}

/// A 32-byte public key file.
fn read_key(path: &std::path::Path) -> Result<[u8; 32], String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    bytes.as_slice().try_into().map_err(|_| {
        format!(
            "{}: {} bytes: a public key file is exactly 32 raw bytes (`rcgw key new`)",
            path.display(),
            bytes.len()
        )
    })
}

/// A board: its name (as `rcgw sign --board` takes it) or its id.
fn parse_board(text: &str) -> Result<u16, String> {
    match text.to_ascii_lowercase().as_str() {
        "l475" => return Ok(rc_boot::BOARD_L475),
        "f429" => return Ok(rc_boot::BOARD_F429),
        _ => {}
    }
    let parsed = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u16::from_str_radix(hex, 16),
        None => text.parse(),
    };
    parsed
        .map_err(|_| format!("{text:?}: a board is l475, f429 or an id 0-65535 (or 0x0000-0xFFFF)"))
}

#[derive(Clone, Copy, Debug)]
struct AxisSetArg(AxisSet);

fn parse_axes(text: &str) -> Result<AxisSetArg, String> {
    let text = text.trim();
    if !text.contains([',', '-']) {
        let count: u8 = text
            .parse()
            .map_err(|_| format!("{text:?}: not a count of axes"))?;
        if !(1..=16).contains(&count) {
            return Err(format!("{count}: 1 to 16 axes"));
        }
        return Ok(AxisSetArg(AxisSet::first(count)));
    }
    let mut set = AxisSet::default();
    for part in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (first, last) = part.split_once('-').unwrap_or((part, part));
        let number = |s: &str| {
            s.trim()
                .parse::<u8>()
                .ok()
                .filter(|&n| n < 16)
                .ok_or_else(|| format!("{s:?}: an axis is 0-15"))
        };
        let (first, last) = (number(first)?, number(last)?);
        if first > last {
            return Err(format!("{part:?}: empty range"));
        }
        for n in first..=last {
            set.0 |= 1 << n;
        }
    }
    if set.0 == 0 {
        return Err("no axis".into());
    }
    Ok(AxisSetArg(set))
}

fn parse_bus_baud(text: &str) -> Result<u32, String> {
    let bps: u32 = text.parse().map_err(|_| format!("{text:?}: not a rate"))?;
    match Baud::from_bits_per_second(bps) {
        Some(baud) if rc_tools::host::port::termios_rate(bps).is_some() => {
            Ok(baud.bits_per_second())
        }
        _ => Err(format!(
            "{bps}: use 9600, 19200, 38400, 57600 or 115200 (rates both the controllers and \
             termios have)"
        )),
    }
}

/// A Modbus unit id a gateway can have: 1-247 (Serial Line §2.2; 0 is the broadcast address,
/// 248-255 are reserved).
fn parse_unit(text: &str) -> Result<u8, String> {
    text.trim()
        .parse::<u8>()
        .ok()
        .filter(|unit| (1..=247).contains(unit))
        .ok_or_else(|| format!("{text:?}: a Modbus unit id is 1-247"))
}

/// A length in mm with at most two decimals, more than 0, as 0.01 mm.
fn parse_hundredths(text: &str) -> Result<u32, String> {
    if text.trim().starts_with('-') {
        return Err(format!(
            "{text:?}: a lead or stroke is a length, more than 0 mm"
        ));
    }
    let bad = || format!("{text:?}: a length in mm more than 0, such as 8 or 2.5");
    let (whole, fraction) = text.trim().split_once('.').unwrap_or((text.trim(), ""));
    if fraction.len() > 2 || !fraction.chars().all(|c| c.is_ascii_digit()) {
        return Err(bad());
    }
    let whole: u32 = whole.parse().map_err(|_| bad())?;
    let fraction: u32 = format!("{fraction:0<2}").parse().map_err(|_| bad())?;
    whole
        .checked_mul(100)
        .and_then(|w| w.checked_add(fraction))
        .filter(|&h| h > 0)
        .ok_or_else(bad)
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: nix::libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

fn options(cli: &Cli) -> Result<Options, String> {
    let lead = u16::try_from(cli.lead_mm)
        .ok()
        .and_then(Lead::from_hundredths)
        .ok_or_else(|| "--lead-mm: out of range".to_string())?;
    let stroke = i32::try_from(cli.stroke_mm)
        .map(Length)
        .map_err(|_| "--stroke-mm: out of range".to_string())?;
    let bus_baud = Baud::from_bits_per_second(cli.bus_baud).ok_or("--bus-baud: unsupported")?;
    let plc = match (&cli.plc, cli.plc_pty) {
        (Some(path), _) => PlcLine::Device(path.clone()),
        (None, true) => PlcLine::Pty,
        (None, false) => PlcLine::None,
    };
    if cli.tcp_allow.len() > 4 {
        return Err(format!(
            "--tcp-allow: {} addresses, at most 4",
            cli.tcp_allow.len()
        ));
    }
    let tcp = cli.modbus_tcp.map(|listen| TcpOptions {
        listen,
        allow: cli
            .tcp_allow
            .iter()
            .map(|a| protocol::net::Ipv4(a.octets()))
            .collect(),
    });
    if rc_tools::host::port::termios_rate(cli.plc_baud).is_none() {
        return Err(format!(
            "--plc-baud {}: termios has no constant for this rate",
            cli.plc_baud
        ));
    }
    let (bus, control_default) = match (&cli.bus, cli.sim) {
        (Some(path), _) => (
            BusLine::Device {
                path: path.clone(),
                axes: cli.axes.0,
                establish: !cli.no_establish,
                echo: cli.echo,
            },
            false,
        ),
        (None, Some(axes)) => (
            BusLine::Sim {
                axes,
                points: cli.points,
            },
            true,
        ),
        (None, None) => return Err("--sim N or --bus PATH".into()),
    };
    let control = if cli.control {
        true
    } else if cli.no_control {
        false
    } else {
        control_default
    };
    Ok(Options {
        plc,
        tcp,
        plc_baud: cli.plc_baud,
        plc_parity: match cli.plc_parity {
            ParityArg::None => Parity::None,
            ParityArg::Even => Parity::Even,
            ParityArg::Odd => Parity::Odd,
        },
        bus,
        bus_baud,
        unit: cli.unit,
        watchdog_ms: cli.watchdog_ms,
        lead,
        stroke,
        home: match cli.home {
            Home::Motor => HomeDirection::MotorEnd,
            Home::Far => HomeDirection::NonMotorEnd,
        },
        log: if cli.log_polls {
            Level::All
        } else if cli.log {
            Level::Commands
        } else {
            Level::Off
        },
        control,
        dfu: match &cli.dfu {
            Some(path) => Some(rc_tools::host::DfuOptions {
                path: path.clone(),
                board: cli.board_id,
                public_key: match &cli.update_key {
                    Some(key) => Some(read_key(key)?),
                    None => {
                        eprintln!(
                            "rc-gateway-host: WARNING: --dfu without --update-key: images are verified with the public TEST key (tests only)"
                        );
                        None
                    }
                },
            }),
            None => None,
        },
        ..Options::default()
    })
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let options = match options(&cli) {
        Ok(options) => options,
        Err(e) => {
            eprintln!("rc-gateway-host: {e}");
            return ExitCode::from(2);
        }
    };
    match run(&options) {
        Ok(ended) => {
            let why = match ended {
                Ended::Stopped => "stopped by a signal",
                Ended::Quit => "quit",
                Ended::InputClosed => "standard input closed",
            };
            eprintln!("rc-gateway-host: {why}");
            ExitCode::SUCCESS
        }
        Err(e) if e.kind() == std::io::ErrorKind::InvalidInput => {
            eprintln!("rc-gateway-host: {e}");
            ExitCode::from(2)
        }
        Err(e) => {
            eprintln!("rc-gateway-host: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(options: &Options) -> std::io::Result<Ended> {
    for sig in [Signal::SIGINT, Signal::SIGTERM] {
        // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
        unsafe { signal::signal(sig, SigHandler::Handler(on_signal)) }?;
    }
    let mut host = Host::new(options)?;
    {
        let mut out = std::io::stdout().lock();
        if let Some(path) = host.plc_path() {
            writeln!(out, "PLC {}", path.display())?;
        }
        if let Some(addr) = host.tcp_addr() {
            writeln!(out, "TCP {addr}")?;
        }
        out.flush()?;
    }
    let axes: Vec<String> = host
        .node()
        .gateway()
        .config()
        .bus
        .axes
        .iter()
        .map(|a| a.get().to_string())
        .collect();
    let plc = match (host.plc_path(), host.tcp_addr()) {
        (Some(path), Some(addr)) => {
            format!(
                "PLC {} at {} bit/s and TCP {addr}",
                path.display(),
                options.plc_baud
            )
        }
        (Some(path), None) => format!("PLC {} at {} bit/s", path.display(), options.plc_baud),
        (None, Some(addr)) => format!("TCP {addr}"),
        (None, None) => String::new(),
    };
    eprintln!(
        "rc-gateway-host: {plc}, gateway unit {}; {} axes {} at {} bit/s",
        options.unit,
        if host.sim().is_some() {
            "simulated"
        } else {
            "RS485"
        },
        axes.join(","),
        options.bus_baud.bits_per_second()
    );
    host.run(&STOP)
}
