//! `rcgw restore`: the settings and point tables of a backup, only what differs written, then
//! verified.

use std::io::IsTerminal;
use std::time::Duration;

use protocol::plc::map::*;
use serde_json::{json, Value};

use crate::backup::progress;
use crate::config::keys;
use crate::link::{Fail, Gw};
use crate::points::{self, Row};
use crate::settings::{self, Section, Settings};
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
    let mut rows_of = |gw: &mut Gw, report: &mut Vec<Value>| -> Result<(), Fail> {
        for (n, rows) in &tables {
            if dry_run && !was_enabled.contains(n) {
                report.push(json!({"axis": n, "enabled_on_apply": true, "rows": rows.len(), "written": [], "unchanged": 0, "not_in_backup": []}));
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
            let entry_of = |written: &Vec<Value>, unchanged, kept: &Vec<usize>| json!({"axis": n, "written": written, "unchanged": unchanged, "not_in_backup": kept});
            for (point, row) in rows {
                let current = table.get(usize::from(*point)).copied().unwrap_or_default();
                if current == *row {
                    unchanged += 1;
                    continue;
                }
                progress(show, &format!("restore: axis {n} writing point {point:>2}"));
                let mut entry = json!({"point": point, "from": if current.is_empty() { Value::Null } else { json!(current.text()) }, "to": row.text()});
                if !dry_run {
                    match points::write_row(gw, *n, *point, row) {
                        Ok(stored) => {
                            if stored != *row {
                                entry["stored"] = json!(stored.text());
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
    if json {
        print_json(&json!({
            "dry_run": dry_run,
            "settings": changes.iter().map(|c| c.json()).collect::<Vec<_>>(),
            "applied": applied,
            "axes": report,
            "not_restored": missing,
            "skipped": skipped,
            "notes": notes,
            "saved": saved.is_some(),
            "save_count": saved,
            "complete": outcome.is_ok(),
        }));
    } else {
        let verb = if dry_run { "would change" } else { "changed" };
        outln!("settings: {} {verb}", changes.len());
        for c in &changes {
            outln!("  {}", c.line());
        }
        if let [first, _] = phases.as_slice() {
            outln!(
                "  in two steps: {} first, then APPLY, then the rest",
                keys(first)
            );
        }
        if changes.iter().any(|c| c.on_restart()) {
            outln!("  [network] addresses take effect after SAVE and RESTART");
        }
        for n in &notes {
            outln!("  {n}");
        }
        if applied {
            outln!("  APPLY done: the bus was established again");
        }
        for r in &report {
            if r["enabled_on_apply"] == true {
                outln!(
                    "axis {}: enabled on APPLY; its {} row(s) compared after it",
                    r["axis"],
                    r["rows"]
                );
                continue;
            }
            let written = r["written"].as_array().map_or(0, |w| w.len());
            outln!(
                "axis {}: {written} point(s) {}, {} unchanged",
                r["axis"],
                if dry_run {
                    "would be written"
                } else {
                    "written and verified"
                },
                r["unchanged"]
            );
            for w in r["written"].as_array().into_iter().flatten() {
                outln!(
                    "  point {}: {} -> {}",
                    w["point"],
                    w["from"].as_str().unwrap_or("empty"),
                    w["to"].as_str().unwrap_or("")
                );
                if let Some(stored) = w["stored"].as_str() {
                    outln!("    stored as {stored} (the controller's resolution)");
                }
            }
            for p in r["not_in_backup"].as_array().into_iter().flatten() {
                outln!("  point {p}: holds data the backup has empty: left as it is (a row cannot be emptied over Modbus)");
            }
        }
        for m in &missing {
            outln!("{m}");
        }
        for k in &skipped {
            outln!("{k}");
        }
        if let Some(count) = saved {
            outln!("saved (SAVECOUNT {count})");
        }
    }
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
