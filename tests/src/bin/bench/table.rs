//! The report as a text table.

use std::fmt::Write as _;

use protocol::engine::Engine;

use crate::measure::Row;
use crate::report::Report;
use crate::{Args, S, WARM_UP};

fn ms(us: f64) -> String {
    format!("{:.3} ms", us / 1000.0)
}

pub(crate) fn table(report: &Report, args: &Args) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Engine benchmark on the simulated bus (virtual time: identical every run; seed {:#x})",
        args.seed
    );
    let _ = writeln!(
        out,
        "Set-up: 16 controllers from power-up (9.6 kbit/s, RTIM 255 ms), Config.establish = true \
         to the rate under test, RTIM 3 ms; measured after a {} s warm-up.",
        WARM_UP / S
    );
    let _ = writeln!(
        out,
        "Engine RAM: size_of::<Engine>() = {} bytes\n",
        std::mem::size_of::<Engine>()
    );
    let header = [
        "scenario",
        "measurement",
        "measured",
        "limit",
        "limit is",
        "ratio",
        "target",
        "result",
    ];
    let cells: Vec<[String; 8]> = report
        .rows
        .iter()
        .map(|r| {
            [
                r.scenario.to_string(),
                r.what.clone(),
                ms(r.measured_us),
                ms(r.limit_us),
                r.limit_is.to_string(),
                format!("{:.3}", r.ratio()),
                r.target.map_or("-".into(), |t| format!("<= {t:.2}")),
                match r.pass() {
                    Some(true) => "PASS".into(),
                    Some(false) => "MISS".into(),
                    None => "info".into(),
                },
            ]
        })
        .collect();
    let mut width = header.map(str::len);
    for row in &cells {
        for (w, c) in width.iter_mut().zip(row) {
            *w = (*w).max(c.chars().count());
        }
    }
    let line = |cells: &[String]| {
        let mut s = String::new();
        for (i, (c, w)) in cells.iter().zip(width).enumerate() {
            // Text left, numbers right.
            if matches!(i, 2 | 3 | 5) {
                let _ = write!(s, "{c:>w$}  ");
            } else {
                let _ = write!(s, "{c:<w$}  ");
            }
        }
        s.trim_end().to_string()
    };
    let _ = writeln!(out, "{}", line(&header.map(String::from)));
    let _ = writeln!(
        out,
        "{}",
        width.map(|w| "-".repeat(w)).join("  ").trim_end()
    );
    for row in &cells {
        let _ = writeln!(out, "{}", line(row));
    }
    let _ = writeln!(
        out,
        "\nT = one transaction (command + RTIM + response + 1 ms host gap, timing::transaction_time); \
         Trt = response time-out (20 ms + RTIM + response)."
    );
    for note in &report.notes {
        let _ = writeln!(out, "{note}");
    }
    let (pass, miss) = report
        .rows
        .iter()
        .filter_map(Row::pass)
        .fold(
            (0, 0),
            |(p, m), ok| if ok { (p + 1, m) } else { (p, m + 1) },
        );
    let _ = writeln!(out, "\nTargets: {pass} PASS, {miss} MISS");
    out
}
