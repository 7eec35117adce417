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

mod control;
pub mod log;
pub mod port;

pub use control::{Control, HELP};
pub use log::Level;
pub use port::{Parity, Port};

use std::collections::BTreeMap;
use std::io::{self, Write};
use std::os::fd::{AsFd, BorrowedFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use protocol::engine::Link;
use protocol::frame::COMM_CHANGE;
use protocol::line::{Baud, LineAction, BREAK_MS};
use protocol::node::{Action, Node};
use protocol::plc::{AxisConfig, GatewayConfig};
use protocol::time::{Duration, Instant};
use protocol::units::{Lead, Length, Scale};
use protocol::AxisSet;
use protocol::{Axis, HomeDirection, PositionNo, Pulses, Request, Rtim};
use serde_json::{json, Value};

use crate::sim::memory::{Actuator, PointRow, POINT_LEN};
use crate::sim::{Bus, BusConfig, ControllerConfig};
use log::Log;
use port::Input;

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
}

impl Default for Options {
    fn default() -> Options {
        Options {
            plc: PlcLine::Pty,
            plc_baud: 115_200,
            plc_parity: Parity::None,
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
    plc: Port,
    bus: BusSide,
    /// Frames sent to each axis, by command mnemonic.
    sent: Vec<BTreeMap<&'static str, u64>>,
    log: Log,
    /// The bytes of the Modbus burst in progress, for the log.
    burst: Vec<u8>,
    /// Saves asked for (a PC has no settings flash).
    saves: u32,
    /// The node's receiver counters when a burst was last logged.
    seen_receiver: protocol::modbus::ReceiverCounters,
    started: StdInstant,
    last_bus_rx: u64,
    /// Standard input's partial line, when control lines are read.
    control: Option<Vec<u8>>,
    max_sleep: StdDuration,
}

fn invalid(text: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, text)
}

/// The gateway's configuration for `options`.
pub fn gateway_config(options: &Options) -> io::Result<GatewayConfig> {
    let (axes, establish, echo) = match &options.bus {
        BusLine::Sim { axes, .. } => {
            if !(1..=16).contains(axes) {
                return Err(invalid(format!("{axes}: 1 to 16 simulated axes")));
            }
            (AxisSet::first(*axes), false, false)
        }
        BusLine::Device {
            axes,
            establish,
            echo,
            ..
        } => (*axes, *establish, *echo),
    };
    if axes.0 == 0 {
        return Err(invalid("no axis".into()));
    }
    let mut config = GatewayConfig::new(axes);
    config.unit = options.unit;
    config.plc = protocol::plc::PlcLine {
        baud: options.plc_baud,
        parity: options.plc_parity,
    };
    config.bus.baud = options.bus_baud;
    config.bus.rtim = Rtim::MIN;
    config.bus.establish = establish;
    config.bus.echo = echo;
    // Bytes are stamped when read: a pseudo-terminal or a USB adapter has no wire time.
    config.bus.wire_timing = false;
    if !(1..=247).contains(&options.unit) || config.axis_of_unit(options.unit).is_some() {
        return Err(invalid(format!(
            "unit {}: 1-247 and not an axis unit (axis n is unit n + 1)",
            options.unit
        )));
    }
    if options.watchdog_ms != 0 && !(50..=60_000).contains(&options.watchdog_ms) {
        return Err(invalid(format!(
            "watchdog {} ms: 0 (off) or 50-60000",
            options.watchdog_ms
        )));
    }
    config.watchdog = Duration::from_millis(u64::from(options.watchdog_ms));
    if options.stroke.0 <= 0 {
        return Err(invalid("the stroke must be positive".into()));
    }
    let scale = gateway_scale(options.lead, options.home);
    config.axes = protocol::AxisMap::new(AxisConfig {
        scale,
        stroke: options.stroke,
    });
    Ok(config)
}

/// The gateway's default conventions with this lead and home end.
fn gateway_scale(lead: Lead, home: protocol::HomeDirection) -> Scale {
    Scale {
        lead,
        home,
        ..AxisConfig::default().scale
    }
}

/// Simulated controllers for `options` (which must be [`BusLine::Sim`]): each at the line rate
/// and RTIM 3 ms, with the lead, stroke and home end given.
pub fn simulated_bus(options: &Options, axes: u8, points: bool) -> io::Result<Bus> {
    let lead = options.lead;
    let lead_type = (0..16u32)
        .find(|&t| Lead::from_lead_type(t) == Some(lead))
        .ok_or_else(|| {
            invalid(format!(
                "lead {}.{:02} mm: the simulator knows the REG1 lead types 2.5, 3, 4, 5, 6, 8, \
                 10, 12, 16 and 20 mm",
                lead.hundredths() / 100,
                lead.hundredths() % 100
            ))
        })?;
    let scale = gateway_scale(lead, options.home);
    let stroke = u32::try_from(scale.pulses(options.stroke))
        .map_err(|_| invalid("the stroke is out of range".into()))?;
    let mut rows: Vec<(PositionNo, PointRow)> = Vec::new();
    if points {
        for (point, position) in [(1u8, 2_000), (3, 4_000)] {
            if position > options.stroke.0 {
                continue;
            }
            let (Some(point), Ok(pcmd)) = (
                PositionNo::new(point),
                scale.position_to_wire(Length(position)),
            ) else {
                continue;
            };
            let mut row = [0u32; POINT_LEN];
            if let Some(slot) = row.first_mut() {
                *slot = pcmd.to_wire();
            }
            rows.push((point, row));
        }
    }
    let baud = options.bus_baud;
    let mut bus = Bus::new(BusConfig {
        host_baud: baud,
        ..BusConfig::default()
    });
    let defaults = ControllerConfig::default();
    for axis in (0..axes).filter_map(Axis::new) {
        bus.add_controller(
            axis,
            ControllerConfig {
                actuator: Actuator { stroke, lead_type },
                start_from_motor_end: defaults.start_from_motor_end.min(stroke / 5),
                home_direction: options.home,
                stored_line: Some((baud, Rtim::MIN)),
                points: rows.clone(),
                ..defaults.clone()
            },
        );
    }
    Ok(bus)
}

impl Host {
    /// Open both lines and build the gateway.
    pub fn new(options: &Options) -> io::Result<Host> {
        let config = gateway_config(options)?;
        let node = Box::new(Node::new(config));
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
            PlcLine::Pty => Port::pty(options.plc_baud)?,
            PlcLine::Device(path) => Port::serial(path, options.plc_baud, options.plc_parity)?,
        };
        Ok(Host {
            node,
            plc,
            bus,
            sent: vec![BTreeMap::new(); 16],
            log: Log::new(options.log),
            burst: Vec::new(),
            seen_receiver: protocol::modbus::ReceiverCounters::default(),
            saves: 0,
            started: StdInstant::now(),
            last_bus_rx: 0,
            control: options.control.then(Vec::new),
            max_sleep: options.max_sleep,
        })
    }

    /// The PLC's device: the pseudo-terminal's `/dev/pts/N`, or the device opened.
    pub fn plc_path(&self) -> &Path {
        self.plc.path()
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

    /// Run until `stop` is raised (checked at least every [`Options::max_sleep`]), a `quit`
    /// line, or the end of standard input (with control lines). Fails on an I/O error of a
    /// line.
    pub fn run(&mut self, stop: &AtomicBool) -> io::Result<Ended> {
        let mut buf = [0u8; 4096];
        self.log.note(self.now(), "started");
        loop {
            if stop.load(Ordering::Relaxed) {
                return Ok(Ended::Stopped);
            }
            let now = self.now();
            self.read_plc(now, &mut buf)?;
            self.read_bus(now, &mut buf)?;
            let until = self.drive(now)?;
            if let Some(ended) = self.read_control(now, &mut buf)? {
                return Ok(ended);
            }
            self.plc.flush()?;
            if let BusSide::Device { port, .. } = &mut self.bus {
                port.flush()?;
            }
            self.sleep(until)?;
        }
    }

    fn read_plc(&mut self, now: u64, buf: &mut [u8]) -> io::Result<()> {
        for _ in 0..MAX_READS_PER_PASS {
            let n = match self.plc.read(buf)? {
                Input::Bytes(n) => n,
                Input::Nothing => break,
            };
            // A frame that ended (t3.5) before these bytes is handled before they start the
            // next one.
            self.drive(now)?;
            let bytes = buf.get(..n).unwrap_or(&[]);
            self.node.plc_received(Instant(now), bytes);
            if self.burst.len() + bytes.len() <= MAX_LOGGED_BURST {
                self.burst.extend_from_slice(bytes);
            }
        }
        Ok(())
    }

    fn read_bus(&mut self, now: u64, buf: &mut [u8]) -> io::Result<()> {
        match &mut self.bus {
            BusSide::Sim(bus) => {
                for (at, byte) in bus.advance(now) {
                    let at = at.max(self.last_bus_rx);
                    self.last_bus_rx = at;
                    self.log.bus_received(at, byte);
                    self.node.bus_received(Instant(at), &[byte]);
                }
            }
            BusSide::Device { port, .. } => {
                for _ in 0..MAX_READS_PER_PASS {
                    let n = match port.read(buf)? {
                        Input::Bytes(n) => n,
                        Input::Nothing => break,
                    };
                    let bytes = buf.get(..n).unwrap_or(&[]);
                    for &byte in bytes {
                        self.log.bus_received(now, byte);
                    }
                    self.node.bus_received(Instant(now), bytes);
                }
            }
        }
        Ok(())
    }

    /// Poll the node until it is idle; its deadline.
    fn drive(&mut self, now: u64) -> io::Result<Option<u64>> {
        for _ in 0..MAX_OUTPUTS_PER_PASS {
            match self.node.poll(Instant(now)) {
                Some(Action::Bus(bytes)) => {
                    if let Ok(request) = protocol::Frame::new_checked(&bytes)
                        .and_then(|frame| Request::parse(&frame))
                    {
                        if let Some(counts) = self.sent.get_mut(usize::from(request.axis.get())) {
                            *counts.entry(request.command.mnemonic()).or_default() += 1;
                        }
                    }
                    if let Ok(frame) = protocol::Frame::new_checked(&bytes) {
                        self.log.bus_sent(now, &frame);
                    }
                    match &mut self.bus {
                        BusSide::Sim(bus) => {
                            bus.host_send(now, &bytes);
                        }
                        BusSide::Device { port } => port.send(&bytes)?,
                    }
                }
                Some(Action::Reply(bytes)) => {
                    self.plc.send(bytes)?;
                    self.log.modbus_request(now, &self.burst, "reply");
                    self.log.modbus_reply(now, bytes);
                    self.burst.clear();
                }
                Some(Action::Line(action)) => self.line(now, action)?,
                Some(Action::PlcLine(line)) => {
                    self.plc.drain()?;
                    self.plc.set_rate(line.baud)?;
                    self.log.note(now, &format!("PLC line: {line:?}"));
                }
                Some(Action::Store(store)) => {
                    // A PC has no settings flash: a save is kept for the run (and counted), a
                    // restart or factory reset is only logged.
                    if let protocol::plc::Store::Save(_) = store {
                        self.saves += 1;
                        self.node.stored(Ok(self.saves));
                    }
                    self.log.note(now, &format!("store: {store:?}"));
                }
                None => {
                    if self.node.receiver_counters() != self.seen_receiver {
                        // A burst ended without a reply (a broadcast, another unit, noise).
                        self.seen_receiver = self.node.receiver_counters();
                        if !self.burst.is_empty() {
                            self.log.modbus_request(now, &self.burst, "no reply");
                            self.burst.clear();
                        }
                    }
                    return Ok(self.node.poll_at().map(|t| t.0));
                }
            }
        }
        // More to do: come back at once.
        Ok(Some(now))
    }

    fn line(&mut self, now: u64, action: LineAction) -> io::Result<()> {
        self.log.note(now, &format!("line: {action:?}"));
        match (&mut self.bus, action) {
            (BusSide::Sim(bus), LineAction::SetBaud(baud)) => bus.set_host_baud(baud),
            (BusSide::Sim(bus), LineAction::BreakStart) => {
                // The node ends the break BREAK_MS later; the simulated line takes it whole.
                bus.host_break(now, u64::from(BREAK_MS) * 1_000);
            }
            (BusSide::Sim(_), LineAction::BreakEnd) => {}
            (BusSide::Sim(bus), LineAction::CommChange) => {
                bus.host_send(now, &COMM_CHANGE);
            }
            (BusSide::Device { port }, LineAction::SetBaud(baud)) => {
                port.drain()?;
                port.set_rate(baud.bits_per_second())?;
            }
            (BusSide::Device { port }, LineAction::BreakStart) => {
                port.drain()?;
                port.set_break(true)?;
            }
            (BusSide::Device { port }, LineAction::BreakEnd) => port.set_break(false)?,
            (BusSide::Device { port }, LineAction::CommChange) => port.send(&COMM_CHANGE)?,
        }
        Ok(())
    }

    fn sleep(&self, until: Option<u64>) -> io::Result<()> {
        let now = self.now();
        let max_us = u64::try_from(self.max_sleep.as_micros()).unwrap_or(u64::MAX);
        let mut wake = now.saturating_add(max_us);
        if let Some(t) = until {
            wake = wake.min(t);
        }
        let mut fds: Vec<(BorrowedFd<'_>, bool)> = vec![(self.plc.fd(), self.plc.output_pending())];
        match &self.bus {
            BusSide::Sim(bus) => {
                if let Some(t) = bus.next_event() {
                    wake = wake.min(t.max(now + BUS_EVENT_GRAIN_US));
                }
            }
            BusSide::Device { port } => {
                fds.push((port.fd(), port.output_pending()));
            }
        }
        if wake <= now {
            return Ok(());
        }
        let stdin = io::stdin();
        if self.control.is_some() {
            fds.push((stdin.as_fd(), false));
        }
        port::wait(&fds, StdDuration::from_micros(wake - now))
    }

    fn read_control(&mut self, now: u64, buf: &mut [u8]) -> io::Result<Option<Ended>> {
        let Some(mut pending) = self.control.take() else {
            return Ok(None);
        };
        let result = self.read_control_lines(now, buf, &mut pending);
        self.control = Some(pending);
        result
    }

    fn read_control_lines(
        &mut self,
        now: u64,
        buf: &mut [u8],
        pending: &mut Vec<u8>,
    ) -> io::Result<Option<Ended>> {
        let stdin = io::stdin();
        if !port::readable(stdin.as_fd())? {
            return Ok(None);
        }
        // Readable: one read returns what is there without blocking (or 0 at the end).
        let n = match nix::unistd::read(stdin.as_fd(), buf) {
            Ok(n) => n,
            Err(nix::errno::Errno::EINTR | nix::errno::Errno::EAGAIN) => return Ok(None),
            Err(e) => return Err(e.into()),
        };
        if n == 0 {
            self.log.note(now, "standard input closed");
            return Ok(Some(Ended::InputClosed));
        }
        pending.extend_from_slice(buf.get(..n).unwrap_or(&[]));
        while let Some(end) = pending.iter().position(|&b| b == b'\n') {
            let line: Vec<u8> = pending.drain(..=end).collect();
            let line = String::from_utf8_lossy(&line);
            let Some(command) = control::parse(&line) else {
                continue;
            };
            let (answer, ended) = match command {
                Ok(command) => self.control(now, command),
                Err(error) => (json!({"ok": false, "error": error}), None),
            };
            let mut out = io::stdout().lock();
            writeln!(out, "{answer}")?;
            out.flush()?;
            if ended.is_some() {
                return Ok(ended);
            }
        }
        Ok(None)
    }

    /// Carry out a control command: its answer, and whether the run ends.
    pub fn control(&mut self, now: u64, command: Control) -> (Value, Option<Ended>) {
        match command {
            Control::Alarm(axis, code) => match &mut self.bus {
                BusSide::Sim(bus) => match bus.inject_alarm(axis, code) {
                    Ok(()) => {
                        self.log.note(
                            now,
                            &format!("alarm {:02X} injected on axis {}", code.0, axis.get()),
                        );
                        (json!({"ok": true, "cmd": "alarm"}), None)
                    }
                    Err(_) => (
                        json!({"ok": false, "error": format!(
                            "no simulated axis {}, or {:02X} is not an error code (80-FF)",
                            axis.get(), code.0)}),
                        None,
                    ),
                },
                BusSide::Device { .. } => (
                    json!({"ok": false, "error": "alarms can be injected on a simulated bus only"}),
                    None,
                ),
            },
            Control::Stats => (self.stats(now), None),
            Control::StopInput(active) => {
                self.node.set_stop_input(Instant(now), active);
                (json!({"ok": true, "cmd": "stop-input"}), None)
            }
            Control::Quit => (json!({"ok": true, "cmd": "quit"}), Some(Ended::Quit)),
            Control::Help => (json!({"ok": true, "help": HELP}), None),
        }
    }

    /// What `stats` answers.
    pub fn stats(&self, now: u64) -> Value {
        let slave = self.node.plc_counters();
        let receiver = self.node.receiver_counters();
        let gateway = self.node.gateway();
        let config = gateway.config();
        let axes: Vec<Value> = config
            .bus
            .axes
            .iter()
            .map(|axis| {
                let i = usize::from(axis.get());
                let sent = self.sent.get(i).cloned().unwrap_or_default();
                let commands: u64 = sent
                    .iter()
                    .filter(|(mnemonic, _)| !matches!(**mnemonic, "n" | "R4"))
                    .map(|(_, count)| count)
                    .sum();
                let (state, reason) = gateway.command_state(axis);
                let link = match gateway.engine().axis(axis).link {
                    Link::Unknown => "unknown",
                    Link::Online => "online",
                    Link::Offline => "offline",
                };
                let mut entry = json!({
                    "axis": i,
                    "sent": sent,
                    "commands": commands,
                    "cmst": state as u16,
                    "cmer": reason,
                    "link": link,
                });
                let scale = Some(config.axes[axis].scale);
                if let (Some(c), Some(scale), Value::Object(map)) = (
                    self.sim().and_then(|bus| bus.controller(axis)),
                    scale,
                    &mut entry,
                ) {
                    let position = c.position();
                    let wire = Pulses(i32::try_from(position).unwrap_or(i32::MAX));
                    map.insert("frames_received".into(), c.stats().frames_addressed.into());
                    map.insert("moving".into(), c.moving().into());
                    map.insert("homing".into(), c.homing().into());
                    map.insert("homed".into(), c.homed().into());
                    map.insert("servo".into(), c.servo().into());
                    map.insert("alarm".into(), c.alarm().0.into());
                    map.insert("position".into(), position.into());
                    map.insert(
                        "position_mm100".into(),
                        scale.position_from_wire(wire).0.into(),
                    );
                    map.insert("last_move_start".into(), c.last_move_start().into());
                    let nv = &c.memory().nv;
                    let stores: u64 = nv.point_writes.iter().map(|&n| u64::from(n)).sum();
                    map.insert(
                        "nv_writes".into(),
                        (stores + u64::from(nv.common_writes)).into(),
                    );
                }
                entry
            })
            .collect();
        json!({
            "ok": true,
            "cmd": "stats",
            "time_us": now,
            "failsafe": gateway.failsafe(),
            "modbus": {
                "frames": slave.frames,
                "replies": slave.replies,
                "crc_errors": slave.crc_errors,
                "too_short": slave.too_short,
                "too_long": slave.too_long,
                "bad_gaps": slave.bad_gaps,
                "ignored": slave.ignored,
                "malformed": slave.malformed,
                "broadcasts": slave.broadcasts,
                "exceptions": [
                    slave.illegal_function,
                    slave.illegal_data_address,
                    slave.illegal_data_value,
                    slave.server_device_failure,
                ],
                "overruns": receiver.overruns,
            },
            "axes": axes,
        })
    }
}
