//! The point table in a file: CSV (`point,position_mm,speed_mm_s,accel_g,band_mm`) or TOML
//! (`[[point]]` tables with the same keys), in the units a machine builder reads on a drawing.

use std::path::Path;

use protocol::jobs::{PointData, PointReadback};
use protocol::memory::PointField;
use protocol::units::{Accel, Length, Scale, Speed};
use protocol::{Acceleration, PositionNo, Pulses, Velocity};
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

#[derive(Deserialize, Serialize)]
struct TomlRow {
    point: u8,
    position_mm: f64,
    speed_mm_s: f64,
    accel_g: f64,
    band_mm: f64,
}

#[derive(Deserialize, Serialize)]
struct TomlFile {
    point: Vec<TomlRow>,
}

const HEADER: &str = "point,position_mm,speed_mm_s,accel_g,band_mm";

fn hundredths(value: f64, what: &str) -> Result<i64, String> {
    let scaled = (value * 100.0).round();
    if !scaled.is_finite() || scaled.abs() > 2e9 {
        return Err(format!("{what} {value}: out of range"));
    }
    Ok(scaled as i64)
}

fn text(hundredths: i64) -> String {
    let sign = if hundredths < 0 { "-" } else { "" };
    format!(
        "{sign}{}.{:02}",
        hundredths.abs() / 100,
        hundredths.abs() % 100
    )
}

impl Row {
    fn from_values(point: u8, values: [f64; 4]) -> Result<Row, String> {
        let [position, speed, accel, band] = values;
        let unsigned = |v: f64, what: &str| {
            u32::try_from(hundredths(v, what)?).map_err(|_| format!("{what} {v}: must be >= 0"))
        };
        Ok(Row {
            point,
            position: i32::try_from(hundredths(position, "position")?)
                .map_err(|_| format!("position {position}: out of range"))?,
            speed: unsigned(speed, "speed")?,
            accel: unsigned(accel, "acceleration")?,
            band: unsigned(band, "band")?,
        })
    }

    /// The row as the controller stores it.
    pub fn to_wire(self, scale: &Scale) -> Result<(PositionNo, PointData), String> {
        let point = PositionNo::new(self.point)
            .ok_or_else(|| format!("point {}: the Robo Cylinder has points 0-15", self.point))?;
        let point_no = self.point;
        let err = |what: &'static str| move |e| format!("point {point_no}: {what}: {e:?}");
        Ok((
            point,
            PointData {
                position: scale
                    .position_to_wire(Length(self.position))
                    .map_err(err("position"))?,
                velocity: scale.velocity(Speed(self.speed)).map_err(err("speed"))?,
                acceleration: scale
                    .acceleration(Accel(self.accel))
                    .map_err(err("acceleration"))?,
                flags: PointData::FLAGS_MOTION_AND_BAND,
                band: scale
                    .band_to_wire(Length(i32::try_from(self.band).unwrap_or(i32::MAX)))
                    .map_err(err("band"))?,
                max_acceleration: 0,
            },
        ))
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

fn is_toml(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("toml"))
}

/// Read a table file (TOML by its extension, CSV otherwise).
pub fn read(path: &Path) -> Result<Vec<Row>, String> {
    let content = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let rows = if is_toml(path) {
        let file: TomlFile =
            toml::from_str(&content).map_err(|e| format!("{}: {e}", path.display()))?;
        file.point
            .iter()
            .map(|r| Row::from_values(r.point, [r.position_mm, r.speed_mm_s, r.accel_g, r.band_mm]))
            .collect::<Result<Vec<_>, _>>()?
    } else {
        let mut rows = Vec::new();
        for (n, line) in content.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') || line == HEADER {
                continue;
            }
            let at = |why: String| format!("{}:{}: {why}", path.display(), n + 1);
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            let [point, rest @ ..] = fields.as_slice() else {
                return Err(at("empty line".into()));
            };
            let point: u8 = point
                .parse()
                .map_err(|_| at(format!("{point:?}: a point number")))?;
            let values: Vec<f64> = rest
                .iter()
                .map(|v| v.parse::<f64>().map_err(|_| at(format!("{v:?}: a number"))))
                .collect::<Result<_, _>>()?;
            let values: [f64; 4] = values
                .try_into()
                .map_err(|_| at(format!("expected {HEADER}")))?;
            rows.push(Row::from_values(point, values).map_err(at)?);
        }
        rows
    };
    let mut seen = Vec::new();
    for row in &rows {
        if seen.contains(&row.point) {
            return Err(format!("{}: point {} twice", path.display(), row.point));
        }
        seen.push(row.point);
    }
    Ok(rows)
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
    let mut out = format!("{HEADER}\n");
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
