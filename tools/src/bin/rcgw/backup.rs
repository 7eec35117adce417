//! `rcgw backup`, and a backup file read and checked for `rcgw restore`: the settings,
//! version, identity and the point table of every online axis, in one TOML file.

use std::fmt;
use std::io::IsTerminal;

use protocol::axes::AXES;
use protocol::plc::map::*;
use serde::Serialize;

use crate::link::{Fail, Gw};
use crate::points::{self, Row};
use crate::settings::{self, Section, Settings};
use crate::{bad_file, print_json, read_toml};

/// The backup's format.
pub const FORMAT: i64 = 1;

/// A backup file's settings and point tables.
pub struct Backup {
    pub settings: Settings,
    pub points: Vec<(u8, Vec<(u16, Row)>)>,
}

/// A backup file, read and checked: bad input (exit 2), naming every problem, if not.
pub fn load(path: &str) -> Result<Backup, Fail> {
    let doc = read_toml(path)?;
    let mut errors = Vec::new();
    match doc.get("backup").and_then(|b| b.as_table()) {
        None => errors.push("[backup] missing: not an rcgw backup".to_string()),
        Some(b) => {
            for (key, value) in b {
                match (key.as_str(), value) {
                    ("format" | "version" | "axes" | "online", _) => {}
                    ("identity", toml::Value::Table(_)) => {}
                    _ => errors.push(format!(
                        "[backup] {key}: unknown key (format, version, axes, online, [backup.identity])"
                    )),
                }
            }
            if b.get("format").and_then(|f| f.as_integer()) != Some(FORMAT) {
                errors.push(format!("[backup] format: {FORMAT} expected"));
            }
            match b.get("axes").and_then(|a| a.as_integer()) {
                Some(n) if n == AXES as i64 => {}
                Some(n) => errors.push(format!(
                    "[backup] axes = {n}: a backup of a gateway with {n} axes; this one has {AXES}"
                )),
                None => errors.push("[backup] axes missing".into()),
            }
        }
    }
    let settings = match Settings::from_toml(&doc, &["backup"], true) {
        Ok(s) => s,
        Err(e) => {
            errors.extend(e);
            Settings::default()
        }
    };
    let mut points = Vec::new();
    let axes = doc.get("axis").and_then(|a| a.as_table());
    let count = axes.map_or(0, |a| a.len());
    if errors.is_empty() && count != AXES {
        errors.push(format!(
            "{count} [axis.N] tables: a backup of another axis count (this gateway has {AXES})"
        ));
    }
    for (n, table) in axes.into_iter().flatten() {
        let Ok(n) = settings::axis_number(n) else {
            continue;
        };
        if let Some(list) = table.get("point") {
            let rows = points::from_toml(n, list, &mut errors);
            points.push((n, rows));
        }
    }
    if !errors.is_empty() {
        return Err(bad_file(path, errors));
    }
    Ok(Backup { settings, points })
}

/// The progress line on standard error, when it is a terminal.
pub fn progress(enabled: bool, text: &str) {
    if enabled {
        eprint!("\r\x1b[K{text}");
    }
}

fn bar(done: usize, total: usize) -> String {
    let width = 24;
    let filled = done * width / total.max(1);
    format!(
        "[{}{}] {done}/{total}",
        "#".repeat(filled),
        "-".repeat(width - filled)
    )
}

/// `rcgw backup FILE`.
pub fn backup(gw: &mut Gw, json: bool, file: &str) -> Result<(), Fail> {
    let settings = Settings::read(gw)?;
    let unit = gw.unit;
    let v = gw.read(unit, G_VERSION, 2)?;
    let version = format!("{}.{}.{}", v[0] >> 8, v[0] & 0xFF, v[1]);
    let identity = gw.identity()?;
    let mut online = Vec::new();
    let mut unserved = Vec::new();
    for n in settings.enabled() {
        let axis_unit = gw.axis_unit(n);
        match gw.probe(axis_unit, LINK, 1)? {
            Some(link) if link.first() == Some(&1) => online.push(n),
            Some(_) => {}
            None => unserved.push(format!("axis {n} (unit {axis_unit})")),
        }
    }
    if !unserved.is_empty() {
        eprintln!(
            "rcgw: settings pending: enabled but not served: {} (enabled or AXISBASE written, not applied): their point tables are not in the backup; `rcgw apply`, then back up again",
            unserved.join(", ")
        );
    }
    let show = std::io::stderr().is_terminal();
    let total = online.len() * usize::from(protocol::plc::table::ROWS);
    let mut tables = Vec::new();
    for (i, &n) in online.iter().enumerate() {
        let rows = points::read_table(gw, n, &mut |p| {
            let done = i * usize::from(protocol::plc::table::ROWS) + usize::from(p);
            progress(
                show,
                &format!("backup: axis {n} point {p:>2} {}", bar(done, total)),
            );
        })?;
        tables.push((n, rows));
    }
    progress(show, "");
    // Rows the position table would refuse (a stroke reduced since, a negative position, no
    // acceleration): left out, so that restore takes the file; said in it and on stderr.
    let mut omitted: Vec<(u8, usize, String)> = Vec::new();
    for (n, rows) in &mut tables {
        let cfg = settings.axis_cfg(*n);
        for (p, row) in rows.iter_mut().enumerate() {
            if row.is_empty() {
                continue;
            }
            if let Err(why) = points::check(row, &cfg) {
                omitted.push((*n, p, format!("{} ({why})", row.text())));
                *row = Row::default();
            }
        }
    }
    for (n, p, why) in &omitted {
        eprintln!(
            "rcgw: axis {n} point {p}: left out of the backup: the position table would refuse it: {why}"
        );
    }
    let mut text = format!(
        "# rcgw backup of gateway unit {unit}\n\n[backup]\nformat = {FORMAT}\nversion = \"{version}\"\naxes = {AXES}\nonline = [{}]\n\n[backup.identity]\n",
        online.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(", ")
    );
    let names = [
        "vendor",
        "product_code",
        "revision",
        "vendor_url",
        "product_name",
        "model_name",
    ];
    for (id, value) in &identity {
        let key = names
            .get(usize::from(*id))
            .map_or(format!("object_{id:02x}"), |n| n.to_string());
        text += &format!("{key} = {}\n", toml::Value::String(value.clone()));
    }
    text += &settings.to_toml_with(&|section| match section {
        Section::Axis(n) => {
            let mut text = tables
                .iter()
                .find(|(a, _)| *a == n)
                .map_or(String::new(), |(_, rows)| points::to_toml(n, rows));
            for (_, p, why) in omitted.iter().filter(|(a, _, _)| *a == n) {
                text += &format!(
                    "\n# point {p} left out: the position table would refuse it: {}\n",
                    why.replace('\n', " ")
                );
            }
            text
        }
        _ => String::new(),
    });
    std::fs::write(file, &text).map_err(|e| Fail::Input(format!("{file}: {e}")))?;
    let axes = tables
        .iter()
        .map(|(n, rows)| BackupAxis {
            axis: *n,
            points: rows.iter().filter(|r| !r.is_empty()).count(),
            without_speed: (0..rows.len())
                .filter(|&p| rows[p].is_empty() && rows[p] != Row::default())
                .filter(|p| !omitted.iter().any(|(a, q, _)| a == n && q == p))
                .collect(),
            left_out: omitted
                .iter()
                .filter(|(a, _, _)| a == n)
                .map(|(_, p, _)| *p)
                .collect(),
        })
        .collect();
    let report = BackupReport {
        unit,
        file: file.to_string(),
        version,
        online,
        axes,
    };
    if json {
        print_json(&report);
    } else {
        out!("{report}");
    }
    Ok(())
}

/// An axis in the backup (`axes[]` in the JSON).
#[derive(Serialize, Debug)]
pub struct BackupAxis {
    pub axis: u8,
    /// Rows saved.
    pub points: usize,
    /// Rows with a position but no speed: not saved.
    pub without_speed: Vec<usize>,
    /// Rows the position table would refuse: left out.
    pub left_out: Vec<usize>,
}

/// `rcgw backup`'s report: the JSON as serialised, the text by [`fmt::Display`].
#[derive(Serialize, Debug)]
pub struct BackupReport {
    #[serde(skip)]
    pub unit: u8,
    pub file: String,
    pub version: String,
    pub online: Vec<u8>,
    pub axes: Vec<BackupAxis>,
}

impl fmt::Display for BackupReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "backup of gateway unit {} (firmware {}) written to {}",
            self.unit, self.version, self.file
        )?;
        for a in &self.axes {
            writeln!(f, "axis {}: {} point(s)", a.axis, a.points)?;
            if !a.without_speed.is_empty() {
                let list: Vec<String> = a.without_speed.iter().map(|p| p.to_string()).collect();
                writeln!(
                    f,
                    "  points [{}] hold a position but no speed: not saved (the position table cannot write a row without a speed)",
                    list.join(",")
                )?;
            }
        }
        if self.online.is_empty() {
            writeln!(f, "no axis online: no point table saved")?;
        }
        Ok(())
    }
}
