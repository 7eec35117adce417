//! What happens on the line at each instant: power events, bytes arriving (collisions, wrong
//! baud rates, corruption), breaks taking effect, replies starting, noise, and forgetting
//! finished transmissions.

use protocol::frame::STX;
use protocol::line::Baud;
use protocol::Axis;

use super::{Bus, Source};

/// How long a finished transmission is kept for collision checks: two bytes at the slowest rate.
const KEEP_US: u64 = 2_100;

impl Bus {
    pub(super) fn run(&mut self, until: u64) {
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
        let byte_start = tx.start + tx.offset(k);
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
            let cut = self.cut.get(slot).copied().unwrap_or(false);
            if cut || source == Source::Axis(axis) || talking.contains(&axis) {
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
