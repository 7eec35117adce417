//! The figures, from the simulator's event log (`rc-sim --events`): what the controllers saw
//! and when, in `CLOCK_MONOTONIC` µs, the clock the driver's own timestamps are in.

use std::fmt::Write as _;

/// One line of the event log.
enum Event {
    Request {
        at: u64,
        axis: u8,
        code: String,
    },
    Reply {
        at: u64,
        axis: u8,
        code: String,
        pfin: bool,
    },
    Move {
        start: u64,
        axis: u8,
        in_band: u64,
    },
}

fn parse(line: &str) -> Option<Event> {
    let mut f = line.split_whitespace();
    let kind = f.next()?;
    let at: u64 = f.next()?.parse().ok()?;
    let axis: u8 = f.next()?.parse().ok()?;
    match kind {
        "REQ" => Some(Event::Request {
            at,
            axis,
            code: f.next()?.to_string(),
        }),
        "REP" => Some(Event::Reply {
            at,
            axis,
            code: f.next()?.to_string(),
            pfin: f.next()? == "1",
        }),
        "MOVE" => Some(Event::Move {
            start: at,
            axis,
            in_band: f.next()?.parse().ok()?,
        }),
        _ => None,
    }
}

/// p50, p99 and the maximum of `values` (nearest rank), or zeros.
pub fn percentiles(values: &[f64]) -> [f64; 3] {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let rank = |p: f64| {
        let i = ((p * v.len() as f64).ceil() as usize).clamp(1, v.len().max(1)) - 1;
        v.get(i).copied().unwrap_or(0.0)
    };
    [rank(0.50), rank(0.99), v.last().copied().unwrap_or(0.0)]
}

/// What one run measured.
pub struct Figures {
    /// The mean transaction time in the window (µs): its length over the commands in it.
    pub transaction_us: f64,
    /// Per mover: INBAND -> the first status reply with PFIN, in transactions.
    pub complete: Vec<(u8, Vec<f64>)>,
    /// Per idle axis: the time between successive status polls, in cycles (16 transactions).
    pub idle_age: Vec<(u8, Vec<f64>)>,
    /// Per stop: from the PLC's write to the `d` reaching the controller, µs.
    pub stops_us: Vec<f64>,
    /// Stops that never reached their axis (should be none).
    pub stops_lost: usize,
    /// Where the bus went in the window.
    pub mix: Mix,
}

/// What the bus carried in the window, by kind: the budget the two targets share (issue 34).
/// Every frame is one transaction.
#[derive(Debug, Default, PartialEq)]
pub struct Mix {
    /// Moves that started in the window.
    pub moves: usize,
    /// Status polls of the movers.
    pub mover_status: usize,
    /// Position reads (R4) of the movers.
    pub mover_reads: usize,
    /// Every other command to a mover (`v`, `a`, `Q3`, `T`, `d`...).
    pub mover_commands: usize,
    /// Status polls of the idle axes.
    pub idle_status: usize,
    /// Every command in the window (what the run's T is measured over).
    pub frames: usize,
}

impl Mix {
    /// Per move: status polls, position reads, other commands; and the idle axes' share of
    /// the bus.
    pub fn per_move(&self) -> [f64; 4] {
        let moves = self.moves.max(1) as f64;
        [
            self.mover_status as f64 / moves,
            self.mover_reads as f64 / moves,
            self.mover_commands as f64 / moves,
            self.idle_status as f64 / self.frames.max(1) as f64,
        ]
    }
}

/// Works the figures out of the event log `text`: moves of `movers` that started in
/// `window`, idle axes' polls in it, and the `stops` (write time, axis) given after it.
pub fn figures(
    text: &str,
    window: (u64, u64),
    movers: &[u8],
    axes: u8,
    stops: &[(u64, u8)],
) -> Result<Figures, String> {
    let events: Vec<Event> = text.lines().filter_map(parse).collect();
    let (from, to) = window;
    let inside = |t: u64| (from..=to).contains(&t);
    let commands = events
        .iter()
        .filter(|e| matches!(e, Event::Request { at, .. } if inside(*at)))
        .count();
    if commands == 0 {
        return Err("no command in the window: the gateway never polled".into());
    }
    let t = (to - from) as f64 / commands as f64;

    let mut mix = Mix {
        frames: commands,
        ..Mix::default()
    };
    for e in &events {
        match e {
            Event::Request { at, axis, code } if inside(*at) => {
                let counter = match (movers.contains(axis), code.as_str()) {
                    (true, "Status") => &mut mix.mover_status,
                    (true, "ReadMemory") => &mut mix.mover_reads,
                    (true, _) => &mut mix.mover_commands,
                    (false, "Status") => &mut mix.idle_status,
                    (false, _) => continue,
                };
                *counter += 1;
            }
            Event::Move { start, .. } if inside(*start) => mix.moves += 1,
            _ => {}
        }
    }

    let mut complete = Vec::new();
    for &m in movers {
        let mut seen = Vec::new();
        for e in &events {
            let Event::Move {
                start,
                axis,
                in_band,
            } = *e
            else {
                continue;
            };
            if axis != m || !inside(start) || in_band > to {
                continue;
            }
            let first = events.iter().find_map(|r| match r {
                Event::Reply {
                    at,
                    axis,
                    code,
                    pfin: true,
                } if *axis == m && code == "Status" && *at >= in_band => Some(*at),
                _ => None,
            });
            if let Some(at) = first {
                seen.push((at - in_band) as f64 / t);
            }
        }
        complete.push((m, seen));
    }

    let mut idle_age = Vec::new();
    for a in (0..axes).filter(|a| !movers.contains(a)) {
        let polls: Vec<u64> = events
            .iter()
            .filter_map(|e| match e {
                Event::Request { at, axis, code } if *axis == a && code == "Status" => Some(*at),
                _ => None,
            })
            .filter(|&at| inside(at))
            .collect();
        let gaps = polls
            .windows(2)
            .map(|w| (w[1] - w[0]) as f64 / (t * f64::from(axes)))
            .collect();
        idle_age.push((a, gaps));
    }

    let mut stops_us = Vec::new();
    let mut stops_lost = 0;
    for &(written, m) in stops {
        let reached = events.iter().find_map(|e| match e {
            Event::Request { at, axis, code }
                if *axis == m && code == "CancelMotion" && *at >= written =>
            {
                Some(*at)
            }
            _ => None,
        });
        match reached {
            Some(at) => stops_us.push((at - written) as f64),
            None => stops_lost += 1,
        }
    }
    Ok(Figures {
        transaction_us: t,
        complete,
        idle_age,
        stops_us,
        stops_lost,
        mix,
    })
}

impl Figures {
    /// The moves' figures of every mover together.
    pub fn complete_all(&self) -> Vec<f64> {
        self.complete.iter().flat_map(|(_, v)| v.clone()).collect()
    }

    /// The idle axes' figures together.
    pub fn idle_all(&self) -> Vec<f64> {
        self.idle_age.iter().flat_map(|(_, v)| v.clone()).collect()
    }

    /// The worst mover's p99, in transactions.
    pub fn worst_mover_p99(&self) -> f64 {
        self.complete
            .iter()
            .map(|(_, v)| percentiles(v)[1])
            .fold(0.0, f64::max)
    }

    /// The table of one run.
    pub fn table(&self, title: &str) -> String {
        let mut out = String::new();
        let t = self.transaction_us;
        let _ = writeln!(out, "{title}: T = {:.2} ms (measured)", t / 1e3);
        let _ = writeln!(
            out,
            "  {:<28} {:>6} {:>6} {:>6} {:>6}",
            "figure", "n", "p50", "p99", "max"
        );
        let row = |out: &mut String, name: &str, v: &[f64]| {
            let [p50, p99, max] = percentiles(v);
            let _ = writeln!(
                out,
                "  {name:<28} {:>6} {p50:>6.2} {p99:>6.2} {max:>6.2}",
                v.len()
            );
        };
        row(&mut out, "INBAND->PFIN, T, all", &self.complete_all());
        for (m, v) in &self.complete {
            row(&mut out, &format!("INBAND->PFIN, T, axis {m}"), v);
        }
        row(&mut out, "idle status age, cycles", &self.idle_all());
        let stops_ms: Vec<f64> = self.stops_us.iter().map(|us| us / 1e3).collect();
        row(&mut out, "stop write->d, ms", &stops_ms);
        let [status, reads, commands, idle] = self.mix.per_move();
        let _ = writeln!(
            out,
            "  bus per move: {status:.2} status polls, {reads:.2} position reads, \
             {commands:.2} other commands ({:.1} T); idle axes' status polls: {:.0} % of it",
            status + reads + commands,
            idle * 100.0
        );
        if self.stops_lost > 0 {
            let _ = writeln!(out, "  STOPS LOST: {}", self.stops_lost);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Axis 3 polled every 10 µs from 1,000 µs, ten times.
    fn idle_polls() -> String {
        (0..10)
            .map(|k| format!("REQ {} 3 Status\n", 1_000 + 10 * k))
            .collect()
    }

    #[test]
    fn a_move_is_measured_from_in_band_to_the_first_pfin_reply() {
        // 10 commands in 100 µs: T = 10 µs.
        let mut log = idle_polls();
        log += "MOVE 1005 0 1040\nREP 1030 0 Status 1\nREP 1050 0 Status 0\nREP 1065 0 Status 1\n";
        let f = figures(&log, (1_000, 1_100), &[0], 4, &[(1_000, 0)]).unwrap();
        assert_eq!(f.transaction_us, 10.0);
        assert_eq!(f.complete, vec![(0, vec![2.5])]);
        // Axis 3 polled every 10 µs: 10 / (4 x 10) = 0.25 cycles.
        assert_eq!(f.idle_age.iter().find(|(a, _)| *a == 3).unwrap().1[0], 0.25);
        assert_eq!(f.stops_lost, 1);
        assert_eq!(percentiles(&[1.0, 2.0, 3.0, 4.0]), [2.0, 4.0, 4.0]);
    }

    #[test]
    fn the_bus_is_counted_by_kind_within_the_window() {
        let mut log = idle_polls();
        // A mover's move, a read, a command and a poll; one poll after the window, one move
        // before it, and a read of an idle axis (counted in the frames only).
        log += "MOVE 1005 0 1040\nMOVE 900 0 950\n";
        log += "REQ 1003 0 ReadMemory\nREQ 1004 0 MoveAbsolute\nREQ 1006 0 Status\n";
        log += "REQ 1200 0 Status\nREQ 1007 3 ReadMemory\n";
        let f = figures(&log, (1_000, 1_100), &[0], 4, &[]).unwrap();
        let mix = Mix {
            moves: 1,
            mover_status: 1,
            mover_reads: 1,
            mover_commands: 1,
            idle_status: 10,
            frames: 14,
        };
        assert_eq!(f.mix, mix);
        assert_eq!(mix.per_move(), [1.0, 1.0, 1.0, 10.0 / 14.0]);
    }
}
