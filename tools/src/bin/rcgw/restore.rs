//! `rcgw restore`: the settings and point tables of a backup, only what differs written, then
//! verified.

use std::fmt;
use std::io::IsTerminal;
use std::time::Duration;

use protocol::plc::map::*;
use serde::Serialize;

use crate::backup::progress;
use crate::config::keys;
use crate::link::{Fail, Gw};
use crate::points::{self, Row};
use crate::settings::{self, Change, Section, Settings};
use crate::{bad_file, print_json};

/// `rcgw restore FILE`.
pub fn restore(gw: &mut Gw, json: bool, file: &str, dry_run: bool, save: bool) -> Result<(), Fail> {
    let b = crate::backup::load(file)?;
    let now = Settings::read(gw)?;
    let mut wanted = b.settings.clone();
    let mut notes = Vec::new();
    if !now.has_network() && wanted.has_network() {
        wanted.values.retain(|(s, _), _| *s != Section::Network);
        notes.push(
            "[network] of the backup left out: this gateway has no network settings (a build without Modbus TCP)"
                .to_string(),
        );
    }
    // The gateway unit and the PLC line are the ones this connection uses: a backup of another
    // gateway would take them over; they are restored too (that is the point of a backup).
    let after = now.merged(&wanted);
    let mut whole = after.check_whole();
    for (n, rows) in &b.points {
        if !rows.is_empty() && after.word(Section::Axis(*n), "enabled") != Some(1) {
            whole.push(format!(
                "[[axis.{n}.point]]: axis {n} is not enabled ([axis.{n}] enabled = false): its {} row(s) cannot be written",
                rows.len()
            ));
        }
    }
    let changes = now.diff(&wanted);
    let phases = settings::plan(&now, &changes).unwrap_or_else(|e| {
        whole.push(e);
        Vec::new()
    });
    if !whole.is_empty() {
        return Err(bad_file(file, whole));
    }
    // Every row checked as the position table will check it, with the axis' settings as
    // they will be, before anything is written: a row it would refuse is skipped.
    let mut skipped = Vec::new();
    let mut tables: Vec<(u8, Vec<(u16, Row)>)> = Vec::new();
    for (n, rows) in &b.points {
        let cfg = after.axis_cfg(*n);
        let mut keep = Vec::new();
        for (p, row) in rows {
            match points::check(row, &cfg) {
                Ok(()) => keep.push((*p, *row)),
                Err(why) => skipped.push(format!(
                    "axis {n} point {p}: not restored: the position table would refuse it: {why}"
                )),
            }
        }
        tables.push((*n, keep));
    }
    let was_enabled = now.enabled();
    let applied = if dry_run {
        false
    } else {
        settings::write_changes(gw, &phases)?
    };
    let mut report = Vec::new();
    let mut missing = Vec::new();
    let show = std::io::stderr().is_terminal() && !dry_run;
    let mut rows_of = |gw: &mut Gw, report: &mut Vec<RestoreAxis>| -> Result<(), Fail> {
        for (n, rows) in &tables {
            if dry_run && !was_enabled.contains(n) {
                report.push(RestoreAxis {
                    axis: *n,
                    on_apply: Some(OnApply {
                        enabled_on_apply: true,
                        rows: rows.len(),
                    }),
                    written: Vec::new(),
                    unchanged: 0,
                    not_in_backup: Vec::new(),
                });
                continue;
            }
            let axis_unit = gw.axis_unit(*n);
            // Not served (0A, 02, silence): not online. LINK 0 (unknown: its first exchange
            // still under way, as right after a start or an APPLY): waited for, at most 3 s.
            let deadline = std::time::Instant::now() + Duration::from_secs(3);
            let online = loop {
                match gw.probe(axis_unit, LINK, 1)? {
                    Some(l) if l.first() == Some(&0) && std::time::Instant::now() < deadline => {
                        std::thread::sleep(Duration::from_millis(50))
                    }
                    Some(l) => break l.first() == Some(&1),
                    None => break false,
                }
            };
            if !online {
                missing.push(format!(
                    "axis {n} (unit {axis_unit}): not online: its {} point(s) not restored",
                    rows.len()
                ));
                continue;
            }
            let mut written = Vec::new();
            let mut unchanged = 0;
            let mut kept = Vec::new();
            let table = points::read_table(gw, *n, &mut |p| {
                progress(show, &format!("restore: axis {n} reading point {p:>2}"));
            })?;
            let entry_of = |written: &Vec<PointWrite>, unchanged, kept: &Vec<usize>| RestoreAxis {
                axis: *n,
                on_apply: None,
                written: written.clone(),
                unchanged,
                not_in_backup: kept.clone(),
            };
            for (point, row) in rows {
                let current = table.get(usize::from(*point)).copied().unwrap_or_default();
                if current == *row {
                    unchanged += 1;
                    continue;
                }
                progress(show, &format!("restore: axis {n} writing point {point:>2}"));
                let mut entry = PointWrite {
                    point: *point,
                    from: (!current.is_empty()).then(|| current.text()),
                    to: row.text(),
                    stored: None,
                };
                if !dry_run {
                    match points::write_row(gw, *n, *point, row) {
                        Ok(stored) => {
                            if stored != *row {
                                entry.stored = Some(stored.text());
                            }
                        }
                        Err(e) => {
                            report.push(entry_of(&written, unchanged, &kept));
                            return Err(e);
                        }
                    }
                }
                written.push(entry);
            }
            for (point, row) in table.iter().enumerate() {
                if !row.is_empty()
                    && !b.points.iter().any(|(a, rows)| {
                        a == n && rows.iter().any(|(p, _)| usize::from(*p) == point)
                    })
                {
                    kept.push(point);
                }
            }
            report.push(entry_of(&written, unchanged, &kept));
        }
        Ok(())
    };
    let outcome = rows_of(gw, &mut report);
    progress(show, "");
    let saved = match (&outcome, save && !dry_run) {
        (Ok(()), true) => Some(settings::save(gw)?),
        _ => None,
    };
    let out = RestoreReport {
        dry_run,
        settings: changes,
        two_steps: match phases.as_slice() {
            [first, _] => Some(keys(first)),
            _ => None,
        },
        applied,
        axes: report,
        not_restored: missing,
        skipped,
        notes,
        saved: saved.is_some(),
        save_count: saved,
        complete: outcome.is_ok(),
    };
    if json {
        print_json(&out);
    } else {
        out!("{out}");
    }
    let RestoreReport {
        not_restored: missing,
        skipped,
        ..
    } = out;
    outcome.map_err(|e| match e {
        Fail::Device(m) | Fail::Input(m) => Fail::Device(format!(
            "{m}\n  restore stopped there: the report above is what was done"
        )),
    })?;
    if !missing.is_empty() {
        return Err(Fail::Device(format!(
            "{}: {} axis/axes of the backup not online: check their controllers, then restore again",
            gw.link.name,
            missing.len()
        )));
    }
    if !skipped.is_empty() {
        return Err(Fail::Input(format!(
            "{file}: {} row(s) skipped (the position table would refuse them), the rest restored:\n  {}",
            skipped.len(),
            skipped.join("\n  ")
        )));
    }
    Ok(())
}

/// A point row restore writes (or would write).
#[derive(Serialize, Clone, Debug)]
pub struct PointWrite {
    pub point: u16,
    /// What the row held: `null` for an empty row.
    pub from: Option<String>,
    pub to: String,
    /// What the controller stored, when its resolution changed it; absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stored: Option<String>,
}

/// An axis enabled by the restore, in a dry run: its rows compared once it is.
#[derive(Serialize, Debug)]
pub struct OnApply {
    pub enabled_on_apply: bool,
    pub rows: usize,
}

/// An axis' point table restored (`axes[]` in the JSON).
#[derive(Serialize, Debug)]
pub struct RestoreAxis {
    pub axis: u8,
    #[serde(flatten)]
    pub on_apply: Option<OnApply>,
    pub written: Vec<PointWrite>,
    pub unchanged: usize,
    /// Rows that hold data the backup has empty: left as they are.
    pub not_in_backup: Vec<usize>,
}

/// `rcgw restore`'s report: the JSON as serialised, the text by [`fmt::Display`].
#[derive(Serialize, Debug)]
pub struct RestoreReport {
    pub dry_run: bool,
    pub settings: Vec<Change>,
    /// The first phase's settings, when they are written in two steps (text only).
    #[serde(skip)]
    pub two_steps: Option<String>,
    pub applied: bool,
    pub axes: Vec<RestoreAxis>,
    pub not_restored: Vec<String>,
    pub skipped: Vec<String>,
    pub notes: Vec<String>,
    pub saved: bool,
    pub save_count: Option<u32>,
    pub complete: bool,
}

impl fmt::Display for RestoreReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let verb = if self.dry_run {
            "would change"
        } else {
            "changed"
        };
        writeln!(f, "settings: {} {verb}", self.settings.len())?;
        for c in &self.settings {
            writeln!(f, "  {}", c.line())?;
        }
        if let Some(first) = &self.two_steps {
            writeln!(
                f,
                "  in two steps: {first} first, then APPLY, then the rest"
            )?;
        }
        if self.settings.iter().any(|c| c.on_restart()) {
            writeln!(
                f,
                "  [network] addresses take effect after SAVE and RESTART"
            )?;
        }
        for n in &self.notes {
            writeln!(f, "  {n}")?;
        }
        if self.applied {
            writeln!(f, "  APPLY done: the bus was established again")?;
        }
        for r in &self.axes {
            if let Some(later) = &r.on_apply {
                writeln!(
                    f,
                    "axis {}: enabled on APPLY; its {} row(s) compared after it",
                    r.axis, later.rows
                )?;
                continue;
            }
            writeln!(
                f,
                "axis {}: {} point(s) {}, {} unchanged",
                r.axis,
                r.written.len(),
                if self.dry_run {
                    "would be written"
                } else {
                    "written and verified"
                },
                r.unchanged
            )?;
            for w in &r.written {
                writeln!(
                    f,
                    "  point {}: {} -> {}",
                    w.point,
                    w.from.as_deref().unwrap_or("empty"),
                    w.to
                )?;
                if let Some(stored) = &w.stored {
                    writeln!(f, "    stored as {stored} (the controller's resolution)")?;
                }
            }
            for p in &r.not_in_backup {
                writeln!(f, "  point {p}: holds data the backup has empty: left as it is (a row cannot be emptied over Modbus)")?;
            }
        }
        for m in &self.not_restored {
            writeln!(f, "{m}")?;
        }
        for k in &self.skipped {
            writeln!(f, "{k}")?;
        }
        if let Some(count) = self.save_count {
            writeln!(f, "saved (SAVECOUNT {count})")?;
        }
        Ok(())
    }
}
