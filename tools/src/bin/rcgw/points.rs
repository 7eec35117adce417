//! The position table of an axis unit (0x1000 + 16 n) in the file's units: position, band in
//! mm, speed in mm/s, acceleration in G, 2 decimals (the registers' 0.01 units).

use std::fmt::Write as _;
use std::time::Duration;

use protocol::plc::table::{self, BASE, ROWS, ROW_LEN};

use crate::link::{Fail, Gw};
use crate::settings::{hundredths, parse_hundredths};

/// How long a row may answer 04 (fetched from the controller, or being stored). A fetch is a
/// job among the bus's other work: a dozen transactions, each waiting its turn beside every
/// axis' polls (at 9.6 kbit/s with 16 axes, seconds), and rc-gateway-host on a busy PC can take
/// longer still (3 s was too short for the rcgw tests on a loaded 2-core CI machine).
const ROW_WAIT: Duration = Duration::from_secs(10);

/// One row, in 0.01 units.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Row {
    pub position: u32,
    pub band: u32,
    pub speed: u32,
    pub accel: u16,
}

impl Row {
    /// A row the controller holds no motion for (speed 0) is empty: it cannot be written.
    pub fn is_empty(&self) -> bool {
        self.speed == 0
    }

    fn from_registers(r: &[u16]) -> Row {
        let word = |i: usize| r.get(i).copied().unwrap_or(0);
        let long = |i: usize| u32::from(word(i)) << 16 | u32::from(word(i + 1));
        Row {
            position: long(0),
            band: long(2),
            speed: long(4),
            accel: word(10),
        }
    }

    /// The row's 16 registers as the position table takes them.
    pub fn registers(&self) -> [u16; 16] {
        let hi = |v: u32| (v >> 16) as u16;
        let lo = |v: u32| v as u16;
        let (p, b, s, a) = (self.position, self.band, self.speed, self.accel);
        [
            hi(p),
            lo(p),
            hi(b),
            lo(b),
            hi(s),
            lo(s),
            0,
            0,
            0,
            0,
            a,
            a,
            0,
            0,
            0,
            0,
        ]
    }

    pub fn text(&self) -> String {
        format!(
            "{} mm, {} mm/s, {} G, band {} mm",
            hundredths(i64::from(self.position as i32)),
            hundredths(i64::from(self.speed)),
            hundredths(i64::from(self.accel)),
            hundredths(i64::from(self.band))
        )
    }
}

/// The address of row `point`.
pub fn row_address(point: u16) -> u16 {
    BASE + ROW_LEN * point
}

/// Row `point` of `axis`, waiting while the gateway fetches it.
pub fn read_row(gw: &mut Gw, axis: u8, point: u16) -> Result<Row, Fail> {
    let unit = gw.axis_unit(axis);
    let regs = gw.read_wait(unit, row_address(point), ROW_LEN, ROW_WAIT)?;
    Ok(Row::from_registers(&regs))
}

/// Every row of `axis`; `progress(point)` before each.
pub fn read_table(gw: &mut Gw, axis: u8, progress: &mut dyn FnMut(u16)) -> Result<Vec<Row>, Fail> {
    (0..ROWS)
        .map(|point| {
            progress(point);
            read_row(gw, axis, point)
        })
        .collect()
}

/// Whether `back` is `row` as the controller stores it: equal, or within its resolution
/// (positions and bands within 0.05 mm, speeds and accelerations within 1 %).
fn close(row: &Row, back: &Row) -> bool {
    let near = |a: u32, b: u32, tolerance: u32| a.abs_diff(b) <= tolerance;
    near(row.position, back.position, 5)
        && near(row.band, back.band, 5)
        && near(row.speed, back.speed, (row.speed / 100).max(1))
        && near(
            u32::from(row.accel),
            u32::from(back.accel),
            (u32::from(row.accel) / 100).max(1),
        )
}

/// Write a whole row, then read it back once stored (the row answers 04 until then): the row
/// as the controller now holds it (its resolution may round a value by a step).
pub fn write_row(gw: &mut Gw, axis: u8, point: u16, row: &Row) -> Result<Row, Fail> {
    let unit = gw.axis_unit(axis);
    gw.write(unit, row_address(point), &row.registers())?;
    let back = read_row(gw, axis, point)?;
    if !close(row, &back) {
        return Err(Fail::Device(format!(
            "{}: point {point} verify failed: wrote {}, reads {}",
            gw.at(unit, row_address(point)),
            row.text(),
            back.text()
        )));
    }
    Ok(back)
}

/// The non-empty rows as `[[axis.N.point]]` tables.
pub fn to_toml(axis: u8, rows: &[Row]) -> String {
    let mut out = String::new();
    for (point, row) in rows.iter().enumerate() {
        if row.is_empty() {
            continue;
        }
        let _ = writeln!(
            out,
            "\n[[axis.{axis}.point]]\npoint = {point}\nposition_mm = {}\nspeed_mm_s = {}\naccel_g = {}\nband_mm = {}",
            hundredths(i64::from(row.position as i32)),
            hundredths(i64::from(row.speed)),
            hundredths(i64::from(row.accel)),
            hundredths(i64::from(row.band))
        );
    }
    out
}

/// Whether the gateway's position table takes `row` for an axis whose AXISCFG block reads
/// `axis_cfg`: the protocol crate's own check of a row written (`check_row`), before anything
/// is written. `Err`: what it would refuse, in the file's units.
pub fn check(row: &Row, axis_cfg: &[u16]) -> Result<(), String> {
    let Some(config) = table::axis_config(axis_cfg) else {
        return Err("the axis' settings (lead, home, pulses/rev, stroke) are not valid".into());
    };
    if table::check_row(&row.registers(), &config).is_ok() {
        return Ok(());
    }
    // Which field: each tried alone beside values the table takes.
    let safe = Row {
        position: 0,
        band: 0,
        speed: 100,
        accel: 1,
    };
    let safe = Row {
        accel: (1..=100)
            .find(|&a| table::check_row(&Row { accel: a, ..safe }.registers(), &config).is_ok())
            .unwrap_or(30),
        ..safe
    };
    let ok = |r: Row| table::check_row(&r.registers(), &config).is_ok();
    let mut why = Vec::new();
    if !ok(Row {
        position: row.position,
        ..safe
    }) {
        why.push(format!(
            "position_mm = {}: outside 0.00-{} (the axis' stroke)",
            hundredths(i64::from(row.position as i32)),
            hundredths(i64::from(config.stroke.0))
        ));
    }
    if !ok(Row {
        speed: row.speed,
        ..safe
    }) {
        why.push(format!(
            "speed_mm_s = {}: 0 or more than the controller can hold with lead {} mm",
            hundredths(i64::from(row.speed)),
            hundredths(i64::from(config.scale.lead.hundredths()))
        ));
    }
    if !ok(Row {
        accel: row.accel,
        ..safe
    }) {
        why.push(format!(
            "accel_g = {}: 0, too small or more than the controller can hold with lead {} mm",
            hundredths(i64::from(row.accel)),
            hundredths(i64::from(config.scale.lead.hundredths()))
        ));
    }
    if !ok(Row {
        band: row.band,
        ..safe
    }) {
        why.push(format!(
            "band_mm = {}: out of range",
            hundredths(i64::from(row.band))
        ));
    }
    if why.is_empty() {
        why.push(format!("{}: refused", row.text()));
    }
    Err(why.join(", "))
}

/// `[[axis.N.point]]` tables as rows by point, each checked for its form: point 0-15 once,
/// every key there, numbers with 2 decimals that fit their registers. What the gateway takes
/// ([`check`]) is looked at separately, against the axis' settings.
pub fn from_toml(axis: u8, value: &toml::Value, errors: &mut Vec<String>) -> Vec<(u16, Row)> {
    let mut rows: Vec<(u16, Row)> = Vec::new();
    let Some(list) = value.as_array() else {
        errors.push(format!(
            "axis.{axis}.point: not a list of [[axis.{axis}.point]] tables"
        ));
        return rows;
    };
    for (i, item) in list.iter().enumerate() {
        let at = format!("[[axis.{axis}.point]] #{}", i + 1);
        let Some(table) = item.as_table() else {
            errors.push(format!("{at}: not a table"));
            continue;
        };
        for key in table.keys() {
            if !["point", "position_mm", "speed_mm_s", "accel_g", "band_mm"].contains(&key.as_str())
            {
                errors.push(format!(
                    "{at} {key}: unknown key (point, position_mm, speed_mm_s, accel_g, band_mm)"
                ));
            }
        }
        let mut get = |key: &str, min: i64, max: i64| -> Option<i64> {
            let Some(v) = table.get(key) else {
                errors.push(format!("{at}: {key} missing"));
                return None;
            };
            match parse_hundredths(v) {
                Ok(x) if (min..=max).contains(&x) => Some(x),
                Ok(_) => {
                    errors.push(format!(
                        "{at} {key} = {v}: out of range ({}-{})",
                        hundredths(min),
                        hundredths(max)
                    ));
                    None
                }
                Err(e) => {
                    errors.push(format!("{at} {key} = {v}: {e}"));
                    None
                }
            }
        };
        let position = get("position_mm", i64::from(i32::MIN), i64::from(i32::MAX));
        let speed = get("speed_mm_s", 0, i64::from(i32::MAX));
        let accel = get("accel_g", 0, 65535);
        let band = get("band_mm", 0, i64::from(i32::MAX));
        let point = match table.get("point").and_then(|p| p.as_integer()) {
            Some(p) if (0..i64::from(ROWS)).contains(&p) => Some(p as u16),
            _ => {
                errors.push(format!("{at}: point must be 0-{}", ROWS - 1));
                None
            }
        };
        if let (Some(point), Some(p), Some(s), Some(a), Some(b)) =
            (point, position, speed, accel, band)
        {
            if rows.iter().any(|(n, _)| *n == point) {
                errors.push(format!("{at}: point {point} given twice"));
                continue;
            }
            rows.push((
                point,
                Row {
                    position: p as i32 as u32,
                    band: b as u32,
                    speed: s as u32,
                    accel: a as u16,
                },
            ));
        }
    }
    rows
}
