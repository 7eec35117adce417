//! The one object the firmware drives: the whole gateway behind two serial lines and a few
//! pins.
//!
//! A [`Node`] owns the [`Gateway`] (the bus master and the PLC's register map), the Modbus RTU
//! port toward the PLC (frame receiver, slave, reply buffer) and the PIO logic of the axis the
//! discrete I/O drives. The firmware (or the PC gateway, or a test) only moves bytes and pin
//! levels in and out, stamped with the time:
//!
//! | In | Out |
//! |---|---|
//! | [`bus_received`](Node::bus_received): bytes from the RS485 bus | [`Action::Bus`]: a frame for the bus |
//! | [`plc_received`](Node::plc_received): bytes from the PLC line | [`Action::Reply`]: a Modbus reply for the PLC |
//! | [`sample_inputs`](Node::sample_inputs): the PIO input pins | [`outputs`](Node::outputs): the PIO output pins |
//! | [`set_stop_input`](Node::set_stop_input): the stop input | [`Action::Line`]: break start/end, rate change, broadcast |
//! | [`poll`](Node::poll) with the time | [`poll_at`](Node::poll_at): when to poll next |
//!
//! # The hardware contract
//!
//! - **Time** is a monotonic count of microseconds ([`Instant`]), the same clock for every
//!   call. Stamp received bytes with the time they were read from the UART, as soon as they
//!   are: a stamp may be late (the engine then only waits a little longer), never early.
//! - **Ingress before egress**: hand over everything that has arrived (both lines, the inputs)
//!   before calling [`poll`](Node::poll), then call it until it returns `None`. Each action is
//!   carried out before the next call.
//! - **[`Action::Bus`]**: write the 16 bytes and wait until the last one has left the shift
//!   register (`flush`, transmission complete) before releasing the driver (DE) and listening:
//!   the answer can start RTIM (3 ms) after the command's last stop bit.
//! - **[`Action::Reply`]**: write it on the PLC line; the caller may go on with other actions
//!   while it is on the wire (255 bytes take 2.3 s at 1.2 kbit/s), as long as it flushes it and
//!   releases DE before it hands the node any more PLC bytes (the PLC answers only after the
//!   reply, and the receiver is off while the driver is on), before [`Action::PlcLine`] and
//!   before [`Action::Settings`]. The PLC watchdog counts the PLC's silence from the reply's end,
//!   at the line's rate.
//! - **[`Action::Line`]**: [`LineAction::SetBaud`] only after the previous transmission has been
//!   flushed (a rate change mid-byte garbles it); [`LineAction::BreakStart`] holds the bus' TX
//!   low (the driver enabled) until [`LineAction::BreakEnd`]; [`LineAction::CommChange`] writes
//!   [`COMM_CHANGE`](crate::frame::COMM_CHANGE) (nobody answers).
//! - **[`Action::PlcLine`]**: flush the reply before, then switch the PLC UART's rate and parity.
//! - **[`Action::Settings`]**: write the settings record to flash (or erase it, or restart) when
//!   asked, never otherwise; report a save with [`Node::stored`].
//! - **`Action::Update`** (feature `update`): erase, write or finish the DFU partition as the
//!   job says, never outside it, then report with `Node::update_done`. The node is polled
//!   meanwhile: a long job (an erase of many pages) is carried out in steps between the node's
//!   other actions, or by another task, and reported once it is whole. It is handed out only
//!   when no frame is due on the bus and the bus is quiet (`Node::quiet_for_flash`: nothing
//!   moves, waits or is owed a stop), and a step that stalls the caller must be taken only
//!   then too: a stop never waits behind one.
//! - **Inputs** are sampled every millisecond or so ([`sample_inputs`](Node::sample_inputs));
//!   the PIO's debounce and settle times count in the samples' times. The outputs are valid at
//!   any time ([`outputs`](Node::outputs)), and all OFF (the safe state: *ALM OFF shows an
//!   alarm) until the axis has answered.
//! - **Sleep** until [`poll_at`](Node::poll_at) or until something arrives. Polling early is
//!   harmless; polling late only delays the bus (and the Modbus reply past t3.5).
//!
//! # The loop
//!
//! ```
//! use protocol::node::{Action, Node};
//! use protocol::line::LineAction;
//! use protocol::pio::PioInputs;
//! use protocol::plc::{Boot, GatewayConfig, SettingsRequest, IDENTITY};
//! use protocol::time::Instant;
//! use protocol::AxisSet;
//!
//! /// Stand-ins for the board: two half-duplex UARTs, the input pins and a clock.
//! #[derive(Default)]
//! struct Board { now: u64, bus_tx: Vec<u8>, plc_tx: Vec<u8>, break_held: bool }
//! impl Board {
//!     fn now(&self) -> Instant { Instant(self.now) }
//!     fn bus_rx(&mut self, _buf: &mut [u8]) -> usize { 0 }
//!     fn plc_rx(&mut self, _buf: &mut [u8]) -> usize { 0 }
//!     fn input_pins(&self) -> u16 { PioInputs::STP_N.bits() }
//!     fn bus_write_and_flush(&mut self, bytes: &[u8]) { self.bus_tx.extend_from_slice(bytes) }
//!     fn plc_write_and_flush(&mut self, bytes: &[u8]) { self.plc_tx.extend_from_slice(bytes) }
//!     fn set_bus_baud(&mut self, _bps: u32) {}
//!     fn hold_bus_tx_low(&mut self, low: bool) { self.break_held = low }
//!     fn write_output_pins(&mut self, _bits: u16) {}
//!     fn set_plc_line(&mut self, _bps: u32) {}
//!     fn write_settings(&mut self, _record: &[u8]) -> Result<u32, ()> { Ok(1) }
//!     fn restart(&mut self) {}
//!     fn sleep_until(&mut self, deadline: Option<Instant>) {
//!         self.now = deadline.map_or(self.now + 1_000, |t| t.0.max(self.now)).min(self.now + 1_000);
//!     }
//! }
//!
//! // In the firmware the node (about 11 KB) is built once, in place, and lives as long as it.
//! let mut config = GatewayConfig::new(AxisSet::first(2));
//! config.bus.establish = false;
//! let mut node = Node::new(config, &IDENTITY, Boot::DEFAULT);
//! let mut board = Board::default();
//! let mut buf = [0u8; 64];
//! for _ in 0..50 {
//!     let now = board.now();
//!     // Ingress: everything that arrived, stamped.
//!     let n = board.bus_rx(&mut buf);
//!     node.bus_received(now, &buf[..n]);
//!     let n = board.plc_rx(&mut buf);
//!     node.plc_received(now, &buf[..n]);
//!     node.sample_inputs(now, PioInputs::from_bits(board.input_pins()));
//!     // Egress: until there is nothing left to do now.
//!     while let Some(action) = node.poll(now) {
//!         match action {
//!             Action::Bus(frame) => board.bus_write_and_flush(&frame),
//!             Action::Reply(bytes) => board.plc_write_and_flush(bytes),
//!             Action::Line(LineAction::SetBaud(baud)) => board.set_bus_baud(baud.bits_per_second()),
//!             Action::Line(LineAction::BreakStart) => board.hold_bus_tx_low(true),
//!             Action::Line(LineAction::BreakEnd) => board.hold_bus_tx_low(false),
//!             Action::Line(LineAction::CommChange) => {
//!                 board.bus_write_and_flush(&protocol::frame::COMM_CHANGE)
//!             }
//!             Action::PlcLine(line) => board.set_plc_line(line.baud.bits_per_second()),
//!             Action::Settings(SettingsRequest::Save) => {
//!                 let saved = board.write_settings(&node.settings_record());
//!                 node.stored(saved);
//!             }
//!             Action::Settings(SettingsRequest::FactoryReset | SettingsRequest::Restart) => board.restart(),
//!             // A board with Ethernet (feature `tcp`) sends or closes on its sockets.
//!             #[cfg(feature = "tcp")]
//!             Action::Tcp(_) => {}
//!             // A board with a DFU partition (feature `update`) erases or writes it, then
//!             // reports (`Node::update_done`).
//!             #[cfg(feature = "update")]
//!             Action::Update(_) => node.update_done(Ok(())),
//!         }
//!     }
//!     board.write_output_pins(node.outputs().bits());
//!     board.sleep_until(node.poll_at());
//! }
//! // Nobody answers on this bench: the node polled both axes (and retried) meanwhile.
//! assert!(board.bus_tx.len() >= 2 * 16);
//! assert!(board.bus_tx.starts_with(b"\x020n"));
//! ```

use crate::engine::{JobKind, Output};
use crate::frame::FRAME_LEN;
use crate::line::{Baud, LineAction};
use crate::memory::PointField;
use crate::modbus::{
    chars_time, t3_5, Handled, Identity, Receiver, ReceiverCounters, ReplyBuffer, Slave,
    SlaveCounters,
};
use crate::pio::{self, Band, Jog, Pattern, Pio, PioInputs, PioOutputs};
use crate::plc::{Boot, Gateway, GatewayConfig, PlcLine, SettingsRequest, PIO_ACCEL};
use crate::time::{earliest, Duration, Instant};
use crate::units::{Accel, Length};
use crate::{Axis, PositionNo, Pulses};

#[cfg(feature = "tcp")]
use crate::modbus::tcp::SocketHandle;

mod discrete;
#[cfg(feature = "tcp")]
mod tcp;
#[cfg(feature = "tcp")]
pub use tcp::TcpAction;
#[cfg(feature = "tcp")]
use tcp::TcpPort;

/// The most the whole node may take on a microcontroller: 12 KiB for 16 axes (an STM32F103C8
/// has 20 KiB of RAM in all); 16 KiB with the Modbus TCP side (feature `tcp`: five connection
/// buffers, a slave and a reply of its own; only on boards with Ethernet, which have far more
/// RAM). Checked at compile time on the firmware's targets; the host test
/// `the_whole_state_fits_12_kib` prints the figures.
pub const RAM_BUDGET: usize = if cfg!(feature = "tcp") {
    16 * 1024
} else {
    12 * 1024
};

#[cfg(target_os = "none")]
const _: () = assert!(core::mem::size_of::<Node>() <= RAM_BUDGET);

/// What the caller does next; see the [hardware contract](self#the-hardware-contract).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Action<'a> {
    /// Transmit this frame on the RS485 bus, then flush.
    Bus([u8; FRAME_LEN]),
    /// Do this to the RS485 line.
    Line(LineAction),
    /// Transmit this Modbus reply on the PLC line, then flush.
    Reply(&'a [u8]),
    /// Switch the PLC line to these settings (APPLY changed them; the reply that asked for it
    /// has been handed out before, at the old settings: flush it first).
    PlcLine(PlcLine),
    /// Do this with the flash (SAVE, FACTORY, RESTART), then report a save with
    /// [`Node::stored`]. A factory reset and a restart end with the board restarting.
    Settings(SettingsRequest),
    /// Do this on a Modbus TCP socket (feature `tcp`).
    #[cfg(feature = "tcp")]
    Tcp(TcpAction),
    /// Do this to the DFU partition (feature `update`), then report how it went with
    /// [`Node::update_done`]; the node goes on meanwhile ([`plc::update`](crate::plc::update)).
    #[cfg(feature = "update")]
    Update(crate::plc::update::UpdateJob<'a>),
}

/// The state of the indicator LEDs (besides a run LED the firmware blinks itself).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Indicators {
    /// Every configured axis answers.
    pub link: bool,
    /// A fail-safe is latched, or an axis is in alarm or offline.
    pub alarm: bool,
}

/// The gateway behind its two lines and its pins; see the [module documentation](self).
#[derive(Debug)]
pub struct Node {
    gateway: Gateway,
    receiver: Receiver,
    slave: Slave,
    reply: ReplyBuffer,
    pio: Pio,
    outputs: PioOutputs,
    #[cfg(feature = "tcp")]
    tcp: TcpPort,
    /// When the gateway is due next, as of its last idle answer.
    idle_until: Option<Instant>,
    /// Something arrived since that answer: poll now.
    dirty: bool,
}

/// The silence that ends a frame on the PLC line: t3.5 of `baud`, or `gap` where one is
/// configured ([`GatewayConfig::plc_frame_gap`]). Its receiver has no t1.5 check (see
/// [`Node::new`]).
// Not inlined: `Node::new` and a line change share it (a copy in each took 96 B more of the
// F103's flash).
#[inline(never)]
const fn plc_frame_end(baud: u32, gap: Option<Duration>) -> Duration {
    match gap {
        Some(gap) => gap,
        None => t3_5(baud),
    }
}

impl Node {
    /// A node for `config`, the gateway being `identity` (FC2B/0E, FC11, VERSION) and started
    /// as `boot` says (CFGSOURCE, CFGERRORS, RESETCAUSE, SAVECOUNT): the firmware's facts, which
    /// are no settings. The Modbus receiver's t3.5 follows `config.settings.plc.baud`; its t1.5 gap
    /// check is off, since byte stamps taken when a task reads the UART are not accurate to the
    /// 750 µs it needs (the CRC still rejects a garbled frame).
    ///
    /// Built where its caller's result goes, without a node-sized temporary. Const as well, for
    /// a node in a `static` where flash is no object.
    // Not inlined, so that the caller hands its destination over as the return slot, and so
    // are `Gateway::new` and `Engine::new` below it (measured on the MCU: inlined, the
    // constructors' parts were temporaries, 6 to 11 KB of stack).
    #[inline(never)]
    pub const fn new(config: GatewayConfig, identity: &'static Identity, boot: Boot) -> Node {
        Node {
            gateway: Gateway::new(config, identity, boot),
            receiver: Receiver::with_timing(
                None,
                plc_frame_end(
                    config.settings.plc.baud.bits_per_second(),
                    config.plc_frame_gap,
                ),
            ),
            slave: Slave::new(),
            reply: ReplyBuffer::new(),
            pio: Pio::new(pio::Config::DEFAULT),
            outputs: PioOutputs::SAFE,
            #[cfg(feature = "tcp")]
            tcp: TcpPort {
                server: crate::modbus::tcp::Server::new(),
                slave: Slave::new(),
                reply: ReplyBuffer::new(),
            },
            idle_until: None,
            dirty: true,
        }
    }

    /// Bytes received on the RS485 bus at `now`.
    pub fn bus_received(&mut self, now: Instant, bytes: &[u8]) {
        // Only a completed frame (or a rejected candidate) gives `poll` something new to do:
        // the bytes before it are the deframer's alone.
        if self.gateway.receive(now, bytes) {
            self.dirty = true;
        }
    }

    /// Bytes received on the PLC line at `now`.
    pub fn plc_received(&mut self, now: Instant, bytes: &[u8]) {
        self.plc_received_between(now, now, bytes);
    }

    /// Bytes received on the PLC line after `since` and by `now`: read from a UART's buffer at
    /// `now` by a caller that last found it empty at `since` (it was sending meanwhile). A frame
    /// whose bytes waited is kept whole ([`modbus::rtu`](crate::modbus::rtu)).
    pub fn plc_received_between(&mut self, since: Instant, now: Instant, bytes: &[u8]) {
        self.receiver.push_between(since, now, bytes);
    }

    /// The stop input at `now`: `active` when it is OFF (a safety input).
    pub fn set_stop_input(&mut self, now: Instant, active: bool) {
        self.gateway.set_stop_input(now, active);
        self.dirty = true;
    }

    /// What to do at `now`, if anything: a Modbus reply first (the PLC waits for it), then the
    /// bus. Call until `None`, carrying out each action before the next call.
    // Not inlined: in the firmware's loop, inlined, it took 152 B more of the F103's flash
    // (`scripts/size-report.sh`).
    #[inline(never)]
    pub fn poll(&mut self, now: Instant) -> Option<Action<'_>> {
        // Nothing new and nothing due: the common case on the firmware's wakes between the bytes
        // of a frame and between input samples, which must stay cheap (the gateway's poll
        // itself looks at every axis).
        match self.poll_at() {
            Some(at) if now >= at => {}
            _ => return None,
        }
        let link = self.link_counters();
        let model = self.gateway.registers(now, link);
        // TCPCONN and TCPLINK read the same over the serial line as over TCP.
        #[cfg(feature = "tcp")]
        let model = model.with_tcp(crate::plc::TcpView {
            counters: self.tcp.server.counters(),
            connections: self.tcp.server.connections(),
        });
        let mut model = model;
        let handled = self
            .slave
            .poll(&mut self.receiver, now, &mut model, &mut self.reply);
        if let Some(Ok(handled @ (Handled::Reply(_) | Handled::Broadcast | Handled::Silent))) =
            handled
        {
            // Any valid request to the gateway or its axes is the PLC's sign of life, whether
            // it reads, writes, asks for an echo, gets an exception or no answer (Listen Only).
            // Its silence counts from the end of the reply: the PLC cannot ask again before
            // (at 1.2 kbit/s a 125-register reply takes 2.3 s, longer than the watchdog's 1 s).
            self.dirty = true;
            if let Handled::Reply(_) = handled {
                let reply = self.reply.as_bytes();
                let on_wire = chars_time(
                    reply.len(),
                    self.gateway.config().settings.plc.baud.bits_per_second(),
                );
                self.gateway.plc_activity(now, now + on_wire);
                return Some(Action::Reply(reply));
            }
            self.gateway.plc_activity(now, now);
        }
        #[cfg(feature = "tcp")]
        if let Some(action) = self.poll_tcp(now) {
            return Some(Action::Tcp(action));
        }
        if let Some(line) = self.gateway.take_plc_line() {
            let end = plc_frame_end(
                line.baud.bits_per_second(),
                self.gateway.config().plc_frame_gap,
            );
            self.receiver.set_frame_end(end);
            return Some(Action::PlcLine(line));
        }
        if let Some(store) = self.gateway.take_settings_request() {
            return Some(Action::Settings(store));
        }
        match self.gateway.poll(now) {
            Output::Transmit(frame) => Some(Action::Bus(frame.to_bytes())),
            Output::Line(action) => Some(Action::Line(action)),
            Output::Idle(until) => {
                self.idle_until = until;
                // The flash work of a firmware update, when the bus has nothing to send at once
                // (a stop goes first). The node does not wait for it: the caller reports it.
                #[cfg(feature = "update")]
                if let Some(job) = self.gateway.take_update_job() {
                    return Some(Action::Update(job));
                }
                self.dirty = false;
                None
            }
        }
    }

    /// The settings record to store for [`SettingsRequest::Save`]: the settings in force with the
    /// pending ones. Asked for when the save is carried out, not carried in the action: 213
    /// bytes less in every action and in the node.
    pub fn settings_record(&self) -> [u8; crate::plc::settings::RECORD_LEN] {
        self.gateway.settings_record()
    }

    /// How the save asked for by [`Action::Settings`] went: the new save count, or a failure
    /// (SAVESTAT shows it).
    pub fn stored(&mut self, result: Result<u32, ()>) {
        self.gateway.stored(result);
    }

    /// The board and its DFU partition (feature `update`): until the caller says, the PLC link
    /// cannot send an image (UPDCTL answers 02).
    #[cfg(feature = "update")]
    pub fn set_update_target(&mut self, target: crate::plc::update::Target) {
        self.gateway.set_update_target(target);
    }

    /// What the bootloader did at this start (feature `update`; BOOTSTAT): the running
    /// firmware confirmed, on trial, or the old one back after a trial that never confirmed. The
    /// caller tells it at the start and again once it confirms a trial.
    #[cfg(feature = "update")]
    pub fn set_boot_state(&mut self, state: crate::plc::update::BootState) {
        self.gateway.set_boot_state(state);
    }

    /// Whether a firmware on trial has shown it works (feature `update`): the bus's
    /// establishment is over (the axes found, or none answered) and the PLC link has had an
    /// answer from it (any Modbus reply, RTU or TCP: a tool that reads the version after the
    /// restart is enough). The caller then confirms the trial to the bootloader; until then a
    /// restart, a hang (the watchdog) or a power cut brings the old firmware back.
    #[cfg(feature = "update")]
    pub fn trial_passed(&self) -> bool {
        #[cfg(feature = "tcp")]
        let tcp = self.tcp_slave_counters().replies;
        #[cfg(not(feature = "tcp"))]
        let tcp = 0;
        !self.gateway.engine().establishing() && (self.plc_counters().replies > 0 || tcp > 0)
    }

    /// The version of the image a FINISH checked and marked for the next start (feature
    /// `update`; BOOTSTAT): `major << 24 | minor << 16 | patch`, from the image's signed
    /// trailer. Told with the report of the FINISH job.
    #[cfg(feature = "update")]
    pub fn set_image_version(&mut self, version: u32) {
        self.gateway.set_image_version(version);
    }

    /// How the job of [`Action::Update`] went (feature `update`). Reported once the job is
    /// done, at any later call: the node goes on meanwhile, and refuses the next chunk (04)
    /// until it hears.
    #[cfg(feature = "update")]
    pub fn update_done(&mut self, result: Result<(), crate::plc::update::UpdateError>) {
        self.gateway.update_done(result);
        self.dirty = true;
    }

    /// Whether the caller may take a step of the update's flash work now (feature `update`):
    /// nothing moves, waits or is owed a stop on the bus. A step stalls the caller (a page
    /// erase), so the stop rule holds only if the caller steps when this says so; the node
    /// hands out [`Action::Update`] under the same rule.
    #[cfg(feature = "update")]
    pub fn quiet_for_flash(&self) -> bool {
        self.gateway.quiet_for_flash()
    }

    /// The firmware update's transfer (feature `update`): its state, last error, progress.
    #[cfg(feature = "update")]
    pub fn update(&self) -> &crate::plc::update::Update {
        self.gateway.update()
    }

    /// The earliest moment anything is due: the bus engine's next deadline, the PLC watchdog,
    /// the end of a Modbus frame (t3.5 of silence). After input that [`poll`](Node::poll) has
    /// not seen yet, [`Instant::ZERO`]: poll now. `None`: nothing until something arrives.
    pub fn poll_at(&self) -> Option<Instant> {
        if self.dirty {
            return Some(Instant::ZERO);
        }
        let at = earliest(self.idle_until, self.receiver.next_deadline());
        #[cfg(feature = "tcp")]
        let at = earliest(
            at,
            self.tcp
                .server
                .poll_at(&self.gateway.config().settings.net.policy),
        );
        at
    }

    /// The PLC link's counters (PLCLINK): the serial line's, and TCP's added where there is
    /// TCP.
    fn link_counters(&self) -> SlaveCounters {
        let link = self.slave.counters();
        #[cfg(feature = "tcp")]
        let link = link.plus(&self.tcp.slave.counters());
        link
    }

    /// Until when the bus line's received bytes may stay in the UART buffer: the frame that has
    /// started is due whole then ([`Engine::frame_due`](crate::engine::Engine::frame_due)).
    /// `None`: read each byte as it comes. (The PLC line is read at once: Modbus frames end by
    /// silence, timed per byte.)
    pub fn bus_frame_due(&self) -> Option<Instant> {
        self.gateway.engine().frame_due()
    }

    /// The PIO output pins (bit n = PCON pattern 0 port OUTn): all OFF while the PIO axis has
    /// not answered, or none is configured (at once when the PLC takes the discrete I/O off its
    /// axis: with no PIO axis the firmware samples the inputs only when they change); *ALM OFF
    /// with FAILSAFE on PM1-PM8 while the fail-safe is latched
    /// ([`PioOutputs::with_failsafe`]).
    pub fn outputs(&self) -> PioOutputs {
        if self.gateway.config().settings.pio_axis.is_none() {
            return PioOutputs::SAFE;
        }
        self.outputs
            .with_failsafe(self.gateway.failsafe(), self.pio.config().pattern)
    }

    /// The rate the bus line is to run at: the UART starts at it (the node asks for every
    /// change after that with [`LineAction::SetBaud`]).
    pub fn bus_baud(&self) -> Baud {
        self.gateway.engine().line_baud()
    }

    /// The PLC line's settings: the UART starts at them (the node asks for every change after
    /// that with [`Action::PlcLine`]).
    pub fn plc_line(&self) -> PlcLine {
        self.gateway.config().settings.plc
    }

    /// How often the inputs must be sampled ([`sample_inputs`](Node::sample_inputs)): every
    /// [`pio::SAMPLE_PERIOD`] while a PIO axis is configured (the PIO's debounce and settle
    /// times count in its samples); `None` when only a change matters (the stop input: the
    /// PIO inputs then mean nothing).
    pub fn sample_period(&self) -> Option<Duration> {
        self.gateway
            .config()
            .settings
            .pio_axis
            .map(|_| pio::SAMPLE_PERIOD)
    }

    /// The indicator LEDs.
    pub fn indicators(&self) -> Indicators {
        Indicators {
            link: self.gateway.all_online(),
            alarm: self.gateway.alarm(),
        }
    }

    /// The gateway (for tests and tools: its engine, configuration and command states; feature
    /// `inspect`, a default one). The firmware builds without it: it asks the node itself
    /// ([`bus_baud`](Node::bus_baud), [`plc_line`](Node::plc_line),
    /// [`sample_period`](Node::sample_period)).
    #[cfg(feature = "inspect")]
    pub fn gateway(&self) -> &Gateway {
        &self.gateway
    }

    /// What the Modbus slave of the serial line has counted.
    pub fn plc_counters(&self) -> SlaveCounters {
        self.slave.counters()
    }

    /// What the Modbus frame receiver has counted.
    pub fn receiver_counters(&self) -> ReceiverCounters {
        self.receiver.counters()
    }

    /// The PIO logic (its recognised inputs).
    pub fn pio(&self) -> &Pio {
        &self.pio
    }
}
