//! The simulator in real time: a real bus master talks to simulated controllers through a
//! pseudo-terminal or a loopback TCP socket.
//!
//! [`RealTime`] owns a [`Bus`] and runs it against the wall clock. The master (the host-side
//! gateway, the firmware under QEMU, a person with a terminal program) sees a serial line with
//! controllers on it; the controllers see a host whose bytes arrive at the line rate. The
//! `rc-sim` binary is a command line around it.
//!
//! # Clock mapping
//! Virtual time is the bus's time when [`RealTime::run`] starts plus the microseconds of
//! [`Instant`] elapsed since, so one virtual µs is one real µs. Each pass of the loop:
//! 1. reads the termios speed of the pseudo-terminal (see *Baud rate* below);
//! 2. reads whatever bytes the master has written and hands each read to
//!    [`Bus::host_send`] at the current time: the bytes go out back to back at the host's line
//!    rate, from now or from the end of the host's previous transmission, so a frame written in
//!    one `write` takes its exact wire time (1.39 ms at 115.2 kbit/s) before the controllers
//!    have it;
//! 3. runs the bus to now ([`Bus::advance`]) and writes the bytes the host received to the
//!    master (kept in a queue while the master does not read; a full queue drops the oldest
//!    bytes, like a receiver overrun, counted in [`RealTimeStats::overrun_bytes`]);
//! 4. sleeps (`ppoll`, µs resolution) until the master writes, the next bus event
//!    ([`Bus::next_event`]: a byte arriving, a reply starting) or at most
//!    [`Options::max_sleep`], whichever comes first.
//!
//! **Limits.** Inside the simulator every time is exact: a reply starts exactly RTIM after the
//! last byte of the command was received, bytes are 10 bit times apart, collisions and faults
//! happen as in virtual time. What the host's scheduler adds is *delivery jitter* only: a byte
//! is written to the master when the loop wakes after the byte's arrival time, usually within
//! tens of µs, occasionally a few ms on a loaded machine ([`RealTimeStats::max_lag_us`]
//! records the worst), and a command counts from when the loop read it, not from when the master
//! wrote it. A master whose time-outs are the §5 ones (tens of ms) does not notice; a test of
//! sub-millisecond timing belongs in virtual time, not here. A pseudo-terminal or a socket has
//! no line rate of its own: bytes written by the master are available at once, and the
//! simulator alone paces them.
//!
//! # Baud rate
//! The host's rate starts at the bus's [`BusConfig::host_baud`]; [`bus_at_line`] builds a bus
//! whose host *and* controllers start at a given rate and RTIM (the controllers power up with
//! that BRSL/RTIM stored, [`ControllerConfig::stored_line`]), so that a master configured to
//! skip the establishment procedure (`establish = false`) talks to them at once.
//!
//! On a pseudo-terminal the master may change its rate: the terminal's termios (one set, shared
//! by every descriptor of the slave; on Linux `tcgetattr` on the master side returns it too)
//! holds the speed the master set with `tcsetattr`, as `serialport`, `stty` and QEMU's `serial`
//! character device do. Each pass reads it and, when it *changes* to one of the rates termios
//! can express (9600, 19200, 38400, 57600, 115200 bit/s), applies it with
//! [`Bus::set_host_baud`] ([`Options::follow_baud`], on by default). 14.4, 28.8 and 76.8 kbit/s
//! have no termios constant: for a master at those rates, give its rate as the starting rate
//! and turn `follow_baud` off. A speed set between two passes applies to every byte read in the
//! next pass. Over TCP the rate never changes.
//!
//! **QEMU.** The STM32L4x5 USART model passes the guest's rate (BRR) to its character device;
//! the `serial` backend opened on [`Pty::path`] (`-chardev serial,id=rs485,path=/dev/pts/N`)
//! turns it into the termios rate at or above 10/11 of it, so a firmware at a rate termios has
//! is followed, and one at 14.4, 28.8 or 76.8 kbit/s shows up as the next rate up (use
//! `follow_baud` off). QEMU's own `pty` backend and its `socket` backend (which can connect to
//! a [`TcpServer`]) carry bytes only. The model does not implement sending a break (SBKRQ).
//!
//! # Break
//! A break cannot be seen through either transport. Linux pseudo-terminals have no
//! `break_ctl`: `tcsendbreak` and `TIOCSBRK` on the slave succeed and do nothing, and the master
//! side sees no byte and no packet-mode event (checked on Linux 6.x; `PARMRK` only marks
//! breaks a *receiving* UART detected, which a pseudo-terminal never does). A raw TCP stream has
//! no out-of-band signal either, and no in-band escape is defined: every byte the master writes
//! is a byte on the line. So:
//! - the default is a master that does not establish: controllers power up at the line settings
//!   given (see above);
//! - [`Options::slow_baud_is_break`] (off by default, pseudo-terminal only) treats the master
//!   switching its speed *to* 9.6 kbit/s and then staying silent for [`BREAK_SILENCE_US`] as a
//!   break: the §6-1 procedure (and the gateway's engine) switches to 9.6 kbit/s right before
//!   its 200 ms break, during which it sends nothing, and after a break every controller is at
//!   9.6 kbit/s anyway, so the rest of the procedure (configuration at 9.6 kbit/s and RTIM
//!   255 ms, the communication-change broadcast, the switch to the new rate) then runs as on a
//!   real line. The emulated break starts when the silence has lasted [`BREAK_SILENCE_US`] and
//!   lasts [`EMULATED_BREAK_US`], more than 10 bit times at 9.6 kbit/s, so that it ends before
//!   the master's first byte after its own (invisible) break. A switch to 9.6 kbit/s followed
//!   by bytes sooner is a plain rate change: the gateway engine's rejoin probe of an offline
//!   axis at the power-up settings writes its probe at once, and must not knock every other
//!   axis back to 9.6 kbit/s. It is a heuristic still: a master that switches to 9.6 kbit/s and
//!   then idles for no reason breaks the line, and so does any switch to 9.6 kbit/s that the
//!   simulator only sees after it was not scheduled for a while (a loaded host), when the
//!   silence after it went unobserved.
//!
//! # Transports
//! - [`Pty`]: a pseudo-terminal pair. The master opens [`Pty::path`] (`/dev/pts/N`) as its
//!   serial port. The simulator keeps a slave descriptor open itself, so the terminal stays
//!   configured in raw mode at the starting speed between clients and the master side never
//!   sees a hang-up: the master may close and reopen the port at will, and the simulator runs
//!   until stopped. Bytes the simulator wrote while nobody read stay in the terminal's input
//!   queue until a client reads or flushes it.
//! - [`TcpServer`]: a listening socket on a loopback address (anything else is refused), raw
//!   bytes in both directions, one client at a time. When the client disconnects the run ends
//!   ([`Ended::Disconnected`]) unless [`Options::reconnect`] is set, in which case the next
//!   client is accepted and the bus carries on as it was (controllers keep their state, like a
//!   bus whose gateway was unplugged). A client that connects while another one is connected
//!   waits in the backlog.
//!
//! Either way the bus runs from the start of [`RealTime::run`], client or not.

mod control;
pub mod events;
mod log;
mod transport;

pub use control::Control;
pub use transport::{Pty, TcpServer, Transport};

use std::collections::VecDeque;
use std::io;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Receiver;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use protocol::line::Baud;
use protocol::{Axis, Rtim};

use super::bus::{Bus, BusConfig};
use super::controller::ControllerConfig;
use super::stats::BusStats;
pub use events::monotonic_us;
use events::EventLog;
use log::{stamp, FrameLog};
use transport::Input;

/// How long an emulated break lasts (µs): more than 10 bit times at 9.6 kbit/s (1042 µs), and
/// short enough to end before the master's next byte.
pub const EMULATED_BREAK_US: u64 = 2_000;

/// How long the master stays silent after switching to 9.6 kbit/s before the switch counts as
/// a break ([`Options::slow_baud_is_break`], µs): half the §6-1 break (200 ms), and far longer
/// than any master takes to write the frame it switched the rate for.
pub const BREAK_SILENCE_US: u64 = 100_000;

/// A pass of the loop later than this after the previous one (µs) means the simulator was not
/// scheduled in between (its passes are at most [`Options::max_sleep`] apart otherwise).
const STALL_US: u64 = 50_000;

/// Reads per pass of the loop, at most (4 KiB each).
const MAX_READS_PER_PASS: usize = 16;

/// How the adapter runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Options {
    /// Follow the pseudo-terminal's termios speed (see the [module documentation](self)).
    pub follow_baud: bool,
    /// Treat a switch of the pseudo-terminal's speed to 9.6 kbit/s as a break (a heuristic for
    /// masters that establish; see the [module documentation](self) for when it misfires).
    pub slow_baud_is_break: bool,
    /// TCP: accept another client after a disconnection instead of ending the run.
    pub reconnect: bool,
    /// End the run after this long, if set.
    pub duration: Option<Duration>,
    /// The longest sleep between two passes (how quickly a stop request is seen).
    pub max_sleep: Duration,
    /// Bytes kept for a master that does not read before the oldest are dropped.
    pub queue_limit: usize,
    /// Print every frame, decoded, and every line event on standard error.
    pub log: bool,
}

impl Default for Options {
    fn default() -> Options {
        Options {
            follow_baud: true,
            slow_baud_is_break: false,
            reconnect: false,
            duration: None,
            max_sleep: Duration::from_millis(5),
            queue_limit: 64 * 1024,
            log: false,
        }
    }
}

/// Why a run ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ended {
    /// The stop flag was raised.
    Stopped,
    /// [`Options::duration`] elapsed.
    Duration,
    /// The TCP client disconnected (without [`Options::reconnect`]).
    Disconnected,
}

/// What the adapter itself has counted (the bus counts the rest: [`Bus::stats`]).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RealTimeStats {
    /// Bytes read from the master.
    pub bytes_from_master: u64,
    /// Reads that returned bytes (each one transmission on the bus).
    pub reads: u64,
    /// Bytes written to the master.
    pub bytes_to_master: u64,
    /// Bytes dropped because the master did not read them.
    pub overrun_bytes: u64,
    /// Host rate changes followed from the pseudo-terminal.
    pub baud_changes: u64,
    /// Breaks emulated ([`Options::slow_baud_is_break`]).
    pub emulated_breaks: u64,
    /// TCP clients accepted.
    pub clients: u64,
    /// The latest the loop handled a byte for the master after its arrival on the line (µs).
    pub max_lag_us: u64,
}

/// A bus whose host and controllers (one at each of `axes`, otherwise factory-configured) all
/// start at `baud` and `rtim`, for a master that does not run the establishment procedure.
/// `config.host_baud` is replaced by `baud`.
pub fn bus_at_line(config: BusConfig, axes: &[Axis], baud: Baud, rtim: Rtim) -> Bus {
    let mut bus = Bus::new(BusConfig {
        host_baud: baud,
        ..config
    });
    for &axis in axes {
        bus.add_controller(
            axis,
            ControllerConfig {
                stored_line: Some((baud, rtim)),
                ..ControllerConfig::default()
            },
        );
    }
    bus
}

/// The simulator against the wall clock; see the [module documentation](self).
#[derive(Debug)]
pub struct RealTime {
    bus: Bus,
    options: Options,
    stats: RealTimeStats,
    queue: VecDeque<u8>,
    log: FrameLog,
    control: Option<Receiver<Control>>,
    /// The event log, if one was asked for ([`RealTime::set_events`]).
    events: Option<EventLog>,
    /// When the master switched to 9.6 kbit/s, while it has been silent since
    /// ([`Options::slow_baud_is_break`]).
    pending_break: Option<u64>,
}

impl RealTime {
    /// An adapter around `bus`.
    pub fn new(bus: Bus, options: Options) -> RealTime {
        RealTime {
            bus,
            options,
            stats: RealTimeStats::default(),
            queue: VecDeque::new(),
            log: FrameLog::default(),
            control: None,
            events: None,
            pending_break: None,
        }
    }

    /// Take [`Control`]s from `receiver` while running: each is applied at the next pass of
    /// the loop (within [`Options::max_sleep`]) and noted in the log.
    pub fn set_control(&mut self, receiver: Receiver<Control>) {
        self.control = Some(receiver);
    }

    /// Write the event log ([`events`]: commands, replies and moves, in
    /// `CLOCK_MONOTONIC` µs) to `out` while running.
    pub fn set_events(&mut self, out: Box<dyn io::Write + Send>) {
        self.events = Some(EventLog::new(out));
    }

    /// The bus.
    pub fn bus(&self) -> &Bus {
        &self.bus
    }

    /// The bus, to change it between runs.
    pub fn bus_mut(&mut self) -> &mut Bus {
        &mut self.bus
    }

    /// The bus, giving up the adapter.
    pub fn into_bus(self) -> Bus {
        self.bus
    }

    /// What the bus has counted.
    pub fn bus_stats(&self) -> &BusStats {
        self.bus.stats()
    }

    /// What the adapter has counted.
    pub fn stats(&self) -> &RealTimeStats {
        &self.stats
    }

    /// The options.
    pub fn options(&self) -> &Options {
        &self.options
    }

    /// Run the bus against the wall clock, talking to the master through `transport`, until
    /// `stop` is raised (checked at least every [`Options::max_sleep`]), the duration elapses or
    /// the TCP client leaves. Fails on an I/O error of the transport.
    pub fn run(&mut self, transport: &mut Transport, stop: &AtomicBool) -> io::Result<Ended> {
        let monotonic = monotonic_us();
        let started = Instant::now();
        let origin = self.bus.now();
        if let Some(events) = &mut self.events {
            events.sync(origin, monotonic);
        }
        let clock = |at: Instant| {
            let elapsed = at.saturating_duration_since(started).as_micros();
            origin.saturating_add(u64::try_from(elapsed).unwrap_or(u64::MAX))
        };
        let deadline = self.options.duration.map(|d| started + d);
        let mut buf = [0u8; 4096];
        let mut last_pass = clock(started);
        loop {
            let wall = Instant::now();
            let now = clock(wall);
            // This process did not run for a while (a loaded host): a rate change seen now may
            // be old, and the master's silence after it unobserved.
            let stalled = now.saturating_sub(last_pass) > STALL_US;
            last_pass = now;
            if stop.load(Ordering::Relaxed) {
                self.deliver(now, transport)?;
                self.flush_events()?;
                return Ok(Ended::Stopped);
            }
            if deadline.is_some_and(|d| wall >= d) {
                self.deliver(now, transport)?;
                self.flush_events()?;
                return Ok(Ended::Duration);
            }

            if let Some(baud) = transport.speed_change()? {
                self.line_rate(now, baud, stalled);
            }
            // Bounded, so that a master writing without pause cannot stall the bus.
            for _ in 0..MAX_READS_PER_PASS {
                match transport.read(&mut buf)? {
                    Input::Bytes(n) => {
                        let bytes = buf.get(..n).unwrap_or(&[]);
                        if self.pending_break.take().is_some() {
                            self.note(
                                now,
                                "bytes at once after the switch to 9600 bit/s: a rate change only",
                            );
                        }
                        self.stats.reads += 1;
                        self.stats.bytes_from_master += bytes.len() as u64;
                        if self.options.log {
                            self.log.host(now, bytes);
                        }
                        if let Some(events) = &mut self.events {
                            events.host(now, bytes)?;
                        }
                        self.bus.host_send(now, bytes);
                    }
                    Input::Connected(peer) => {
                        self.stats.clients += 1;
                        self.queue.clear();
                        self.note(now, &format!("client {peer} connected"));
                    }
                    Input::Closed => {
                        self.queue.clear();
                        self.note(now, "client disconnected");
                        if !self.options.reconnect {
                            self.bus.advance(now);
                            self.flush_events()?;
                            return Ok(Ended::Disconnected);
                        }
                    }
                    Input::Nothing => break,
                }
            }

            self.emulate_break(now);
            self.deliver(now, transport)?;
            self.apply_controls(now);

            let now = clock(Instant::now());
            let mut sleep = self.options.max_sleep;
            let pending_break = self.pending_break.map(|at| at + BREAK_SILENCE_US);
            for at in [self.bus.next_event(), pending_break].into_iter().flatten() {
                sleep = sleep.min(Duration::from_micros(at.saturating_sub(now)));
            }
            if let Some(d) = deadline {
                sleep = sleep.min(d.saturating_duration_since(Instant::now()));
            }
            transport.wait(sleep, !self.queue.is_empty())?;
        }
    }

    /// Run on a new thread until [`Handle::stop`] (or the end of the run).
    pub fn spawn(self, transport: Transport) -> io::Result<Handle> {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stop);
        let thread = std::thread::Builder::new()
            .name("rc-sim".into())
            .spawn(move || {
                let mut realtime = self;
                let mut transport = transport;
                let ended = realtime.run(&mut transport, &flag)?;
                Ok(Outcome { realtime, ended })
            })?;
        Ok(Handle {
            stop,
            thread: Some(thread),
        })
    }

    fn apply_controls(&mut self, now: u64) {
        let Some(receiver) = &self.control else {
            return;
        };
        let controls: Vec<Control> = receiver.try_iter().collect();
        for control in controls {
            match control.apply(&mut self.bus) {
                Ok(()) => self.note(now, &control.report(&self.bus)),
                Err(why) => self.note(now, &format!("control refused: {why}")),
            }
        }
    }

    fn line_rate(&mut self, now: u64, baud: Baud, stalled: bool) {
        if !self.options.follow_baud || baud == self.bus.host_baud() {
            return;
        }
        self.bus.set_host_baud(baud);
        self.stats.baud_changes += 1;
        self.note(now, &format!("master at {} bit/s", baud.bits_per_second()));
        self.pending_break =
            (self.options.slow_baud_is_break && baud == Baud::B9600).then_some(now);
        if stalled {
            // The silence that makes the switch a break may have passed unseen: take it as one
            // (a §6-1 break is the switch's usual reason).
            self.pending_break = self
                .pending_break
                .map(|at| at.saturating_sub(BREAK_SILENCE_US));
            self.emulate_break(now);
        }
    }

    /// A switch to 9.6 kbit/s followed by [`BREAK_SILENCE_US`] of silence is a break.
    fn emulate_break(&mut self, now: u64) {
        let Some(at) = self.pending_break else {
            return;
        };
        if now >= at + BREAK_SILENCE_US {
            self.pending_break = None;
            self.bus.host_break(now, EMULATED_BREAK_US);
            self.stats.emulated_breaks += 1;
            self.note(
                now,
                "break (emulated: master switched to 9600 bit/s, then silent)",
            );
        }
    }

    /// Run the bus to `now` and write what the host received to the master, as far as it
    /// takes it.
    fn deliver(&mut self, now: u64, transport: &mut Transport) -> io::Result<()> {
        let received = self.bus.advance(now);
        for &(at, byte) in &received {
            self.stats.max_lag_us = self.stats.max_lag_us.max(now.saturating_sub(at));
            self.queue.push_back(byte);
        }
        if self.options.log {
            self.log.master(&received);
        }
        if let Some(events) = &mut self.events {
            events.master(&received)?;
            events.moves(&self.bus)?;
        }
        let excess = self.queue.len().saturating_sub(self.options.queue_limit);
        if excess > 0 {
            self.queue.drain(..excess);
            self.stats.overrun_bytes += excess as u64;
        }
        self.flush(transport)
    }

    fn flush_events(&mut self) -> io::Result<()> {
        self.events.as_mut().map_or(Ok(()), EventLog::flush)
    }

    fn flush(&mut self, transport: &mut Transport) -> io::Result<()> {
        while !self.queue.is_empty() {
            let (front, _) = self.queue.as_slices();
            let written = transport.write(front)?;
            if written == 0 {
                break;
            }
            self.queue.drain(..written.min(self.queue.len()));
            self.stats.bytes_to_master += written as u64;
        }
        Ok(())
    }

    fn note(&self, now: u64, what: &str) {
        if self.options.log {
            eprintln!("{} -- {what}", stamp(now));
        }
    }
}

/// How a spawned run ended, with the adapter for its counters.
#[derive(Debug)]
pub struct Outcome {
    /// The adapter, its bus and counters as the run left them.
    pub realtime: RealTime,
    /// Why the run ended.
    pub ended: Ended,
}

/// A run on its own thread ([`RealTime::spawn`]). Dropping it stops the run and waits for the
/// thread, so that nothing outlives it.
#[derive(Debug)]
pub struct Handle {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<io::Result<Outcome>>>,
}

impl Handle {
    /// Ask the run to stop, wait for it, and return how it ended (it may have ended before).
    pub fn stop(self) -> io::Result<Outcome> {
        self.stop.store(true, Ordering::Relaxed);
        self.join()
    }

    /// Wait for the run to end by itself (duration, disconnection).
    pub fn join(mut self) -> io::Result<Outcome> {
        match self.thread.take() {
            Some(thread) => thread
                .join()
                .unwrap_or_else(|_| Err(io::Error::other("the simulator thread panicked"))),
            None => Err(io::Error::other("the simulator thread was already joined")),
        }
    }

    /// Whether the run has ended.
    pub fn is_finished(&self) -> bool {
        self.thread.as_ref().is_none_or(JoinHandle::is_finished)
    }
}

impl Drop for Handle {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}
