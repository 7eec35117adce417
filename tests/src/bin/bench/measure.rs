//! What every scenario shares: the table's rows, distributions, the engine configuration, the
//! established bus, and the wire limits.

use protocol::engine::{timing, Config, Engine, Event, Link};
use protocol::line::Baud;
use protocol::AxisSet;
use protocol::{Axis, Command, Request, Rtim};
use rc_host::harness::Harness;
use rc_tools::sim::{Bus, BusConfig};
use serde_json::{json, Value};

use crate::{AXES, S, WARM_UP};

/// One line of the table: a measured value against a limit.
pub(crate) struct Row {
    pub(crate) id: &'static str,
    pub(crate) scenario: &'static str,
    pub(crate) what: String,
    pub(crate) measured_us: f64,
    pub(crate) limit_us: f64,
    /// What the limit is, in a few characters.
    pub(crate) limit_is: &'static str,
    /// The ratio measured / limit must not exceed this; `None`: informative.
    pub(crate) target: Option<f64>,
}

impl Row {
    pub(crate) fn ratio(&self) -> f64 {
        if self.limit_us > 0.0 {
            self.measured_us / self.limit_us
        } else {
            f64::NAN
        }
    }

    pub(crate) fn pass(&self) -> Option<bool> {
        self.target.map(|t| self.ratio() <= t)
    }
}

/// Distribution of a set of durations (µs).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Stats {
    pub(crate) n: usize,
    pub(crate) mean: f64,
    pub(crate) p50: u64,
    pub(crate) p99: u64,
    pub(crate) max: u64,
    pub(crate) min: u64,
}

impl Stats {
    pub(crate) fn of(values: &[u64]) -> Result<Stats, String> {
        if values.is_empty() {
            return Err("no samples".into());
        }
        let mut sorted = values.to_vec();
        sorted.sort_unstable();
        // Nearest rank: the smallest value with at least p of the samples at or below it.
        let rank = |p: f64| {
            let r = (p * sorted.len() as f64).ceil() as usize;
            sorted[r.clamp(1, sorted.len()) - 1]
        };
        Ok(Stats {
            n: sorted.len(),
            mean: sorted.iter().map(|&v| v as f64).sum::<f64>() / sorted.len() as f64,
            p50: rank(0.50),
            p99: rank(0.99),
            max: sorted[sorted.len() - 1],
            min: sorted[0],
        })
    }

    pub(crate) fn json(&self) -> Value {
        json!({
            "n": self.n,
            "mean_us": round3(self.mean),
            "min_us": self.min,
            "p50_us": self.p50,
            "p99_us": self.p99,
            "max_us": self.max,
        })
    }
}

pub(crate) fn round3(x: f64) -> f64 {
    (x * 1000.0).round() / 1000.0
}

pub(crate) fn axis(n: u8) -> Result<Axis, String> {
    Axis::new(n).ok_or_else(|| format!("no axis {n}"))
}

pub(crate) fn all_axes() -> Result<Vec<Axis>, String> {
    (0..AXES).map(axis).collect()
}

/// The engine configuration of every scenario: 16 axes, `baud`, RTIM 3 ms, establishment on,
/// everything else at its default.
pub(crate) fn config(baud: Baud) -> Config {
    Config {
        axes: AxisSet::first(AXES),
        baud,
        rtim: Rtim::MIN,
        establish: true,
        ..Config::default()
    }
}

/// 16 controllers fresh from power-up and an engine with `config`, run until established (at
/// `config.baud` and `config.rtim`), every axis online, and warmed up.
pub(crate) fn established(config: Config) -> Result<Harness, String> {
    let (baud, rtim) = (config.baud, config.rtim);
    let axes = all_axes()?;
    let bus = Bus::with_axes(BusConfig::default(), &axes);
    let mut h = Harness::new(Engine::new(config), bus);
    h.run_until_event(120 * S, |e| *e == Event::Established)
        .ok_or_else(|| format!("{baud:?}: the bus never established"))?;
    h.run_until(h.now + WARM_UP);
    for &a in &axes {
        let link = h.engine.axis(a).link;
        if link != Link::Online {
            return Err(format!(
                "{baud:?}: axis {} is {link:?} after establishment",
                a.get()
            ));
        }
        let c = h
            .bus
            .controller(a)
            .ok_or_else(|| format!("no controller {}", a.get()))?;
        if (c.baud(), c.rtim_ms()) != (baud, rtim.get()) {
            return Err(format!(
                "axis {} runs at {:?}/{} ms after establishment",
                a.get(),
                c.baud(),
                c.rtim_ms()
            ));
        }
    }
    Ok(h)
}

/// The times the status of `axis` was polled in `[from, to)`.
fn poll_times(sent: &[(u64, Request)], axis: Axis, from: u64, to: u64) -> Vec<u64> {
    sent.iter()
        .filter(|(t, r)| *t >= from && *t < to && r.axis == axis && r.command == Command::Status)
        .map(|(t, _)| *t)
        .collect()
}

/// Times between successive status polls of the same axis, for each of `axes`, in `[from, to)`.
pub(crate) fn cycles(sent: &[(u64, Request)], axes: &[Axis], from: u64, to: u64) -> Vec<u64> {
    axes.iter()
        .flat_map(|&a| {
            let times = poll_times(sent, a, from, to);
            times.windows(2).map(|w| w[1] - w[0]).collect::<Vec<_>>()
        })
        .collect()
}

pub(crate) fn timeouts(h: &Harness) -> u32 {
    Axis::all()
        .map(|a| h.engine.axis(a).counters.timeouts)
        .sum()
}

/// Wire limit of one transaction and of a 16-axis status cycle at `baud`, RTIM 3 ms (µs).
pub(crate) fn transaction(baud: Baud) -> u64 {
    timing::transaction_time(baud, Rtim::MIN).as_micros()
}

/// The response time-out Trt at `baud`, RTIM 3 ms (µs).
pub(crate) fn trt(baud: Baud) -> u64 {
    timing::response_timeout(baud, Rtim::MIN, false).as_micros()
}
