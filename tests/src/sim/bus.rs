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

use std::collections::BTreeSet;

use protocol::alarm::AlarmCode;
use protocol::frame::STX;
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
}

impl Default for BusConfig {
    fn default() -> Self {
        BusConfig {
            seed: 0x5EED,
            faults: Faults::default(),
            host_echo: false,
            host_baud: Baud::B9600,
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
    bytes: Vec<u8>,
    next: usize,
    /// A break has been applied to the controllers.
    applied: bool,
}

impl Transmission {
    fn next_arrival(&self) -> Option<u64> {
        (self.next < self.bytes.len()).then(|| self.start + byte_offset(self.next + 1, self.timing))
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

/// How long a finished transmission is kept for collision checks: two bytes at the slowest rate.
const KEEP_US: u64 = 2_100;

/// The bus: see the [module documentation](self).
#[derive(Clone, Debug)]
pub struct Bus {
    config: BusConfig,
    now: u64,
    host_baud: Baud,
    host_busy_until: u64,
    controllers: Vec<Option<Controller>>,
    silent: [bool; 16],
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
        let end = start + transmit_time(bytes.len(), timing);
        let id = self.next_id;
        self.next_id += 1;
        self.transmissions.push(Transmission {
            id,
            source,
            start,
            end,
            baud,
            timing,
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

    fn run(&mut self, until: u64) {
        while let Some(t) = self.next_event().filter(|&t| t <= until) {
            self.now = t;
            self.step(t);
        }
        self.now = self.now.max(until);
        let now = self.now;
        for controller in self.controllers.iter_mut().flatten() {
            controller.update(now);
        }
        self.prune();
    }

    /// Everything that happens at `t`.
    fn step(&mut self, t: u64) {
        while self.power_events.first().is_some_and(|&(at, _, _)| at <= t) {
            let (at, axis, on) = self.power_events.remove(0);
            self.power(at, axis, on);
        }
        while let Some(index) = self.next_arrival_at(t) {
            self.deliver(index, t);
        }
        let breaks: Vec<u64> = self
            .transmissions
            .iter_mut()
            .filter(|tx| tx.source == Source::Break && !tx.applied && tx.break_detected_at() <= t)
            .map(|tx| {
                tx.applied = true;
                tx.end - tx.start
            })
            .collect();
        for duration in breaks {
            for controller in self.controllers.iter_mut().flatten() {
                if controller.line_low(t, duration) {
                    self.stats.replies_cancelled += 1;
                }
            }
        }
        let due: Vec<usize> = self
            .controllers
            .iter()
            .enumerate()
            .filter_map(|(i, c)| c.as_ref().map(|c| (i, c)))
            .filter(|(_, c)| c.powered() && c.reply_due().is_some_and(|at| at <= t))
            .map(|(i, _)| i)
            .collect();
        for index in due {
            self.start_reply(index, t);
        }
    }

    fn next_arrival_at(&self, t: u64) -> Option<usize> {
        self.transmissions
            .iter()
            .enumerate()
            .filter_map(|(i, tx)| tx.next_arrival().map(|at| (at, tx.id, i)))
            .filter(|&(at, _, _)| at <= t)
            .min()
            .map(|(_, _, i)| i)
    }

    fn power(&mut self, at: u64, axis: Axis, on: bool) {
        let Some(controller) = self.controller_mut(axis) else {
            return;
        };
        if on {
            controller.power_on(at);
            return;
        }
        if controller.pending_reply().is_some() {
            self.stats.replies_cancelled += 1;
        }
        if let Some(controller) = self.controller_mut(axis) {
            controller.power_off(at);
        }
        self.stats.power_cycles += 1;
        // A reply on the line stops where it is.
        for tx in self.transmissions.iter_mut() {
            if tx.source == Source::Axis(axis) && tx.next < tx.bytes.len() {
                tx.bytes.truncate(tx.next);
                tx.end = at;
            }
        }
    }

    fn start_reply(&mut self, index: usize, t: u64) {
        let Some(controller) = self.controllers.get_mut(index).and_then(Option::as_mut) else {
            return;
        };
        let axis = controller.axis();
        let Some((bytes, baud)) = controller.take_reply(t) else {
            return;
        };
        let mut bytes = bytes.to_vec();
        let p = self.config.faults.reply_byte_corruption;
        let mut corrupted = 0;
        for byte in bytes.iter_mut() {
            let hit = self.rngs.corruption.chance(p);
            let mask = self.rngs.corruption.nonzero_byte();
            if hit {
                *byte ^= mask;
                corrupted += 1;
            }
        }
        self.stats.reply_bytes_corrupted += corrupted;
        self.stats.replies_corrupted += u64::from(corrupted > 0);
        self.stats.replies_sent += 1;
        self.push_transmission(Source::Axis(axis), t, Some(baud), baud, bytes);
    }

    /// Byte `next` of transmission `index` arrives at `t`.
    fn deliver(&mut self, index: usize, t: u64) {
        let Some(tx) = self.transmissions.get_mut(index) else {
            return;
        };
        let k = tx.next;
        tx.next += 1;
        let (id, source, baud, timing) = (tx.id, tx.source, tx.baud, tx.timing);
        let byte_start = tx.start + byte_offset(k, timing);
        let mut value = tx.bytes.get(k).copied().unwrap_or(0);
        let last = tx.next == tx.bytes.len();

        let overlapping: Vec<u64> = self
            .transmissions
            .iter()
            .filter(|o| o.id != id && o.start < t && o.end > byte_start)
            .map(|o| o.id)
            .collect();
        if !overlapping.is_empty() {
            value ^= self.rngs.collision.nonzero_byte();
            self.stats.collided_bytes += 1;
            for other in overlapping {
                if self.collided.insert((id.min(other), id.max(other))) {
                    self.stats.collisions += 1;
                }
            }
        }

        if source != Source::Host || self.config.host_echo {
            let received = match baud {
                Some(sent) if sent != self.host_baud => {
                    self.stats.host_wrong_baud_bytes += 1;
                    if sent.bits_per_second() > self.host_baud.bits_per_second() {
                        0xFF
                    } else {
                        0x00
                    }
                }
                _ => value,
            };
            self.host_rx.push((t, received));
            self.stats.bytes_to_host += 1;
        }

        let talking: Vec<Axis> = self
            .transmissions
            .iter()
            .filter(|o| o.start < t && o.end > byte_start)
            .filter_map(|o| match o.source {
                Source::Axis(axis) => Some(axis),
                _ => None,
            })
            .collect();
        let faults = self.config.faults;
        for slot in 0..self.controllers.len() {
            let Some(controller) = self.controllers.get_mut(slot).and_then(Option::as_mut) else {
                continue;
            };
            let axis = controller.axis();
            if source == Source::Axis(axis) || talking.contains(&axis) {
                continue;
            }
            if controller.receive(t, value, baud).is_none() {
                continue;
            }
            let drop = self.rngs.drop.chance(faults.reply_drop);
            let delay = self.rngs.delay.chance(faults.reply_delay);
            let silent = self.silent.get(slot).copied().unwrap_or(false);
            if silent {
                controller.cancel_reply();
                self.stats.replies_silenced += 1;
            } else if drop {
                controller.cancel_reply();
                self.stats.replies_dropped += 1;
            } else if delay {
                controller.delay_reply(faults.reply_delay_us);
                self.stats.replies_delayed += 1;
            }
        }

        if last && matches!(source, Source::Host | Source::Axis(_)) {
            self.maybe_noise(t, timing);
        }
    }

    fn maybe_noise(&mut self, t: u64, timing: Baud) {
        let faults = self.config.faults;
        let rng = &mut self.rngs.noise;
        let hit = rng.chance(faults.noise);
        let count = 1 + rng.below(u64::from(faults.noise_max_bytes.max(1)));
        if !hit {
            return;
        }
        let bytes: Vec<u8> = (0..count)
            .map(|_| match rng.byte() {
                STX => 0xFF,
                byte => byte,
            })
            .collect();
        self.stats.noise_bursts += 1;
        self.stats.noise_bytes += bytes.len() as u64;
        self.push_transmission(Source::Noise, t, None, timing, bytes);
    }

    fn prune(&mut self) {
        let now = self.now;
        self.transmissions
            .retain(|tx| !(tx.finished() && tx.end.saturating_add(KEEP_US) <= now));
        let oldest = self.transmissions.iter().map(|tx| tx.id).min();
        match oldest {
            Some(oldest) => self.collided.retain(|&(_, b)| b >= oldest),
            None => self.collided.clear(),
        }
    }
}
