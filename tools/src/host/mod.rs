//! The gateway on a PC: the firmware's own [`Node`] (bus master, Modbus slave and register
//! map) with std I/O, for end-to-end tests with a real Modbus master and for bench work with
//! real adapters. The `rc-gateway-host` binary is a command line around [`Host`].
//!
//! # The loop
//! One thread, driven by a monotonic clock (µs since the start), doing what the firmware's
//! task does ([`protocol::node`]'s hardware contract). Each pass:
//! 1. reads what the PLC wrote (non-blocking) and hands it to the node, stamped with the time
//!    of the read; a frame whose t3.5 silence ended before those bytes is handled first;
//! 2. hands the bus bytes received to the node (a simulated bus gives each byte's arrival
//!    time, a real one the time of the read);
//! 3. polls the node until it is idle: frames go to the bus, Modbus replies to the PLC, line
//!    actions (rate, break start and end, communication change) are carried out;
//! 4. reads control lines from standard input, if enabled;
//! 5. sleeps until the node's [`poll_at`](Node::poll_at), the simulated bus' next event (at
//!    most every [`BUS_EVENT_GRAIN_US`]) or [`Options::max_sleep`], or until a line becomes
//!    readable.
//!
//! # Timing limits
//! Bytes are stamped when the loop reads them, not when they crossed the wire. The node's
//! Modbus receiver does not check the t1.5 gap (a pseudo-terminal or a USB adapter delivers a
//! frame in chunks whose spacing says nothing about the wire); t3.5 (end of frame) is that of
//! [`Options::plc_baud`]; a USB adapter with a latency timer (FTDI: 16 ms by default) can split
//! a frame with gaps longer than t3.5, so set it to 1 ms
//! (`/sys/bus/usb-serial/devices/ttyUSB0/latency_timer`). The bus engine's earliest-answer
//! bound is off ([`Config::wire_timing`](protocol::engine::Config::wire_timing)): neither a
//! pseudo-terminal nor a USB adapter gives byte times that obey the line rate.

mod answers;
pub mod board;
mod config;
mod control;
pub mod log;
pub mod port;
mod run;
pub mod tcp;

pub use board::DfuOptions;
pub use config::{gateway_config, simulated_bus};
pub use control::{Control, HELP};
pub use log::Level;
pub use port::{Parity, Port};

use std::collections::BTreeMap;
use std::io;
use std::path::{Path, PathBuf};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use protocol::line::Baud;
use protocol::node::Node;
use protocol::units::{Lead, Length};
use protocol::AxisSet;
use protocol::HomeDirection;

use crate::sim::Bus;
use config::invalid;
use log::Log;

/// A simulated bus' events closer together than this are handled in one pass (a reply's bytes
/// arrive 87 µs apart at 115.2 kbit/s; the engine's time-outs are tens of ms).
pub const BUS_EVENT_GRAIN_US: u64 = 250;

/// Reads per pass of the loop, at most, on each line.
const MAX_READS_PER_PASS: usize = 16;

/// Node actions handled per pass, at most.
const MAX_OUTPUTS_PER_PASS: usize = 64;

/// A Modbus burst longer than this is not kept for the log (the receiver drops it anyway).
const MAX_LOGGED_BURST: usize = 300;

/// Where the PLC is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PlcLine {
    /// A new pseudo-terminal; the PLC (a Modbus master program) opens [`Host::plc_path`].
    Pty,
    /// A serial device (an RS485 or RS232 adapter wired to the PLC).
    Device(PathBuf),
    /// No serial PLC line: the PLC talks Modbus TCP ([`Options::tcp`]).
    None,
}

/// The Modbus TCP side of the host gateway.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TcpOptions {
    /// Where to listen (port 0: any free one; the address listened on is
    /// [`Host::tcp_addr`]).
    pub listen: std::net::SocketAddr,
    /// The clients allowed (at most 4; empty: anyone).
    pub allow: Vec<protocol::net::Ipv4>,
}

/// Where the actuators are.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum BusLine {
    /// Simulated controllers at axes 0..`axes`, in this process, already at the line rate.
    Sim {
        /// How many axes.
        axes: u8,
        /// Point 1 = 20 mm and point 3 = 40 mm stored on every axis (where the stroke allows).
        points: bool,
    },
    /// An RS485 adapter.
    Device {
        /// The device.
        path: PathBuf,
        /// The axes on the bus.
        axes: AxisSet,
        /// Run the communication establishment procedure (break, configuration at 9.6 kbit/s,
        /// communication change) first.
        establish: bool,
        /// The adapter's receiver hears the gateway's own transmissions.
        echo: bool,
    },
}

/// How the host gateway is set up.
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    /// The PLC side.
    pub plc: PlcLine,
    /// The PLC line's rate (sets t3.5; a pseudo-terminal has no rate of its own).
    pub plc_baud: u32,
    /// The PLC line's parity (serial device only).
    pub plc_parity: Parity,
    /// The Modbus TCP side, if any.
    pub tcp: Option<TcpOptions>,
    /// The bus side.
    pub bus: BusLine,
    /// The RS485 line rate.
    pub bus_baud: Baud,
    /// The gateway's own Modbus unit.
    pub unit: u8,
    /// The PLC watchdog, ms (0 = off).
    pub watchdog_ms: u16,
    /// Screw lead of every axis.
    pub lead: Lead,
    /// Stroke of every axis.
    pub stroke: Length,
    /// Home end of every axis.
    pub home: HomeDirection,
    /// What to log on standard error.
    pub log: Level,
    /// Read control lines on standard input (see [`Control`]).
    pub control: bool,
    /// The longest sleep of the loop.
    pub max_sleep: StdDuration,
    /// A DFU partition in a file: the PLC link may send a firmware image into it.
    pub dfu: Option<DfuOptions>,
}

impl Default for Options {
    fn default() -> Options {
        Options {
            plc: PlcLine::Pty,
            plc_baud: 115_200,
            plc_parity: Parity::None,
            tcp: None,
            bus: BusLine::Sim {
                axes: 1,
                points: false,
            },
            bus_baud: Baud::B115200,
            unit: protocol::plc::DEFAULT_GATEWAY_UNIT,
            watchdog_ms: protocol::plc::DEFAULT_WATCHDOG_MS,
            lead: Lead::from_hundredths(800).unwrap_or(Lead::of(
                protocol::units::ActuatorType::RM,
                protocol::units::SpeedType::M,
            )),
            stroke: Length(10_000), // 100 mm
            home: HomeDirection::MotorEnd,
            log: Level::Off,
            control: true,
            max_sleep: StdDuration::from_millis(2),
            dfu: None,
        }
    }
}

/// Why a run ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ended {
    /// The stop flag was raised (SIGINT, SIGTERM).
    Stopped,
    /// A `quit` control line.
    Quit,
    /// Standard input ended (with control lines enabled).
    InputClosed,
}

enum BusSide {
    Sim(Box<Bus>),
    Device { port: Port },
}

/// The gateway between two lines; see the [module documentation](self).
pub struct Host {
    node: Box<Node>,
    plc: Option<Port>,
    tcp: Option<tcp::TcpSide>,
    bus: BusSide,
    /// Frames sent to each axis, by command mnemonic.
    sent: Vec<BTreeMap<&'static str, u64>>,
    log: Log,
    /// The bytes of the Modbus burst in progress, for the log.
    burst: Vec<u8>,
    /// Saves asked for (a PC has no settings flash).
    saves: u32,
    /// The settings saved during the run (a restart starts with them).
    saved: Option<[u8; protocol::plc::settings::RECORD_LEN]>,
    /// The options, for a restart.
    options: Options,
    /// µs of the host's clock at the node's start (the node's clock starts at 0 at each start).
    epoch: u64,
    /// A restart asked for, carried out at the end of the pass (after the reply has left).
    restart_due: Option<Restart>,
    /// The node's receiver counters when a burst was last logged.
    seen_receiver: protocol::modbus::ReceiverCounters,
    started: StdInstant,
    last_bus_rx: u64,
    /// Standard input's partial line, when control lines are read.
    control: Option<Vec<u8>>,
    max_sleep: StdDuration,
    /// The board's flash and bootloader, if there is one.
    board: Option<board::Board>,
}

/// Why the host gateway restarts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Restart {
    /// RESTART, or the `restart` control line (a reset: the saved settings).
    Reset,
    /// FACTORY: the saved settings erased first.
    Factory,
}

/// The identity the node answers with: the built-in one, with the running image's version.
fn identity_for(version: Option<rc_boot::image::Version>) -> &'static protocol::modbus::Identity {
    match version {
        None => &protocol::plc::IDENTITY,
        Some(v) => {
            // One small leak per start: the node keeps a `&'static Identity`.
            let revision: &'static str =
                Box::leak(format!("{}.{}.{}", v.major, v.minor, v.patch).into_boxed_str());
            Box::leak(Box::new(protocol::modbus::Identity {
                revision,
                ..protocol::plc::IDENTITY
            }))
        }
    }
}

impl Host {
    /// Open both lines and build the gateway.
    pub fn new(options: &Options) -> io::Result<Host> {
        let mut board = match &options.dfu {
            Some(dfu) => Some(board::Board::open(dfu)?),
            None => None,
        };
        let node = Host::start_node(options, None, 0, None, board.as_mut())?;
        let bus = match &options.bus {
            BusLine::Sim { axes, points } => {
                BusSide::Sim(Box::new(simulated_bus(options, *axes, *points)?))
            }
            BusLine::Device { path, .. } => {
                let bps = node.gateway().engine().line_baud().bits_per_second();
                port::termios_rate(options.bus_baud.bits_per_second()).ok_or_else(|| {
                    invalid(format!(
                        "{} bit/s: termios has no constant for this rate; use 9600, 19200, \
                         38400, 57600 or 115200",
                        options.bus_baud.bits_per_second()
                    ))
                })?;
                BusSide::Device {
                    port: Port::serial(path, bps, Parity::None)?,
                }
            }
        };
        let plc = match &options.plc {
            PlcLine::Pty => Some(Port::pty(options.plc_baud)?),
            PlcLine::Device(path) => {
                Some(Port::serial(path, options.plc_baud, options.plc_parity)?)
            }
            PlcLine::None => None,
        };
        let tcp = match &options.tcp {
            Some(tcp) => Some(tcp::TcpSide::bind(tcp.listen)?),
            None if plc.is_none() => {
                return Err(invalid(
                    "no PLC side: a serial line, Modbus TCP or both".into(),
                ))
            }
            None => None,
        };
        Ok(Host {
            node,
            plc,
            tcp,
            bus,
            sent: vec![BTreeMap::new(); 16],
            log: Log::new(options.log),
            burst: Vec::new(),
            seen_receiver: protocol::modbus::ReceiverCounters::default(),
            saves: 0,
            saved: None,
            options: options.clone(),
            epoch: 0,
            restart_due: None,
            started: StdInstant::now(),
            last_bus_rx: 0,
            control: options.control.then(Vec::new),
            max_sleep: options.max_sleep,
            board,
        })
    }

    /// A new node, as the firmware starts: the configuration with the saved settings on it,
    /// the reset's cause (a restart's: software), and, with a board, the bootloader's `prepare_boot` first and the version ACTIVE runs.
    fn start_node(
        options: &Options,
        saved: Option<&[u8]>,
        saves: u32,
        reset: Option<protocol::plc::ResetCause>,
        board: Option<&mut board::Board>,
    ) -> io::Result<Box<Node>> {
        let mut config = gateway_config(options)?;
        let mut source = protocol::plc::ConfigSource::Defaults;
        let mut load_errors = 0;
        if let Some(record) = saved {
            match protocol::plc::settings::Settings::decode(record) {
                Ok(settings) => {
                    config = settings.apply(config);
                    source = protocol::plc::ConfigSource::Flash;
                }
                Err(_) => {
                    source = protocol::plc::ConfigSource::Damaged;
                    load_errors = 1;
                }
            }
        }
        let boot = protocol::plc::Boot {
            source,
            load_errors,
            save_count: saves,
            reset: reset.unwrap_or(protocol::plc::Boot::DEFAULT.reset),
        };
        let started = match board {
            Some(board) => Some((board.boot()?, board.target())),
            None => None,
        };
        let version = started.and_then(|(s, _)| s.version);
        let mut node = Box::new(Node::new(config, identity_for(version), boot));
        if let Some((started, target)) = started {
            node.set_update_target(target);
            node.set_boot_state(started.boot);
        }
        Ok(node)
    }

    /// The PLC's device: the pseudo-terminal's `/dev/pts/N`, or the device opened; `None`
    /// without a serial PLC line.
    pub fn plc_path(&self) -> Option<&Path> {
        self.plc.as_ref().map(Port::path)
    }

    /// The address the Modbus TCP side listens on, if there is one.
    pub fn tcp_addr(&self) -> Option<std::net::SocketAddr> {
        self.tcp.as_ref().and_then(|tcp| tcp.local_addr().ok())
    }

    /// The node (the gateway behind its lines).
    pub fn node(&self) -> &Node {
        &self.node
    }

    /// The simulated bus, if the bus is simulated.
    pub fn sim(&self) -> Option<&Bus> {
        match &self.bus {
            BusSide::Sim(bus) => Some(bus),
            BusSide::Device { .. } => None,
        }
    }

    /// µs since the start.
    fn now(&self) -> u64 {
        u64::try_from(self.started.elapsed().as_micros()).unwrap_or(u64::MAX)
    }

    /// The node's time for the host's `now`: since the node's start.
    fn node_time(&self, now: u64) -> protocol::time::Instant {
        protocol::time::Instant(now.saturating_sub(self.epoch))
    }

    /// The bootloader's state told at the last start, if there is a board.
    pub fn boot_state(&self) -> Option<protocol::plc::update::BootState> {
        self.board.as_ref().map(board::Board::boot_state)
    }
}
