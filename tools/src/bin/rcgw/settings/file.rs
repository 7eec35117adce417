//! The settings as TOML text: each value parsed and checked for its form and range (every
//! problem reported), and printed with the units in the key names.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use protocol::axes::AXES;
use protocol::plc::write::GatewayWrite;

use super::schema::{field, range_text, Field, Kind, Section};
use super::Settings;

/// An `[axis.N]` table's number: 0-15, written as a plain number (`[axis.01]` would be a
/// second table for axis 1).
pub fn axis_number(key: &str) -> Result<u8, String> {
    match key.parse::<u8>() {
        Ok(n) if usize::from(n) < AXES && n.to_string() == key => Ok(n),
        Ok(n) if usize::from(n) < AXES => Err(format!(
            "[axis.{key}]: write the axis number as [axis.{n}] (one table per axis)"
        )),
        _ => Err(format!("[axis.{key}]: no such axis (0-{})", AXES - 1)),
    }
}

/// The TOML text of a setting's registers.
pub(super) fn render(kind: Kind, regs: &[u16]) -> String {
    let word = |i: usize| regs.get(i).copied().unwrap_or(0);
    let ip = |i: usize| {
        let [a, b] = word(i).to_be_bytes();
        let [c, d] = word(i + 1).to_be_bytes();
        format!("{a}.{b}.{c}.{d}")
    };
    match kind {
        Kind::Int(factor) => (u32::from(word(0)) * factor).to_string(),
        Kind::Hundredths => hundredths(i64::from(word(0))),
        Kind::Hundredths32 => hundredths(i64::from(u32::from(word(0)) << 16 | u32::from(word(1)))),
        Kind::Bool => (word(0) == 1).to_string(),
        Kind::Enum(names) => names
            .iter()
            .find(|(_, v)| *v == word(0))
            .map_or_else(|| word(0).to_string(), |(n, _)| format!("\"{n}\"")),
        Kind::PioAxis if word(0) == 0xFFFF => "\"none\"".into(),
        Kind::PioAxis => word(0).to_string(),
        Kind::Ipv4 => format!("\"{}\"", ip(0)),
        Kind::Ipv4List => {
            let list: Vec<String> = (0..4)
                .map(|i| ip(2 * i))
                .filter(|a| a != "0.0.0.0")
                .map(|a| format!("\"{a}\""))
                .collect();
            format!("[{}]", list.join(", "))
        }
    }
}

/// 0.01 units as a decimal with 2 places.
pub fn hundredths(v: i64) -> String {
    let sign = if v < 0 { "-" } else { "" };
    format!("{sign}{}.{:02}", v.abs() / 100, v.abs() % 100)
}

/// A number in the file with at most 2 decimals, in 0.01 units.
pub fn parse_hundredths(value: &toml::Value) -> Result<i64, String> {
    let x = match value {
        toml::Value::Integer(i) => *i as f64,
        toml::Value::Float(x) => *x,
        _ => return Err(format!("{value} is not a number")),
    };
    let scaled = x * 100.0;
    if !scaled.is_finite() || (scaled - scaled.round()).abs() > 1e-6 || scaled.abs() > 1e12 {
        return Err(format!("{value}: at most 2 decimals"));
    }
    Ok(scaled.round() as i64)
}

fn parse_ip(value: &toml::Value) -> Result<[u16; 2], String> {
    let text = value
        .as_str()
        .ok_or_else(|| format!("{value} is not an IPv4 address in quotes"))?;
    let ip: std::net::Ipv4Addr = text
        .parse()
        .map_err(|_| format!("\"{text}\" is not an IPv4 address"))?;
    let [a, b, c, d] = ip.octets();
    Ok([u16::from_be_bytes([a, b]), u16::from_be_bytes([c, d])])
}

/// A TOML value as the setting's registers, checked for its form and for fitting its
/// registers (the gateway's own range rules come after: `GatewayWrite::parse`). A value out of
/// range says so with the range in the file's units, before its form (decimals, multiples) is
/// looked at.
fn parse(section: Section, field: Field, value: &toml::Value) -> Result<Vec<u16>, String> {
    let range = || format!("out of range (allowed: {})", range_text(section, field));
    let int = || {
        value
            .as_integer()
            .ok_or_else(|| format!("{value} is not a whole number"))
    };
    // A number in 0.01 units, its magnitude checked before its decimals.
    let hundredths = |max: i64| -> Result<i64, String> {
        let x = match value {
            toml::Value::Integer(i) => *i as f64,
            toml::Value::Float(x) => *x,
            _ => return Err(format!("{value} is not a number")),
        };
        if !(x * 100.0 >= -0.5 && x * 100.0 <= max as f64 + 0.5) {
            return Err(range());
        }
        parse_hundredths(value)
    };
    Ok(match field.kind {
        Kind::Int(factor) => {
            let v = int()?;
            let word = u16::try_from(v / i64::from(factor))
                .ok()
                .filter(|_| v >= 0)
                .ok_or_else(range)?;
            if v % i64::from(factor) != 0 {
                return Err(format!("{v} is not a multiple of {factor}"));
            }
            vec![word]
        }
        Kind::Hundredths => vec![u16::try_from(hundredths(65_535)?).map_err(|_| range())?],
        Kind::Hundredths32 => {
            let v = u32::try_from(hundredths(i64::from(i32::MAX))?).map_err(|_| range())?;
            vec![(v >> 16) as u16, v as u16]
        }
        Kind::Bool => vec![u16::from(
            value
                .as_bool()
                .ok_or_else(|| format!("{value} is not true or false"))?,
        )],
        Kind::Enum(names) => {
            let text = value.as_str().unwrap_or("");
            let choices: Vec<&str> = names.iter().map(|(n, _)| *n).collect();
            vec![names
                .iter()
                .find(|(n, _)| *n == text)
                .map(|(_, v)| *v)
                .ok_or_else(|| format!("{value} is not one of \"{}\"", choices.join("\", \"")))?]
        }
        Kind::PioAxis => match value.as_str() {
            Some("none") => vec![0xFFFF],
            Some(_) => return Err(format!("{value} is not an axis 0-15 or \"none\"")),
            None => vec![u16::try_from(int()?)
                .ok()
                .filter(|&a| usize::from(a) < AXES)
                .ok_or_else(range)?],
        },
        Kind::Ipv4 => parse_ip(value)?.to_vec(),
        Kind::Ipv4List => {
            let list = value
                .as_array()
                .ok_or_else(|| format!("{value} is not a list of IPv4 addresses"))?;
            if list.len() > 4 {
                return Err(format!("{} addresses: at most 4", list.len()));
            }
            let mut regs = vec![0u16; 8];
            for (i, item) in list.iter().enumerate() {
                let [hi, lo] = parse_ip(item)?;
                regs[2 * i] = hi;
                regs[2 * i + 1] = lo;
            }
            regs
        }
    })
}

impl Settings {
    /// The TOML text: `[gateway]`, `[network]`, then `[axis.N]` for every axis.
    pub fn to_toml(&self) -> String {
        self.to_toml_with(&|_| String::new())
    }

    /// The TOML text, with `extra(section)` after each section's keys.
    pub fn to_toml_with(&self, extra: &dyn Fn(Section) -> String) -> String {
        let mut out = String::new();
        let mut sections: Vec<Section> = self.values.keys().map(|(s, _)| *s).collect();
        sections.dedup();
        for section in sections {
            let _ = writeln!(out, "\n{}", section.name());
            for field in section.fields() {
                if let Some(regs) = self.values.get(&(section, field.key)) {
                    let _ = writeln!(out, "{} = {}", field.key, render(field.kind, regs));
                }
            }
            out.push_str(&extra(section));
        }
        out
    }

    /// The settings as JSON (section -> key -> TOML text parsed back as a value).
    pub fn to_json(&self) -> serde_json::Value {
        let text = self.to_toml();
        let value: toml::Value = toml::from_str(&text).unwrap_or(toml::Value::Integer(0));
        serde_json::to_value(value).unwrap_or_default()
    }

    /// Settings from a parsed TOML document's `gateway`, `network` and `axis` tables, every
    /// value checked for its form and range. Every problem is reported, one line each.
    /// `others` are the other top-level keys the caller reads itself; `points`: a `point` list
    /// is allowed in an `axis.N` table (a backup), nowhere else.
    pub fn from_toml(
        doc: &toml::Table,
        others: &[&str],
        points: bool,
    ) -> Result<Settings, Vec<String>> {
        let mut errors = Vec::new();
        let mut values = BTreeMap::new();
        let mut sections: Vec<(Section, &toml::Table)> = Vec::new();
        for (key, value) in doc {
            match (key.as_str(), value) {
                ("gateway", toml::Value::Table(t)) => sections.push((Section::Gateway, t)),
                ("network", toml::Value::Table(t)) => sections.push((Section::Network, t)),
                ("axis", toml::Value::Table(axes)) => {
                    for (n, table) in axes {
                        match (axis_number(n), table) {
                            (Ok(n), toml::Value::Table(t)) => sections.push((Section::Axis(n), t)),
                            (Err(e), _) => errors.push(e),
                            (_, _) => errors.push(format!("axis.{n}: not a table")),
                        }
                    }
                }
                (k @ ("gateway" | "network" | "axis"), _) => {
                    errors.push(format!("{k}: not a table ([{k}])"))
                }
                (k, _) if others.contains(&k) => {}
                (k, _) => errors.push(format!("unknown key \"{k}\" (expected {})", {
                    let mut keys = vec!["[gateway]", "[network]", "[axis.N]"];
                    keys.extend(others.iter().copied());
                    keys.join(", ")
                })),
            }
        }
        for (section, table) in sections {
            for (key, value) in table {
                if key == "point" && points && matches!(section, Section::Axis(_)) {
                    continue;
                }
                let Some(field) = field(section, key) else {
                    let keys: Vec<&str> = section.fields().iter().map(|f| f.key).collect();
                    errors.push(format!(
                        "{} {key}: unknown key (one of {}{})",
                        section.name(),
                        keys.join(", "),
                        if points && matches!(section, Section::Axis(_)) {
                            ", [[point]]"
                        } else {
                            ""
                        }
                    ));
                    continue;
                };
                let first = section.base() + field.address;
                match parse(section, field, value) {
                    Err(e) if e.starts_with("out of range") => errors.push(format!(
                        "{} {key} = {value}: {e} (register {first:#06x})",
                        section.name()
                    )),
                    Err(e) => errors.push(format!("{} {key} = {value}: {e}", section.name())),
                    Ok(regs) => {
                        for (i, &v) in regs.iter().enumerate() {
                            let address = first + i as u16;
                            if GatewayWrite::parse(address, v).is_err() {
                                errors.push(format!(
                                    "{} {key} = {value}: out of range (allowed: {}) (register {address:#06x})",
                                    section.name(),
                                    range_text(section, field)
                                ));
                                break;
                            }
                        }
                        values.insert((section, field.key), regs);
                    }
                }
            }
        }
        if errors.is_empty() {
            Ok(Settings { values })
        } else {
            Err(errors)
        }
    }
}
