//! The RS485 line: a half-duplex bus with the host (the gateway) and up to 16 controllers, in
//! virtual time.
//!
//! # Wire model
//! A transmission is a run of bytes from one talker at one baud rate; byte `k` occupies the
//! line for 10 bit times ([`super::wire`]) and is received by every *other* node when its stop
//! bit ends. Controllers hear the host and each other (and ignore responses, §3). With
//! [`BusConfig::host_echo`] the host also hears its own bytes, as with a transceiver whose
//! receiver is always enabled (see `Deframer::expect_echo`).
//!
//! Nobody listens before talking: a controller answers RTIM after the command whatever the line
//! is doing, and the host sends when told to (after its own previous transmission or break).
//! **Collision**: a byte whose time on the line overlaps another talker's transmission (or a
//! break, or noise) is garbled for every receiver (random bits flipped; never the byte sent).
//! Both transmissions are therefore corrupted; each overlapping pair counts once in
//! [`BusStats::collisions`], each garbled byte in [`BusStats::collided_bytes`]. The host hears
//! the garbled bytes even while it is talking (it reads the line), so a collision shows up as
//! garbage, never as silence.
//!
//! A controller does not receive while it transmits (its receiver is disabled with its driver,
//! the usual 2-wire wiring).
//!
//! **Baud rates**: a receiver at another rate than the sender does not understand the bytes.
//! Controllers drop them ([`super::controller`]). The host gets one garbage byte per byte sent
//! ([`BusStats::host_wrong_baud_bytes`]): 0xFF when the sender is faster (the receiver samples
//! mostly idle line), 0x00 when it is slower (the receiver samples one long start bit). Noise
//! bytes are read as they are at any rate.
//!
//! **Break** ([`Bus::host_break`]): the line held low. At its end every controller for which it
//! lasted more than 10 of its bit times returns to 9.6 kbit/s and RTIM 255 ms (§2, §7-2-1).
//!
//! # Driving it
//! [`Bus::next_event`] says when something next happens on the line (a byte arriving, a reply
//! starting, a break ending, a power event); [`Bus::advance`] runs to a time and returns what
//! the host received. Motion needs no events: controllers compute their state lazily at any
//! time. A real-time adapter can therefore call `advance(clock_now)` whenever it wakes, sleeping
//! until `next_event()` or until the host has bytes to send.

mod events;

use std::collections::BTreeSet;

use protocol::alarm::AlarmCode;
use protocol::line::Baud;
use protocol::Axis;

use super::controller::{Controller, ControllerConfig};
use super::fault::{FaultRngs, Faults};
use super::stats::BusStats;
use super::wire::{break_threshold, byte_offset, transmit_time};

/// Everything on the bus with a fixed set-up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BusConfig {
    /// Seed of every random fault.
    pub seed: u64,
    /// Random faults.
    pub faults: Faults,
    /// Whether the host hears its own transmissions.
    pub host_echo: bool,
    /// The host's line rate at the start.
    pub host_baud: Baud,
    /// Whether bytes take their time on the wire (10 bit times each). Off, every transmission
    /// arrives whole the moment it starts: a pseudo-terminal or a USB adapter in front of a
    /// master hides the wire's time from it, and a benchmark that must hold on such a line
    /// runs the simulator this way (`rc-sim --no-wire-time`). RTIM still applies.
    pub wire_time: bool,
}

impl Default for BusConfig {
    fn default() -> Self {
        BusConfig {
            seed: 0x5EED,
            faults: Faults::default(),
            host_echo: false,
            host_baud: Baud::B9600,
            wire_time: true,
        }
    }
}

/// Who is driving the line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Source {
    /// The host (gateway).
    Host,
    /// A controller.
    Axis(Axis),
    /// Injected noise.
    Noise,
    /// A break from the host.
    Break,
}

#[derive(Clone, Debug)]
struct Transmission {
    id: u64,
    source: Source,
    start: u64,
    end: u64,
    /// The rate receivers must be at to understand it; `None` for noise and breaks.
    baud: Option<Baud>,
    /// The rate that times its bytes.
    timing: Baud,
    /// Bytes take their wire time ([`BusConfig::wire_time`]).
    paced: bool,
    bytes: Vec<u8>,
    next: usize,
    /// A break has been applied to the controllers.
    applied: bool,
}

impl Transmission {
    fn next_arrival(&self) -> Option<u64> {
        (self.next < self.bytes.len()).then(|| self.start + self.offset(self.next + 1))
    }

    /// Start of byte `k`, relative to the start of the transmission.
    fn offset(&self, k: usize) -> u64 {
        if self.paced {
            byte_offset(k, self.timing)
        } else {
            0
        }
    }

    fn pending_event(&self) -> Option<u64> {
        match self.source {
            Source::Break if !self.applied => Some(self.break_detected_at()),
            _ => self.next_arrival(),
        }
    }

    /// When the controllers act on a break: once it has lasted 10 bit times at 9.6 kbit/s
    /// (enough at every rate), or when it ends if it is shorter.
    fn break_detected_at(&self) -> u64 {
        let detect = break_threshold(Baud::B9600);
        self.start + (self.end - self.start).min(detect)
    }

    fn finished(&self) -> bool {
        self.next >= self.bytes.len() && (self.source != Source::Break || self.applied)
    }
}

/// The bus: see the [module documentation](self).
#[derive(Clone, Debug)]
pub struct Bus {
    config: BusConfig,
    now: u64,
    host_baud: Baud,
    host_busy_until: u64,
    controllers: Vec<Option<Controller>>,
    silent: [bool; 16],
    /// Axes whose wire is cut: they hear nothing and answer nothing (and go on doing what they
    /// were doing).
    cut: [bool; 16],
    transmissions: Vec<Transmission>,
    next_id: u64,
    /// (time, axis, power on?)
    power_events: Vec<(u64, Axis, bool)>,
    host_rx: Vec<(u64, u8)>,
    collided: BTreeSet<(u64, u64)>,
    rngs: FaultRngs,
    stats: BusStats,
}

impl Bus {
    /// An empty bus at time 0.
    pub fn new(config: BusConfig) -> Bus {
        Bus {
            now: 0,
            host_baud: config.host_baud,
            host_busy_until: 0,
            controllers: (0..16).map(|_| None).collect(),
            silent: [false; 16],
            cut: [false; 16],
            transmissions: Vec::new(),
            next_id: 0,
            power_events: Vec::new(),
            host_rx: Vec::new(),
            collided: BTreeSet::new(),
            rngs: FaultRngs::new(config.seed),
            stats: BusStats::default(),
            config,
        }
    }

    /// A bus with a factory-configured controller at each of `axes`.
    pub fn with_axes(config: BusConfig, axes: &[Axis]) -> Bus {
        let mut bus = Bus::new(config);
        for &axis in axes {
            bus.add_controller(axis, ControllerConfig::default());
        }
        bus
    }

    /// Connect a controller (powered up now), replacing any at the same axis.
    pub fn add_controller(&mut self, axis: Axis, config: ControllerConfig) {
        if let Some(slot) = self.controllers.get_mut(usize::from(axis.get())) {
            *slot = Some(Controller::new(axis, config, self.now));
        }
    }

    /// The controller at `axis`.
    pub fn controller(&self, axis: Axis) -> Option<&Controller> {
        self.controllers
            .get(usize::from(axis.get()))
            .and_then(Option::as_ref)
    }

    /// The controller at `axis`, to change it (its time is the bus's).
    pub fn controller_mut(&mut self, axis: Axis) -> Option<&mut Controller> {
        self.controllers
            .get_mut(usize::from(axis.get()))
            .and_then(Option::as_mut)
    }

    /// Every controller, by axis.
    pub fn controllers(&self) -> impl Iterator<Item = &Controller> {
        self.controllers.iter().flatten()
    }

    /// The time the bus has run to (µs).
    pub fn now(&self) -> u64 {
        self.now
    }

    /// What has been counted.
    pub fn stats(&self) -> &BusStats {
        &self.stats
    }

    /// The set-up.
    pub fn config(&self) -> &BusConfig {
        &self.config
    }

    /// Change the random faults from now on (the generators carry on).
    pub fn set_faults(&mut self, faults: Faults) {
        self.config.faults = faults;
    }

    /// The host's line rate.
    pub fn host_baud(&self) -> Baud {
        self.host_baud
    }

    /// Switch the host's UART: later transmissions go out, and later bytes are read, at `baud`.
    pub fn set_host_baud(&mut self, baud: Baud) {
        self.host_baud = baud;
    }

    /// When the host's last transmission or break ends.
    pub fn host_busy_until(&self) -> u64 {
        self.host_busy_until
    }

    /// Make an axis silent (it executes commands but never answers) or not.
    pub fn set_silent(&mut self, axis: Axis, silent: bool) {
        if let Some(slot) = self.silent.get_mut(usize::from(axis.get())) {
            *slot = silent;
        }
    }

    /// Cut the wire to `axis` (it hears nothing and answers nothing, and an axis in motion
    /// keeps moving), or mend it.
    pub fn set_cut(&mut self, axis: Axis, cut: bool) {
        if let Some(slot) = self.cut.get_mut(usize::from(axis.get())) {
            *slot = cut;
        }
    }

    /// Cut the power of `axis` at `at` and restore it `off_for` µs later.
    pub fn schedule_power_cycle(&mut self, axis: Axis, at: u64, off_for: u64) {
        let at = at.max(self.now);
        self.power_events.push((at, axis, false));
        self.power_events
            .push((at.saturating_add(off_for), axis, true));
        self.power_events.sort_by_key(|&(t, _, on)| (t, on));
    }

    /// Raise an alarm on `axis` now. Fails for a missing axis or a code that is not an error.
    pub fn inject_alarm(&mut self, axis: Axis, code: AlarmCode) -> Result<(), AlarmCode> {
        let now = self.now;
        match self.controller_mut(axis) {
            Some(controller) => controller.inject_alarm(now, code),
            None => Err(code),
        }
    }

    /// Put `bytes` of noise on the line from `at` (not before now), timed at the host's rate and
    /// read as they are at any rate.
    pub fn inject_noise(&mut self, at: u64, bytes: &[u8]) {
        let start = at.max(self.now);
        let timing = self.host_baud;
        self.stats.noise_bursts += 1;
        self.stats.noise_bytes += bytes.len() as u64;
        self.push_transmission(Source::Noise, start, None, timing, bytes.to_vec());
    }

    /// The host sends `bytes` from `now` (not before the bus's time, and after its previous
    /// transmission or break). Random corruption of host bytes is decided here.
    /// Runs the bus up to `now` first; bytes received meanwhile are kept for the next
    /// [`advance`](Self::advance). Returns when the last byte has left.
    pub fn host_send(&mut self, now: u64, bytes: &[u8]) -> u64 {
        self.run(now);
        let start = now.max(self.now).max(self.host_busy_until);
        let mut bytes = bytes.to_vec();
        let p = self.config.faults.host_byte_corruption;
        let mut corrupted = 0;
        for byte in bytes.iter_mut() {
            let hit = self.rngs.corruption.chance(p);
            let mask = self.rngs.corruption.nonzero_byte();
            if hit {
                *byte ^= mask;
                corrupted += 1;
            }
        }
        self.stats.host_bytes_corrupted += corrupted;
        self.stats.host_frames_corrupted += u64::from(corrupted > 0);
        self.stats.host_transmissions += 1;
        self.stats.host_bytes_sent += bytes.len() as u64;
        let baud = self.host_baud;
        let end = self.push_transmission(Source::Host, start, Some(baud), baud, bytes);
        self.host_busy_until = end;
        end
    }

    /// The host holds the line low for `duration` µs from `now` (or when its previous
    /// transmission ends). Returns when the break ends.
    pub fn host_break(&mut self, now: u64, duration: u64) -> u64 {
        self.run(now);
        let start = now.max(self.now).max(self.host_busy_until);
        let end = start.saturating_add(duration);
        let id = self.next_id;
        self.next_id += 1;
        self.transmissions.push(Transmission {
            id,
            source: Source::Break,
            start,
            end,
            baud: None,
            timing: self.host_baud,
            paced: true,
            bytes: Vec::new(),
            next: 0,
            applied: false,
        });
        self.stats.breaks += 1;
        self.host_busy_until = end;
        end
    }

    fn push_transmission(
        &mut self,
        source: Source,
        start: u64,
        baud: Option<Baud>,
        timing: Baud,
        bytes: Vec<u8>,
    ) -> u64 {
        let paced = self.config.wire_time;
        let end = start
            + if paced {
                transmit_time(bytes.len(), timing)
            } else {
                0
            };
        let id = self.next_id;
        self.next_id += 1;
        self.transmissions.push(Transmission {
            id,
            source,
            start,
            end,
            baud,
            timing,
            paced,
            bytes,
            next: 0,
            applied: false,
        });
        end
    }

    /// When the next thing happens on the line, if anything is pending.
    pub fn next_event(&self) -> Option<u64> {
        let transmissions = self
            .transmissions
            .iter()
            .filter_map(Transmission::pending_event);
        let replies = self
            .controllers
            .iter()
            .flatten()
            .filter(|c| c.powered())
            .filter_map(Controller::reply_due);
        let power = self.power_events.first().map(|&(t, _, _)| t);
        transmissions
            .chain(replies)
            .chain(power)
            .min()
            .map(|t| t.max(self.now))
    }

    /// Run the bus up to `until` and return the bytes the host received, with their arrival
    /// times, since the last call. Times before [`now`](Self::now) are treated as now.
    pub fn advance(&mut self, until: u64) -> Vec<(u64, u8)> {
        self.run(until);
        std::mem::take(&mut self.host_rx)
    }
}
