//! The gateway's settings as registers of the gateway unit, and as TOML with the units in the
//! key names: read, shown, checked (every value, before anything is written), compared and
//! written.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::{Duration, Instant};

use protocol::axes::AxisSet;
use protocol::axes::AXES;
use protocol::modbus::Exception;
use protocol::plc::map::*;
use protocol::plc::write::{AxisSetting, GatewayWrite};
use protocol::plc::{admit, AxisBase, Conflict, Pending, UnitId};

use crate::link::{Fail, Gw};

/// How a setting's registers read as a TOML value.
#[derive(Clone, Copy, Debug)]
enum Kind {
    /// A number, times `factor` in the file (bit/s written in 100 bit/s).
    Int(u32),
    /// 0.01 in one register, the file in whole units with 2 decimals.
    Hundredths,
    /// 0.01 in two registers (high word first).
    Hundredths32,
    Bool,
    Enum(&'static [(&'static str, u16)]),
    /// 0-15, or "none" for 0xFFFF.
    PioAxis,
    /// An IPv4 address in two registers.
    Ipv4,
    /// Four IPv4 addresses, empty slots 0.0.0.0 left out of the file.
    Ipv4List,
}

impl Kind {
    fn width(self) -> u16 {
        match self {
            Kind::Hundredths32 | Kind::Ipv4 => 2,
            Kind::Ipv4List => 8,
            _ => 1,
        }
    }
}

/// One setting: its key, its first register (offset in the axis block for axis settings).
#[derive(Clone, Copy, Debug)]
struct Field {
    key: &'static str,
    address: u16,
    kind: Kind,
    /// The values the gateway takes, in the file's units, for messages: for a setting whose
    /// map row has its allowed values, what follows them ([`range_text`]).
    range: &'static str,
}

/// The values a setting takes, in the file's units, for messages: a gateway or network
/// setting's from its map row (its spans, times the file's factor, with the unit its key
/// names), then the field's own words.
fn range_text(section: Section, field: Field) -> String {
    let entry = MAP
        .iter()
        .find(|e| e.unit == Unit::Gateway && e.address == field.address)
        .filter(|_| !matches!(section, Section::Axis(_)))
        .filter(|e| !e.allowed.is_empty());
    let Some(entry) = entry else {
        return field.range.into();
    };
    let value = |v: u16| match field.kind {
        Kind::Int(factor) => (u32::from(v) * factor).to_string(),
        Kind::Hundredths => hundredths(i64::from(v)),
        _ => v.to_string(),
    };
    let spans: Vec<String> = entry
        .allowed
        .iter()
        .map(|&(low, high)| match low == high {
            true => value(low),
            false => format!("{}-{}", value(low), value(high)),
        })
        .collect();
    let unit = [
        ("_mm_s", " mm/s"),
        ("_mm", " mm"),
        ("_ms", " ms"),
        ("_bps", " bit/s"),
        ("_s", " s"),
    ]
    .into_iter()
    .find(|(suffix, _)| field.key.ends_with(suffix))
    .map_or("", |(_, unit)| unit);
    format!("{}{unit}{}", spans.join(", "), field.range)
}

const fn f(key: &'static str, address: u16, kind: Kind, range: &'static str) -> Field {
    Field {
        key,
        address,
        kind,
        range,
    }
}

/// Whether a setting is taken on APPLY (not at once), as the register map says: its row's
/// `on_apply`; of AXISCFG (a block in the map), `enabled` only.
fn on_apply(section: Section, field: Field) -> bool {
    match section {
        Section::Axis(_) => field.address == 0,
        _ => MAP
            .iter()
            .find(|e| e.unit == Unit::Gateway && e.address == field.address)
            .is_some_and(|e| e.on_apply),
    }
}

const PARITY: &[(&str, u16)] = &[("none", 0), ("odd", 1), ("even", 2)];
const WD_ACTION: &[(&str, u16)] = &[("stop", 0), ("latch", 1)];
const PIO_START: &[(&str, u16)] = &[("level", 0), ("edge", 1)];
const HOME: &[(&str, u16)] = &[("motor", 7), ("far", 8)];
const ENCODING: &[(&str, u16)] = &[("ones-complement", 1), ("twos-complement", 2)];

const GATEWAY: &[Field] = &[
    f(
        "unit_id",
        G_UNIT_ID,
        Kind::Int(1),
        ", not an enabled axis' unit",
    ),
    f("axis_base", G_AXIS_BASE, Kind::Int(1), ""),
    f("plc_baud_bps", G_PLC_BAUD, Kind::Int(100), ""),
    f(
        "plc_parity",
        G_PLC_PARITY,
        Kind::Enum(PARITY),
        "\"none\", \"odd\", \"even\"",
    ),
    f("bus_baud_bps", G_BUS_BAUD, Kind::Int(100), ""),
    f("bus_rtim_ms", G_BUS_RTIM, Kind::Int(1), ""),
    f("retries", G_RETRIES, Kind::Int(1), ""),
    f("watchdog_ms", G_WATCHDOG, Kind::Int(1), ""),
    f(
        "watchdog_action",
        G_WD_ACTION,
        Kind::Enum(WD_ACTION),
        "\"stop\", \"latch\"",
    ),
    f("pio_axis", G_PIO_AXIS, Kind::PioAxis, "0-15 or \"none\""),
    f("pio_pattern", G_PIO_PATTERN, Kind::Int(1), ""),
    f(
        "pio_start",
        G_PIO_START,
        Kind::Enum(PIO_START),
        "\"level\", \"edge\"",
    ),
    f("pio_jog_mm_s", G_PIO_JOG, Kind::Hundredths, ""),
    f("pio_inch_mm", G_PIO_INCH, Kind::Hundredths, ""),
];

const AXIS: &[Field] = &[
    f("enabled", 0, Kind::Bool, "true, false"),
    f("lead_mm", 1, Kind::Hundredths, "0.01-655.35 mm"),
    f("home", 2, Kind::Enum(HOME), "\"motor\", \"far\""),
    f("pulses_per_rev", 3, Kind::Int(1), "1-65535"),
    f("stroke_mm", 4, Kind::Hundredths32, "0.00-21474836.47 mm"),
    f(
        "encoding",
        6,
        Kind::Enum(ENCODING),
        "\"ones-complement\", \"twos-complement\"",
    ),
];

const NETWORK: &[Field] = &[
    f("ip_address", G_NET, Kind::Ipv4, "an IPv4 address"),
    f("ip_prefix_bits", G_NET + 2, Kind::Int(1), ""),
    f(
        "ip_router",
        G_NET + 3,
        Kind::Ipv4,
        "an IPv4 address, \"0.0.0.0\" for none",
    ),
    f("tcp_max_connections", G_NET + 5, Kind::Int(1), ""),
    f("tcp_idle_s", G_NET + 6, Kind::Int(1), ""),
    f(
        "tcp_allow",
        G_NET + 8,
        Kind::Ipv4List,
        "up to 4 IPv4 addresses",
    ),
];

/// Which section a setting is in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Section {
    Gateway,
    Network,
    Axis(u8),
}

impl Section {
    fn name(self) -> String {
        match self {
            Section::Gateway => "[gateway]".into(),
            Section::Network => "[network]".into(),
            Section::Axis(n) => format!("[axis.{n}]"),
        }
    }

    fn fields(self) -> &'static [Field] {
        match self {
            Section::Gateway => GATEWAY,
            Section::Network => NETWORK,
            Section::Axis(_) => AXIS,
        }
    }

    fn base(self) -> u16 {
        match self {
            Section::Axis(n) => G_AXIS_CONFIG + G_AXIS_CONFIG_LEN * u16::from(n),
            _ => 0,
        }
    }
}

/// Settings: each setting's registers, by section and key (a file may hold some only).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Settings {
    pub values: BTreeMap<(Section, &'static str), Vec<u16>>,
}

fn field(section: Section, key: &str) -> Option<Field> {
    section.fields().iter().copied().find(|f| f.key == key)
}

/// A section's name as the file writes it (`[gateway]`).
pub fn section_name(section: Section) -> String {
    section.name()
}

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
fn render(kind: Kind, regs: &[u16]) -> String {
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
    /// Every setting of the gateway; the network block if it answers (02 on builds without
    /// TCP).
    pub fn read(gw: &mut Gw) -> Result<Settings, Fail> {
        let unit = gw.unit;
        let mut values = BTreeMap::new();
        let block = gw.read(unit, 0, G_AXIS_BASE + 1)?;
        for field in GATEWAY {
            let at = usize::from(field.address);
            let regs = block
                .get(at..at + usize::from(field.kind.width()))
                .unwrap_or(&[]);
            values.insert((Section::Gateway, field.key), regs.to_vec());
        }
        let half = (AXES as u16 / 2) * G_AXIS_CONFIG_LEN;
        let mut axes = gw.read(unit, G_AXIS_CONFIG, half)?;
        axes.extend(gw.read(unit, G_AXIS_CONFIG + half, half)?);
        for n in 0..AXES as u8 {
            let section = Section::Axis(n);
            for field in AXIS {
                let at = usize::from(section.base() - G_AXIS_CONFIG + field.address);
                let regs = axes
                    .get(at..at + usize::from(field.kind.width()))
                    .unwrap_or(&[]);
                values.insert((section, field.key), regs.to_vec());
            }
        }
        match gw.try_read(unit, G_NET, G_NET_LEN)? {
            Ok(net) => {
                for field in NETWORK {
                    let at = usize::from(field.address - G_NET);
                    let regs = net
                        .get(at..at + usize::from(field.kind.width()))
                        .unwrap_or(&[]);
                    values.insert((Section::Network, field.key), regs.to_vec());
                }
            }
            Err(Exception::IllegalDataAddress) => {}
            Err(e) => return Err(Fail::Device(format!("{}: {e}", gw.at(unit, G_NET)))),
        }
        Ok(Settings { values })
    }

    /// Axis `n`'s AXISCFG block as registers (enabled, lead, home, pulses/rev, stroke (2),
    /// complement), 0 for a setting not held.
    pub fn axis_cfg(&self, n: u8) -> Vec<u16> {
        let section = Section::Axis(n);
        let mut regs = vec![0u16; usize::from(G_AXIS_CONFIG_LEN)];
        for field in AXIS {
            if let Some(v) = self.values.get(&(section, field.key)) {
                for (i, &w) in v.iter().enumerate() {
                    if let Some(slot) = regs.get_mut(usize::from(field.address) + i) {
                        *slot = w;
                    }
                }
            }
        }
        regs
    }

    /// The axes enabled (AXISCFG: pending until APPLY), read.
    pub fn read_enabled(gw: &mut Gw) -> Result<Vec<u8>, Fail> {
        let unit = gw.unit;
        let half = (AXES as u16 / 2) * G_AXIS_CONFIG_LEN;
        let mut all = gw.read(unit, G_AXIS_CONFIG, half)?;
        all.extend(gw.read(unit, G_AXIS_CONFIG + half, half)?);
        Ok((0..AXES as u8)
            .filter(|&n| all.get(usize::from(n) * usize::from(G_AXIS_CONFIG_LEN)) == Some(&1))
            .collect())
    }

    /// Whether the gateway has the network block.
    pub fn has_network(&self) -> bool {
        self.values.keys().any(|(s, _)| *s == Section::Network)
    }

    /// The raw registers of a setting.
    pub fn word(&self, section: Section, key: &str) -> Option<u16> {
        self.values
            .iter()
            .find(|((s, k), _)| *s == section && *k == key)
            .and_then(|(_, v)| v.first().copied())
    }

    /// The axes enabled.
    pub fn enabled(&self) -> Vec<u8> {
        (0..AXES as u8)
            .filter(|&n| self.word(Section::Axis(n), "enabled") == Some(1))
            .collect()
    }

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

    /// `self` with `file`'s settings over it.
    pub fn merged(&self, file: &Settings) -> Settings {
        let mut out = self.clone();
        for (k, v) in &file.values {
            out.values.insert(*k, v.clone());
        }
        out
    }

    /// The checks across settings, on the settings as they would be: the gateway's unit not an
    /// enabled axis' unit; enabled axes within the unit range.
    pub fn check_whole(&self) -> Vec<String> {
        let mut errors = Vec::new();
        let unit = self.word(Section::Gateway, "unit_id").unwrap_or(63);
        let base = self.word(Section::Gateway, "axis_base").unwrap_or(1);
        for n in self.enabled() {
            let axis_unit = base + u16::from(n);
            if axis_unit == unit {
                errors.push(format!(
                    "[gateway] unit_id = {unit}: axis {n} is enabled and would be unit {axis_unit} (axis_base {base} + {n}); choose a unit outside the axes' range"
                ));
            }
            if axis_unit > 247 {
                errors.push(format!(
                    "[axis.{n}] enabled: its unit would be {axis_unit} (axis_base {base} + {n}), past 247"
                ));
            }
        }
        errors
    }

    /// The settings of `target` that differ from `self`: (section, key, now, then).
    pub fn diff(&self, target: &Settings) -> Vec<Change> {
        target
            .values
            .iter()
            .filter(|(k, v)| self.values.get(k) != Some(v))
            .filter_map(|((section, key), to)| {
                let field = field(*section, key)?;
                let from = self.values.get(&(*section, *key));
                Some(Change {
                    section: *section,
                    key,
                    address: section.base() + field.address,
                    from: from.map(|r| render(field.kind, r)),
                    to: render(field.kind, to),
                    regs: to.clone(),
                    on_apply: on_apply(*section, field),
                })
            })
            .collect()
    }
}

/// One setting to change.
#[derive(Clone, Debug)]
pub struct Change {
    pub section: Section,
    pub key: &'static str,
    pub address: u16,
    pub from: Option<String>,
    pub to: String,
    pub regs: Vec<u16>,
    pub on_apply: bool,
}

impl Change {
    pub fn line(&self) -> String {
        format!(
            "{} {}: {} -> {}{}",
            self.section.name(),
            self.key,
            self.from.as_deref().unwrap_or("(none)"),
            self.to,
            if self.on_apply {
                " (on APPLY)"
            } else if self.on_restart() {
                " (after SAVE and RESTART)"
            } else {
                ""
            }
        )
    }

    /// Taken only at the next start (the network address settings).
    pub fn on_restart(&self) -> bool {
        self.section == Section::Network && self.key.starts_with("ip_")
    }
}

/// A change in JSON: `{"section": "[gateway]", "key", "register": "0x0001", "from", "to",
/// "on_apply", "on_restart"}`.
impl serde::Serialize for Change {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        #[derive(serde::Serialize)]
        struct Json<'a> {
            section: String,
            key: &'a str,
            register: String,
            from: &'a Option<String>,
            to: &'a str,
            on_apply: bool,
            on_restart: bool,
        }
        Json {
            section: self.section.name(),
            key: self.key,
            register: format!("{:#06x}", self.address),
            from: &self.from,
            to: &self.to,
            on_apply: self.on_apply,
            on_restart: self.on_restart(),
        }
        .serialize(serializer)
    }
}

/// The settings a sequence of writes meets, as the gateway keeps them: every register of a
/// change parsed and admitted by the gateway's own rules (`plc::admit`) on the settings the
/// writes before it left; APPLY puts the enabled axes on the bus.
#[derive(Clone, Copy, Debug)]
struct Admit(Pending);

impl Admit {
    /// The gateway as read: the enabled axes on the bus (nothing pending).
    fn of(now: &Settings) -> Admit {
        let word = |key| {
            now.word(Section::Gateway, key)
                .and_then(|w| u8::try_from(w).ok())
        };
        let enabled = AxisSet(now.enabled().iter().fold(0u16, |m, &n| m | 1 << n));
        Admit(Pending {
            unit: word("unit_id").and_then(UnitId::new).unwrap_or_default(),
            axis_base: word("axis_base")
                .and_then(AxisBase::new)
                .unwrap_or_default(),
            enabled,
            bus: enabled,
        })
    }

    /// One change written: refused with the reason, as the gateway would.
    fn write(&mut self, c: &Change) -> Result<(), String> {
        for (i, &value) in c.regs.iter().enumerate() {
            let address = c.address + i as u16;
            let write = GatewayWrite::parse(address, value).map_err(|e| {
                format!(
                    "{} {} = {}: register {address:#06x} refused ({e:?})",
                    c.section.name(),
                    c.key,
                    c.to
                )
            })?;
            admit(&self.0, write).map_err(|conflict| self.why(write, conflict))?;
            match write {
                GatewayWrite::UnitId(unit) => self.0.unit = unit,
                GatewayWrite::AxisBase(base) => self.0.axis_base = base,
                GatewayWrite::Axis(axis, AxisSetting::Enabled(on)) => {
                    self.0.enabled = if on {
                        self.0.enabled.with(axis)
                    } else {
                        self.0.enabled.without(axis)
                    };
                }
                _ => {}
            }
        }
        Ok(())
    }

    /// Why the gateway refuses `write`, in words.
    fn why(&self, write: GatewayWrite, conflict: Conflict) -> String {
        let Admit(Pending {
            unit, axis_base, ..
        }) = *self;
        match (write, conflict) {
            (GatewayWrite::UnitId(value), Conflict::AxisUnit(axis)) => format!(
                "UNITID {value} while axis {n} (enabled or on the bus until APPLY) is unit {value} (AXISBASE {axis_base} + {n})",
                n = axis.get()
            ),
            (GatewayWrite::AxisBase(value), Conflict::AxisUnit(axis)) => format!(
                "AXISBASE {value} while UNITID is {unit}: axis {n} (enabled or on the bus until APPLY) would be unit {unit}",
                n = axis.get()
            ),
            (GatewayWrite::Axis(..), Conflict::AxisUnit(axis)) => format!(
                "axis {n} enabled while it would be unit {unit} (AXISBASE {axis_base} + {n}), the gateway's UNITID",
                n = axis.get()
            ),
            (write, conflict) => format!("{write:?} refused: {conflict:?}"),
        }
    }

    fn apply(&mut self) {
        self.0.bus = self.0.enabled;
    }
}

/// The changes in phases the gateway admits one write after the other, an APPLY after each
/// phase but the last (which is followed by one only if a change of it is taken on APPLY).
/// Axes disabled come first; UNITID, AXISBASE and the axes enabled in the order that does
/// not collide (UNITID first when the new base would cover the current unit); when every
/// order collides, two phases with an APPLY between. `Err`: no order works (nothing to be
/// written), with the gateway's reason.
pub fn plan(now: &Settings, changes: &[Change]) -> Result<Vec<Vec<Change>>, String> {
    let is = |c: &Change, section: Section, key: &str| c.section == section && c.key == key;
    let disables: Vec<Change> = changes
        .iter()
        .filter(|c| matches!(c.section, Section::Axis(_)) && c.key == "enabled" && c.regs == [0])
        .cloned()
        .collect();
    let enables: Vec<Change> = changes
        .iter()
        .filter(|c| matches!(c.section, Section::Axis(_)) && c.key == "enabled" && c.regs != [0])
        .cloned()
        .collect();
    let unit: Vec<Change> = changes
        .iter()
        .filter(|c| is(c, Section::Gateway, "unit_id"))
        .cloned()
        .collect();
    let base: Vec<Change> = changes
        .iter()
        .filter(|c| is(c, Section::Gateway, "axis_base"))
        .cloned()
        .collect();
    let rest: Vec<Change> = changes
        .iter()
        .filter(|c| {
            c.key != "enabled"
                && !is(c, Section::Gateway, "unit_id")
                && !is(c, Section::Gateway, "axis_base")
        })
        .cloned()
        .collect();
    let groups: Vec<&Vec<Change>> = [&unit, &base, &enables]
        .into_iter()
        .filter(|g| !g.is_empty())
        .collect();
    let orders: Vec<Vec<usize>> = match groups.len() {
        0 => vec![vec![]],
        1 => vec![vec![0]],
        2 => vec![vec![0, 1], vec![1, 0]],
        _ => vec![
            vec![0, 1, 2],
            vec![0, 2, 1],
            vec![1, 0, 2],
            vec![1, 2, 0],
            vec![2, 0, 1],
            vec![2, 1, 0],
        ],
    };
    let run = |state: &mut Admit, phase: &[Change]| -> Result<(), String> {
        phase.iter().try_for_each(|c| state.write(c))
    };
    let mut first_reason = None;
    // One phase if any order admits it, else two (the split after `k` groups, an APPLY there).
    for two in [false, true] {
        for order in &orders {
            let splits: Vec<usize> = if two {
                (0..groups.len()).collect()
            } else {
                vec![groups.len()]
            };
            for k in splits {
                let mut phase1 = disables.clone();
                let mut phase2 = Vec::new();
                for (i, &g) in order.iter().enumerate() {
                    let target = if i < k { &mut phase1 } else { &mut phase2 };
                    target.extend(
                        groups
                            .get(g)
                            .map_or(&[][..], |g| g.as_slice())
                            .iter()
                            .cloned(),
                    );
                }
                if two && phase1.is_empty() {
                    continue;
                }
                let mut state = Admit::of(now);
                let outcome = run(&mut state, &phase1).and_then(|()| {
                    if two {
                        state.apply();
                    }
                    run(&mut state, &phase2)
                });
                match outcome {
                    Ok(()) => {
                        return Ok(if two {
                            phase2.extend(rest.iter().cloned());
                            vec![phase1, phase2]
                        } else {
                            phase1.extend(phase2);
                            phase1.extend(rest.iter().cloned());
                            vec![phase1]
                        });
                    }
                    Err(e) => {
                        first_reason.get_or_insert(e);
                    }
                }
            }
        }
    }
    Err(format!(
        "the gateway would refuse these settings in every order of writing them (with an APPLY between or not): {}; change UNITID, AXISBASE and the axes enabled in separate steps",
        first_reason.unwrap_or_default()
    ))
}

/// The first enabled axis (bit n of `axes`) that moves or runs a command, or a synchronized
/// start that runs: APPLY is refused then (`bus_idle`), so nothing is written. `None`: idle.
pub fn busy(gw: &mut Gw, axes: &[u8]) -> Result<Option<String>, Fail> {
    if gw.get(G_SYNC_STATUS)? == 1 {
        return Ok(Some("a synchronized start runs (SYNCSTAT 1)".into()));
    }
    for &n in axes {
        let unit = gw.axis_unit(n);
        let Some(ext) = gw.probe(unit, CMST, 1)? else {
            continue;
        };
        if ext.first() == Some(&1) {
            return Ok(Some(format!(
                "axis {n} (unit {unit}) runs a command (CMST 1)"
            )));
        }
        if let Ok(dsse) = gw.try_read(unit, DSSE, 1)? {
            if dsse.first().is_some_and(|d| d & DSSE_MOVE != 0) {
                return Ok(Some(format!("axis {n} (unit {unit}) moves (DSSE MOVE)")));
            }
        }
    }
    Ok(None)
}

/// The changes written, for a message after a failure: those an APPLY already took, those
/// written since, and which of them wait for APPLY.
fn written_text(applied: &[Change], written: &[Change]) -> String {
    let mut out = String::new();
    if !applied.is_empty() {
        out += &format!("applied before the failure ({}):", applied.len());
        for c in applied {
            out += &format!("\n    {}", c.line());
        }
        out += "\n  ";
    }
    if written.is_empty() {
        out += "nothing written since the last APPLY";
        return out;
    }
    out += &format!("written before the failure ({}):", written.len());
    for c in written {
        out += &format!("\n    {}", c.line());
    }
    let pending: Vec<String> = written
        .iter()
        .filter(|c| c.on_apply)
        .map(|c| format!("{} {}", c.section.name(), c.key))
        .collect();
    if !pending.is_empty() {
        out += &format!(
            "\n  pending until APPLY (registers read them, the gateway does not run them yet): {}; `rcgw apply` once nothing moves, or write the file again",
            pending.join(", ")
        );
    }
    out
}

/// Write `phases` ([`plan`]), an APPLY after each phase but the last and after the last if a
/// change of it is taken on APPLY, each waited for. Before the first write, when an APPLY
/// will be needed: the bus idle ([`busy`]), or nothing is written. On a failure after the
/// first write, the error says what was written and what waits for APPLY.
/// Returns whether it applied.
pub fn write_changes(gw: &mut Gw, phases: &[Vec<Change>]) -> Result<bool, Fail> {
    let needs_apply = phases.len() > 1 || phases.iter().flatten().any(|c| c.on_apply);
    if needs_apply {
        let unit = gw.unit;
        let enabled = Settings::read_enabled(gw)?;
        if let Some(why) = busy(gw, &enabled)? {
            return Err(Fail::Device(format!(
                "{} unit {unit}: the settings need an APPLY, which the gateway refuses while anything moves or runs: {why}; nothing written (stop the axes, then try again)",
                gw.link.name
            )));
        }
    }
    let mut written: Vec<Change> = Vec::new();
    let mut done: Vec<Change> = Vec::new();
    let mut applied = false;
    let fail = |e: Fail, done: &[Change], written: &[Change]| match e {
        Fail::Device(m) | Fail::Input(m) => {
            Fail::Device(format!("{m}\n  {}", written_text(done, written)))
        }
    };
    for (i, phase) in phases.iter().enumerate() {
        let unit = gw.unit;
        for c in phase {
            let result = if c.key == "tcp_allow" {
                // Each address in one FC10 of two registers.
                (0..4u16).try_for_each(|i| {
                    let at = usize::from(2 * i);
                    gw.write(
                        unit,
                        c.address + 2 * i,
                        c.regs.get(at..at + 2).unwrap_or(&[0, 0]),
                    )
                })
            } else {
                gw.write(unit, c.address, &c.regs)
            };
            result.map_err(|e| fail(e, &done, &written))?;
            written.push(c.clone());
        }
        let last = i + 1 == phases.len();
        if !last || phase.iter().any(|c| c.on_apply) {
            apply(gw).map_err(|e| fail(e, &done, &written))?;
            // Applied: nothing written so far waits any more.
            done.append(&mut written);
            applied = true;
        }
    }
    Ok(applied)
}

/// APPLY, then the PLC line as it now is (RTU), and the establishment awaited.
pub fn apply(gw: &mut Gw) -> Result<(), Fail> {
    let unit = gw.unit;
    let before = gw.read(unit, G_BUS, G_BUS_LEN)?;
    let establishments = |regs: &[u16]| u32::from(regs[6]) << 16 | u32::from(regs[7]);
    let line = gw.read(unit, G_PLC_BAUD, 3)?;
    let (pending_unit, pending_base) = (line[2], gw.get(G_AXIS_BASE)?);
    let enabled = Settings::read_enabled(gw)?;
    // A refusal while nothing the PLC started moves or runs is the gateway's own work: the
    // establishment after a start (its first stops go before it, and a dead axis' cost
    // time-outs), a stop still on the bus. Asked again until it ends, 15 s at most.
    let patience = Instant::now() + Duration::from_secs(15);
    loop {
        match gw.try_write(unit, G_APPLY, &[1])? {
            Ok(()) => break,
            Err(Exception::IllegalDataValue) => {
                let why = busy(gw, &enabled)?;
                if why.is_some() || Instant::now() >= patience {
                    return Err(Fail::Device(format!(
                        "{}: APPLY refused (exception 03): {}",
                        gw.at(unit, G_APPLY),
                        why.unwrap_or_else(|| {
                            "something moves, runs or waits on the bus, or an establishment runs"
                                .into()
                        })
                    )));
                }
                std::thread::sleep(Duration::from_millis(250));
            }
            Err(e) => {
                return Err(Fail::Device(format!(
                    "{}: {e} writing 1",
                    gw.at(unit, G_APPLY)
                )))
            }
        }
    }
    if gw.link.is_rtu() {
        let parity = match line[1] {
            1 => serialport::Parity::Odd,
            2 => serialport::Parity::Even,
            _ => serialport::Parity::None,
        };
        std::thread::sleep(Duration::from_millis(50));
        gw.link.set_line(u32::from(line[0]) * 100, parity)?;
    }
    gw.unit = pending_unit as u8;
    gw.base = pending_base as u8;
    let unit = gw.unit;
    let limit = Duration::from_millis(3000 + 1500 * enabled.len() as u64);
    let deadline = Instant::now() + limit;
    loop {
        // Every axis stops answering while the establishment runs; the gateway unit answers.
        let done = match gw.try_read(unit, G_BUS, G_BUS_LEN) {
            Ok(Ok(now)) => establishments(&now) != establishments(&before),
            _ => false,
        };
        if done {
            break;
        }
        if Instant::now() > deadline {
            return Err(Fail::Device(format!(
                "{}: APPLY written, but no establishment finished within {} ms",
                gw.at(unit, G_BUS + 6),
                limit.as_millis()
            )));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    // Then each enabled axis settles to online or offline.
    for n in enabled {
        let axis_unit = gw.axis_unit(n);
        while Instant::now() < deadline {
            match gw.try_read(axis_unit, LINK, 1)? {
                Ok(v) if v.first().is_some_and(|&l| l != 0) => break,
                _ => std::thread::sleep(Duration::from_millis(50)),
            }
        }
    }
    Ok(())
}

/// SAVE, waiting for SAVESTAT.
pub fn save(gw: &mut Gw) -> Result<u32, Fail> {
    gw.set(G_SAVE, 1)?;
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        match gw.get(G_SAVE_STATUS)? {
            2 => {
                let unit = gw.unit;
                let count = gw.read(unit, G_SAVE_COUNT, 2)?;
                return Ok(u32::from(count[0]) << 16 | u32::from(count[1]));
            }
            3 => {
                return Err(Fail::Device(format!(
                    "{}: the save failed (SAVESTAT 3)",
                    gw.at(gw.unit, G_SAVE_STATUS)
                )))
            }
            _ if Instant::now() > deadline => {
                return Err(Fail::Device(format!(
                    "{}: the save did not finish within 5 s",
                    gw.at(gw.unit, G_SAVE_STATUS)
                )))
            }
            _ => std::thread::sleep(Duration::from_millis(20)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::modbus::{DataModel, RegisterTable, SlaveCounters};
    use protocol::plc::{Gateway, GatewayConfig};
    use protocol::time::Instant;

    /// A gateway started with these settings running: `unit`, `base`, `axes` on the bus.
    fn gateway(unit: u8, base: u8, axes: AxisSet) -> Gateway {
        let mut config = GatewayConfig::new(axes);
        config.unit = UnitId::new(unit).unwrap();
        config.axis_base = AxisBase::new(base).unwrap();
        Gateway::new(
            config,
            &protocol::plc::IDENTITY,
            protocol::plc::Boot::DEFAULT,
        )
    }

    /// What rcgw starts a plan from: the same settings, read.
    fn settings(unit: u8, base: u8, axes: AxisSet) -> Settings {
        let mut values = BTreeMap::new();
        values.insert((Section::Gateway, "unit_id"), vec![u16::from(unit)]);
        values.insert((Section::Gateway, "axis_base"), vec![u16::from(base)]);
        for n in 0..AXES as u8 {
            let on = axes.0 & 1 << n != 0;
            values.insert((Section::Axis(n), "enabled"), vec![u16::from(on)]);
        }
        Settings { values }
    }

    fn change(section: Section, key: &'static str, address: u16, value: u16) -> Change {
        Change {
            section,
            key,
            address,
            from: None,
            to: value.to_string(),
            regs: vec![value],
            on_apply: true,
        }
    }

    /// Every setting's message says its values: a setting left to the map's spans has them
    /// (one whose row lost them would say only the words after them), e.g. the line rate's in
    /// bit/s.
    #[test]
    fn every_range_is_said() {
        for section in [Section::Gateway, Section::Network, Section::Axis(0)] {
            for &field in section.fields() {
                let text = range_text(section, field);
                assert!(
                    !text.is_empty() && !text.starts_with(','),
                    "{} {}: {text:?}",
                    section.name(),
                    field.key
                );
            }
        }
        let baud = field(Section::Gateway, "bus_baud_bps").unwrap();
        assert_eq!(
            range_text(Section::Gateway, baud),
            "9600, 14400, 19200, 28800, 38400, 57600, 76800, 115200 bit/s"
        );
    }

    /// rcgw plans its writes with the rules the gateway applies to them: random sequences of
    /// UNITID, AXISBASE and axes enabled or disabled (small units and bases, so that they
    /// collide often), with APPLYs between, are written to a gateway and fed to rcgw's model
    /// of it, and each write must be admitted by both or refused by both. (The gateway's APPLY
    /// is a start with the pending settings: the rules APPLY itself has, an idle bus, are not
    /// these.) Fails if rcgw's model of what is pending and what is on the bus, or its rules,
    /// drift from the gateway's.
    #[test]
    fn rcgw_and_the_gateway_admit_the_same_writes() {
        let mut seed = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = |n: u64| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed % n
        };
        let (mut admitted, mut refused) = (0, 0);
        for _ in 0..400 {
            let (mut unit, mut base) = (63u8, 1u8);
            let mut axes = AxisSet(next(1 << 16) as u16 & 0x00FF);
            let mut gw = gateway(unit, base, axes);
            let mut model = Admit::of(&settings(unit, base, axes));
            for _ in 0..12 {
                let c = match next(4) {
                    0 => {
                        // APPLY: the pending settings run, in the gateway as in rcgw.
                        let mut regs = gw.registers(Instant::ZERO, SlaveCounters::default());
                        let mut pending = |a: u16| {
                            let mut out = [0];
                            regs.read_registers(unit, RegisterTable::Holding, a, &mut out)
                                .expect("read");
                            out[0]
                        };
                        let (u, b) = (pending(G_UNIT_ID) as u8, pending(G_AXIS_BASE) as u8);
                        let on = (0..AXES as u16).fold(0, |m, n| {
                            m | pending(G_AXIS_CONFIG + G_AXIS_CONFIG_LEN * n) << n
                        });
                        (unit, base, axes) = (u, b, AxisSet(on));
                        gw = gateway(unit, base, axes);
                        model.apply();
                        continue;
                    }
                    1 => {
                        let u = [1 + next(24), 63][next(2) as usize] as u16;
                        change(Section::Gateway, "unit_id", G_UNIT_ID, u)
                    }
                    2 => change(
                        Section::Gateway,
                        "axis_base",
                        G_AXIS_BASE,
                        1 + next(24) as u16,
                    ),
                    _ => {
                        let n = next(16) as u8;
                        let address = G_AXIS_CONFIG + G_AXIS_CONFIG_LEN * u16::from(n);
                        change(Section::Axis(n), "enabled", address, next(2) as u16)
                    }
                };
                let gateway = gw
                    .registers(Instant::ZERO, SlaveCounters::default())
                    .write_registers(unit, c.address, &c.regs);
                let rcgw = model.write(&c);
                assert_eq!(
                    rcgw.is_ok(),
                    gateway.is_ok(),
                    "{}: rcgw {rcgw:?}, the gateway {gateway:?} (running: unit {unit}, \
                     AXISBASE {base}, axes {:#06x})",
                    c.line(),
                    axes.0
                );
                if gateway.is_ok() {
                    admitted += 1;
                } else {
                    refused += 1;
                }
            }
        }
        // Both outcomes exercised.
        assert!(admitted > 100 && refused > 100, "{admitted} {refused}");
    }
}
