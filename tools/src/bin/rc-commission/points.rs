//! The point table in a file: CSV with a header naming the columns (`point`, `position_mm`,
//! `speed_mm_s`, `accel_g`, `band_mm`, in any order) or TOML (`[[point]]` tables with the same
//! keys), in the units a machine builder reads on a drawing.
//!
//! Every row is checked before anything is written ([`check`]): a value the controller would
//! clamp (a position beyond the stroke or the soft limits) or lose (a speed of 0: the row then
//! reads back as never written) is refused with the file's line and the reason.

use std::path::Path;

use protocol::engine::point_jobs::{PointData, PointReadback};
use protocol::memory::PointField;
use protocol::units::{Accel, Length, Scale, Speed, UnitError};
use protocol::{Acceleration, PositionNo, Pulses, Velocity};
use rc_tools::rcframe::units::hundredths as exact_hundredths;
use serde::{Deserialize, Serialize};

/// One row, in hundredths (0.01 mm, 0.01 mm/s, 0.01 G): exact in both directions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Row {
    pub point: u8,
    pub position: i32,
    pub speed: u32,
    pub accel: u32,
    pub band: u32,
}

/// A row of a file, with the line it is on (1-based).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Entry {
    pub line: usize,
    pub row: Row,
}

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct TomlRow {
    point: u8,
    position_mm: f64,
    speed_mm_s: f64,
    accel_g: f64,
    band_mm: f64,
}

#[derive(Serialize)]
struct TomlFile {
    point: Vec<TomlRow>,
}

/// The file as read: each table with where it starts, so that an error names its line.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TomlInput {
    point: Vec<toml::Spanned<TomlRow>>,
}

/// The columns, in the order `points read` writes them.
const COLUMNS: [&str; 5] = ["point", "position_mm", "speed_mm_s", "accel_g", "band_mm"];

/// A TOML number in hundredths; more than two decimals would be rounded away, so refused.
fn hundredths(value: f64, what: &str) -> Result<i64, String> {
    let scaled = value * 100.0;
    let rounded = scaled.round();
    if !rounded.is_finite() || rounded.abs() > 2e9 {
        return Err(format!("{what} {value}: out of range"));
    }
    if (scaled - rounded).abs() > 1e-6 {
        return Err(format!(
            "{what} {value}: more than 2 decimals (0.01 is the resolution)"
        ));
    }
    Ok(rounded as i64)
}

fn text(hundredths: i64) -> String {
    let sign = if hundredths < 0 { "-" } else { "" };
    format!(
        "{sign}{}.{:02}",
        hundredths.abs() / 100,
        hundredths.abs() % 100
    )
}

/// The smallest value in hundredths (up to 10000.00) that `ok` accepts, as text.
fn smallest(ok: impl Fn(u32) -> bool) -> String {
    (1..=1_000_000)
        .find(|&h| ok(h))
        .map_or("?".into(), |h| text(h.into()))
}

impl Row {
    /// A row from its values in hundredths: position, speed, acceleration, band.
    fn from_hundredths(point: u8, values: [i64; 4]) -> Result<Row, String> {
        let [position, speed, accel, band] = values;
        let unsigned = |v: i64, what: &str, unit: &str| {
            u32::try_from(v).map_err(|_| {
                if v < 0 {
                    format!("{what} {} {unit}: must be >= 0", text(v))
                } else {
                    format!("{what} {} {unit}: out of range", text(v))
                }
            })
        };
        Ok(Row {
            point,
            position: i32::try_from(position)
                .map_err(|_| format!("position {} mm: out of range", text(position)))?,
            speed: unsigned(speed, "speed", "mm/s")?,
            accel: unsigned(accel, "acceleration", "G")?,
            band: unsigned(band, "band", "mm")?,
        })
    }

    /// The row as the controller stores it, or every reason it cannot be stored as written
    /// (leaving out the stroke, which [`check`] adds).
    pub fn to_wire(self, scale: &Scale) -> Result<(PositionNo, PointData), Vec<String>> {
        let mut why = Vec::new();
        let point = PositionNo::new(self.point);
        if point.is_none() {
            why.push("the Robo Cylinder has points 0-15".to_string());
        }
        let position = scale.position_to_wire(Length(self.position));
        if position.is_err() {
            why.push(format!(
                "position {} mm: beyond what the controller can store",
                text(self.position.into())
            ));
        }
        let speed = text(self.speed.into());
        let velocity = match scale.velocity(Speed(self.speed)) {
            Ok(v) if v.get() > 0 => Some(v),
            Ok(_) if self.speed == 0 => {
                why.push(
                    "speed 0 mm/s: the controller keeps a point without speed as an empty row \
                     (the row would be lost); give the speed of the move"
                        .to_string(),
                );
                None
            }
            Ok(_) => {
                let least = smallest(|h| scale.velocity(Speed(h)).is_ok_and(|v| v.get() > 0));
                why.push(format!(
                    "speed {speed} mm/s: below the smallest the controller stores with this lead, \
                     {least} mm/s (it would store 0, and the row be lost)"
                ));
                None
            }
            Err(_) => {
                let max = Velocity::new(Velocity::MAX.get()).map(|v| scale.speed(v).0);
                why.push(format!(
                    "speed {speed} mm/s: above the controller's maximum, {} mm/s with this lead",
                    text(max.unwrap_or(0).into())
                ));
                None
            }
        };
        let accel = text(self.accel.into());
        let acceleration = match scale.acceleration(Accel(self.accel)) {
            Ok(a) => Some(a),
            Err(UnitError::TooSmall) => {
                let least = smallest(|h| scale.acceleration(Accel(h)).is_ok());
                why.push(format!(
                    "acceleration {accel} G: below the controller's smallest, {least} G with \
                     this lead"
                ));
                None
            }
            Err(UnitError::OutOfRange) => {
                why.push(format!(
                    "acceleration {accel} G: above the controller's maximum, {} G with this lead",
                    text(scale.accel(Acceleration::MAX).0.into())
                ));
                None
            }
        };
        let band = scale.band_to_wire(Length(i32::try_from(self.band).unwrap_or(i32::MAX)));
        if band.is_err() {
            why.push(format!(
                "band {} mm: beyond what the controller can store",
                text(self.band.into())
            ));
        }
        match (point, position, velocity, acceleration, band) {
            (Some(point), Ok(position), Some(velocity), Some(acceleration), Ok(band))
                if why.is_empty() =>
            {
                Ok((
                    point,
                    PointData {
                        position,
                        velocity,
                        acceleration,
                        flags: PointData::FLAGS_MOTION_AND_BAND,
                        band,
                        max_acceleration: 0,
                    },
                ))
            }
            _ => Err(why),
        }
    }

    /// The row a controller's read-back shows; `None` for an empty row (no velocity: never
    /// written).
    pub fn from_wire(point: u8, readback: &PointReadback, scale: &Scale) -> Option<Row> {
        let velocity = u16::try_from(readback.get(PointField::Velocity))
            .ok()
            .and_then(Velocity::new)
            .filter(|v| v.get() > 0)?;
        let acceleration = u16::try_from(readback.get(PointField::Acceleration))
            .ok()
            .and_then(Acceleration::new)?;
        let position = scale.position_from_wire(Pulses(readback.get(PointField::Position) as i32));
        // INP is a magnitude (band_to_wire), never complemented like a distance.
        let band = scale.length(i64::from(readback.get(PointField::Band)));
        Some(Row {
            point,
            position: position.0,
            speed: scale.speed(velocity).0,
            accel: scale.accel(acceleration).0,
            band: u32::try_from(band.0).unwrap_or(0),
        })
    }

    pub fn describe(&self) -> String {
        format!(
            "{} mm at {} mm/s, {} G, band {} mm",
            text(self.position.into()),
            text(self.speed.into()),
            text(self.accel.into()),
            text(self.band.into())
        )
    }
}

/// Where the axis can go: positions beyond are clamped by the controller, so refused.
#[derive(Clone, Copy, Debug, Default)]
pub struct Travel {
    /// The stroke given with `--stroke`, 0.01 mm.
    pub stroke: Option<i32>,
    /// The soft limits read from the controller (LIML, LIMM), as on the wire.
    pub soft: Option<(Pulses, Pulses)>,
}

impl Travel {
    /// Why `position` (0.01 mm from home; `wire` as the controller stores it) is outside.
    fn refuse(&self, position: i32, wire: Pulses, scale: &Scale) -> Option<String> {
        let mm = text(position.into());
        if position < 0 {
            return Some(format!(
                "position {mm} mm: behind the home end (positions are measured from home, \
                 0 and up)"
            ));
        }
        if let Some(stroke) = self.stroke.filter(|&s| position > s) {
            return Some(format!(
                "position {mm} mm: beyond the stroke, {} mm (--stroke)",
                text(stroke.into())
            ));
        }
        let (low, high) = self.soft?;
        let limit = if wire.0 > high.0 {
            ("LIMM", high)
        } else if wire.0 < low.0 {
            ("LIML", low)
        } else {
            return None;
        };
        Some(format!(
            "position {mm} mm: beyond the controller's soft limit {} at {} mm, where it would \
             stop instead",
            limit.0,
            text(scale.position_from_wire(limit.1).0.into())
        ))
    }
}

/// Every entry as the controller stores it; or, if any row would be refused, clamped or lost,
/// every such row with its line and reasons (and nothing is to be written).
pub fn check(
    entries: &[Entry],
    path: &Path,
    scale: &Scale,
    travel: &Travel,
) -> Result<Vec<(PositionNo, PointData)>, String> {
    let mut stored = Vec::new();
    let mut refused = Vec::new();
    let mut rows = 0;
    for entry in entries {
        let mut why = match entry.row.to_wire(scale) {
            Ok(wire) => {
                stored.push(wire);
                Vec::new()
            }
            Err(why) => why,
        };
        if let Ok(wire) = scale.position_to_wire(Length(entry.row.position)) {
            why.extend(travel.refuse(entry.row.position, wire, scale));
        }
        rows += usize::from(!why.is_empty());
        for reason in why {
            refused.push(format!(
                "{}:{}: point {}: {reason}",
                path.display(),
                entry.line,
                entry.row.point
            ));
        }
    }
    if refused.is_empty() {
        Ok(stored)
    } else {
        Err(format!(
            "nothing written: {rows} of {} rows the controller would refuse, clamp or lose\n{}",
            entries.len(),
            refused.join("\n")
        ))
    }
}

/// The soft limits' positions in mm from home, low to high (for messages).
pub fn soft_limits_mm(soft: (Pulses, Pulses), scale: &Scale) -> (String, String) {
    let a = scale.position_from_wire(soft.0).0;
    let b = scale.position_from_wire(soft.1).0;
    let (low, high) = if a <= b { (a, b) } else { (b, a) };
    (text(low.into()), text(high.into()))
}

fn is_toml(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("toml"))
}

/// The 1-based line of a byte offset.
fn line_of(content: &str, offset: usize) -> usize {
    content
        .get(..offset)
        .map_or(1, |s| s.matches('\n').count() + 1)
}

fn read_toml(path: &Path, content: &str) -> Result<Vec<Entry>, String> {
    let file: TomlInput =
        toml::from_str(content).map_err(|e| format!("{}: {e}", path.display()))?;
    file.point
        .iter()
        .map(|spanned| {
            let line = line_of(content, spanned.span().start);
            let r = spanned.get_ref();
            let at = |why: String| format!("{}:{line}: {why}", path.display());
            let values = [
                hundredths(r.position_mm, "position_mm").map_err(at)?,
                hundredths(r.speed_mm_s, "speed_mm_s").map_err(at)?,
                hundredths(r.accel_g, "accel_g").map_err(at)?,
                hundredths(r.band_mm, "band_mm").map_err(at)?,
            ];
            let row = Row::from_hundredths(r.point, values).map_err(at)?;
            Ok(Entry { line, row })
        })
        .collect()
}

fn read_csv(path: &Path, content: &str) -> Result<Vec<Entry>, String> {
    let expected = COLUMNS.join(",");
    let mut lines = content
        .lines()
        .enumerate()
        .map(|(n, line)| (n + 1, line.trim()))
        .filter(|(_, line)| !line.is_empty() && !line.starts_with('#'));
    let Some((header_line, header)) = lines.next() else {
        return Err(format!(
            "{}: no header and no rows (expected a header such as {expected})",
            path.display()
        ));
    };
    let at = |n: usize, why: String| format!("{}:{n}: {why}", path.display());
    // Which field of a row holds each of COLUMNS.
    let mut index = [None::<usize>; COLUMNS.len()];
    for (i, name) in header.split(',').map(str::trim).enumerate() {
        let Some(column) = COLUMNS.iter().position(|c| c.eq_ignore_ascii_case(name)) else {
            let hint = if name.parse::<f64>().is_ok() {
                "the first line must be the header naming the columns".to_string()
            } else {
                format!("unknown column `{name}`")
            };
            return Err(at(
                header_line,
                format!("{hint} (the columns, in any order: {expected})"),
            ));
        };
        if index[column].replace(i).is_some() {
            return Err(at(header_line, format!("column `{name}` twice")));
        }
    }
    let missing: Vec<&str> = COLUMNS
        .iter()
        .zip(index)
        .filter(|(_, i)| i.is_none())
        .map(|(c, _)| *c)
        .collect();
    if !missing.is_empty() {
        return Err(at(
            header_line,
            format!(
                "no column {} (the columns, in any order: {expected})",
                missing
                    .iter()
                    .map(|c| format!("`{c}`"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        ));
    }
    let width = header.split(',').count();
    let mut entries = Vec::new();
    for (n, line) in lines {
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != width {
            return Err(at(
                n,
                format!("{} fields, the header has {width}", fields.len()),
            ));
        }
        let field = |column: usize| {
            index
                .get(column)
                .copied()
                .flatten()
                .and_then(|i| fields.get(i))
                .copied()
                .unwrap_or("")
        };
        let point = field(0);
        let point: u8 = point
            .parse()
            .map_err(|_| at(n, format!("point {point:?}: a point number 0-15")))?;
        let mut values = [0i64; 4];
        for (k, value) in values.iter_mut().enumerate() {
            let name = COLUMNS.get(k + 1).copied().unwrap_or("");
            let text = field(k + 1);
            *value = exact_hundredths(text).map_err(|e| at(n, format!("{name}: {e}")))?;
        }
        let row = Row::from_hundredths(point, values).map_err(|e| at(n, e))?;
        entries.push(Entry { line: n, row });
    }
    Ok(entries)
}

/// Read a table file (TOML by its extension, CSV otherwise).
pub fn read(path: &Path) -> Result<Vec<Entry>, String> {
    let content = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let entries = if is_toml(path) {
        read_toml(path, &content)?
    } else {
        read_csv(path, &content)?
    };
    let mut seen: Vec<&Entry> = Vec::new();
    for entry in &entries {
        if let Some(first) = seen.iter().find(|e| e.row.point == entry.row.point) {
            return Err(format!(
                "{}:{}: point {} twice (first on line {})",
                path.display(),
                entry.line,
                entry.row.point,
                first.line
            ));
        }
        seen.push(entry);
    }
    Ok(entries)
}

/// The table as file content (TOML by the path's extension, CSV otherwise).
pub fn render(rows: &[Row], path: Option<&Path>) -> Result<String, String> {
    let value = |h: i64| text(h).parse::<f64>().unwrap_or(0.0);
    if path.is_some_and(is_toml) {
        let file = TomlFile {
            point: rows
                .iter()
                .map(|r| TomlRow {
                    point: r.point,
                    position_mm: value(r.position.into()),
                    speed_mm_s: value(r.speed.into()),
                    accel_g: value(r.accel.into()),
                    band_mm: value(r.band.into()),
                })
                .collect(),
        };
        return toml::to_string(&file).map_err(|e| e.to_string());
    }
    let mut out = format!("{}\n", COLUMNS.join(","));
    for r in rows {
        out.push_str(&format!(
            "{},{},{},{},{}\n",
            r.point,
            text(r.position.into()),
            text(r.speed.into()),
            text(r.accel.into()),
            text(r.band.into())
        ));
    }
    Ok(out)
}
