//! The gateway's settings as registers of the gateway unit, and as TOML with the units in the
//! key names: read, shown, checked (every value, before anything is written), compared and
//! written.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::{Duration, Instant};

use protocol::axes::AXES;
use protocol::modbus::Exception;
use protocol::plc::map::*;
use protocol::plc::write::GatewayWrite;

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
    /// Taken on APPLY (not at once).
    on_apply: bool,
}

const fn f(key: &'static str, address: u16, kind: Kind, on_apply: bool) -> Field {
    Field {
        key,
        address,
        kind,
        on_apply,
    }
}

const PARITY: &[(&str, u16)] = &[("none", 0), ("odd", 1), ("even", 2)];
const WD_ACTION: &[(&str, u16)] = &[("stop", 0), ("latch", 1)];
const PIO_START: &[(&str, u16)] = &[("level", 0), ("edge", 1)];
const HOME: &[(&str, u16)] = &[("motor", 7), ("far", 8)];
const ENCODING: &[(&str, u16)] = &[("ones-complement", 1), ("twos-complement", 2)];

const GATEWAY: &[Field] = &[
    f("unit_id", G_UNIT_ID, Kind::Int(1), true),
    f("axis_base", G_AXIS_BASE, Kind::Int(1), true),
    f("plc_baud_bps", G_PLC_BAUD, Kind::Int(100), true),
    f("plc_parity", G_PLC_PARITY, Kind::Enum(PARITY), true),
    f("bus_baud_bps", G_BUS_BAUD, Kind::Int(100), true),
    f("bus_rtim_ms", G_BUS_RTIM, Kind::Int(1), true),
    f("retries", G_RETRIES, Kind::Int(1), false),
    f("watchdog_ms", G_WATCHDOG, Kind::Int(1), false),
    f("watchdog_action", G_WD_ACTION, Kind::Enum(WD_ACTION), false),
    f("pio_axis", G_PIO_AXIS, Kind::PioAxis, false),
    f("pio_pattern", G_PIO_PATTERN, Kind::Int(1), false),
    f("pio_start", G_PIO_START, Kind::Enum(PIO_START), false),
    f("pio_jog_mm_s", G_PIO_JOG, Kind::Hundredths, false),
    f("pio_inch_mm", G_PIO_INCH, Kind::Hundredths, false),
];

const AXIS: &[Field] = &[
    f("enabled", 0, Kind::Bool, true),
    f("lead_mm", 1, Kind::Hundredths, false),
    f("home", 2, Kind::Enum(HOME), false),
    f("pulses_per_rev", 3, Kind::Int(1), false),
    f("stroke_mm", 4, Kind::Hundredths32, false),
    f("encoding", 6, Kind::Enum(ENCODING), false),
];

const NETWORK: &[Field] = &[
    f("ip_address", G_NET, Kind::Ipv4, false),
    f("ip_prefix_bits", G_NET + 2, Kind::Int(1), false),
    f("ip_router", G_NET + 3, Kind::Ipv4, false),
    f("tcp_max_connections", G_NET + 5, Kind::Int(1), false),
    f("tcp_idle_s", G_NET + 6, Kind::Int(1), false),
    f("tcp_allow", G_NET + 8, Kind::Ipv4List, false),
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

/// A TOML value as the setting's registers, checked for its form (not yet its range).
fn parse(kind: Kind, value: &toml::Value) -> Result<Vec<u16>, String> {
    let int = || {
        value
            .as_integer()
            .ok_or_else(|| format!("{value} is not a whole number"))
    };
    let word =
        |v: i64, what: &str| u16::try_from(v).map_err(|_| format!("{v} is out of range ({what})"));
    Ok(match kind {
        Kind::Int(factor) => {
            let v = int()?;
            if v % i64::from(factor) != 0 {
                return Err(format!("{v} is not a multiple of {factor}"));
            }
            vec![word(v / i64::from(factor), "0-65535")?]
        }
        Kind::Hundredths => vec![word(parse_hundredths(value)?, "0.00-655.35")?],
        Kind::Hundredths32 => {
            let v = parse_hundredths(value)?;
            let v = u32::try_from(v)
                .ok()
                .filter(|&v| i32::try_from(v).is_ok())
                .ok_or_else(|| format!("{value} is out of range (0.00-21474836.47)"))?;
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
            None => vec![word(int()?, "an axis 0-15 or \"none\"")?],
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

/// The range a setting's register takes, for messages.
fn range_text(section: Section, address: u16) -> String {
    if let Section::Axis(_) = section {
        return String::new();
    }
    MAP.iter()
        .find(|e| {
            e.unit == Unit::Gateway
                && address
                    .checked_sub(e.address)
                    .is_some_and(|offset| offset < e.count)
        })
        .map(|e| format!(" (allowed: {} {})", e.range, e.units).replace(" )", ")"))
        .unwrap_or_default()
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
    /// `others` are the other top-level keys the caller reads itself.
    pub fn from_toml(doc: &toml::Table, others: &[&str]) -> Result<Settings, Vec<String>> {
        let mut errors = Vec::new();
        let mut values = BTreeMap::new();
        let mut sections: Vec<(Section, &toml::Table)> = Vec::new();
        for (key, value) in doc {
            match (key.as_str(), value) {
                ("gateway", toml::Value::Table(t)) => sections.push((Section::Gateway, t)),
                ("network", toml::Value::Table(t)) => sections.push((Section::Network, t)),
                ("axis", toml::Value::Table(axes)) => {
                    for (n, table) in axes {
                        match (
                            n.parse::<u8>().ok().filter(|&n| usize::from(n) < AXES),
                            table,
                        ) {
                            (Some(n), toml::Value::Table(t)) => {
                                sections.push((Section::Axis(n), t))
                            }
                            (None, _) => {
                                errors.push(format!("[axis.{n}]: no such axis (0-{})", AXES - 1))
                            }
                            (_, _) => errors.push(format!("axis.{n}: not a table")),
                        }
                    }
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
                if key == "point"
                    && matches!(section, Section::Axis(_))
                    && others.contains(&"point")
                {
                    continue;
                }
                let Some(field) = field(section, key) else {
                    let keys: Vec<&str> = section.fields().iter().map(|f| f.key).collect();
                    errors.push(format!(
                        "{} {key}: unknown key (one of {})",
                        section.name(),
                        keys.join(", ")
                    ));
                    continue;
                };
                match parse(field.kind, value) {
                    Err(e) => errors.push(format!("{} {key} = {value}: {e}", section.name())),
                    Ok(regs) => {
                        let first = section.base() + field.address;
                        for (i, &v) in regs.iter().enumerate() {
                            let address = first + i as u16;
                            if let Err(e) = GatewayWrite::parse(address, v) {
                                let _ = e;
                                errors.push(format!(
                                    "{} {key} = {value}: out of range{} (register {address:#06x})",
                                    section.name(),
                                    range_text(section, address)
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
        if let Some(axis) = self
            .word(Section::Gateway, "pio_axis")
            .filter(|&a| a != 0xFFFF)
        {
            let _ = axis;
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
                    on_apply: field.on_apply,
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
            if self.on_apply { " (on APPLY)" } else { "" }
        )
    }

    pub fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "section": self.section.name(),
            "key": self.key,
            "register": format!("{:#06x}", self.address),
            "from": self.from,
            "to": self.to,
            "on_apply": self.on_apply,
        })
    }
}

/// Write `changes` in an order the gateway admits (axes disabled first, then AXISBASE and
/// UNITID, then the rest), APPLY if one of them needs it and wait for the establishment.
/// Returns whether it applied.
pub fn write_changes(gw: &mut Gw, changes: &[Change]) -> Result<bool, Fail> {
    let rank = |c: &Change| match (c.section, c.key) {
        (Section::Axis(_), "enabled") if c.regs == [0] => 0,
        (Section::Gateway, "axis_base") => 1,
        (Section::Gateway, "unit_id") => 2,
        (Section::Axis(_), "enabled") => 4,
        _ => 3,
    };
    let mut ordered: Vec<&Change> = changes.iter().collect();
    ordered.sort_by_key(|c| rank(c));
    let unit = gw.unit;
    for c in &ordered {
        if c.key == "tcp_allow" {
            // Each address in one FC10 of two registers.
            for i in 0..4u16 {
                let at = usize::from(2 * i);
                gw.write(
                    unit,
                    c.address + 2 * i,
                    c.regs.get(at..at + 2).unwrap_or(&[0, 0]),
                )?;
            }
        } else {
            gw.write(unit, c.address, &c.regs)?;
        }
    }
    if !changes.iter().any(|c| c.on_apply) {
        return Ok(false);
    }
    apply(gw)?;
    for c in changes {
        match (c.section, c.key) {
            (Section::Gateway, "unit_id") => gw.unit = c.regs[0] as u8,
            (Section::Gateway, "axis_base") => gw.base = c.regs[0] as u8,
            _ => {}
        }
    }
    Ok(true)
}

/// APPLY, then the PLC line as it now is (RTU), and the establishment awaited.
pub fn apply(gw: &mut Gw) -> Result<(), Fail> {
    let unit = gw.unit;
    let before = gw.read(unit, G_BUS, G_BUS_LEN)?;
    let establishments = |regs: &[u16]| u32::from(regs[6]) << 16 | u32::from(regs[7]);
    let line = gw.read(unit, G_PLC_BAUD, 3)?;
    let (pending_unit, pending_base) = (line[2], gw.get(G_AXIS_BASE)?);
    let enabled: Vec<u8> = {
        let mut all = gw.read(unit, G_AXIS_CONFIG, 64)?;
        all.extend(gw.read(unit, G_AXIS_CONFIG + 64, 64)?);
        (0..AXES as u8)
            .filter(|&n| all.get(usize::from(n) * 8) == Some(&1))
            .collect()
    };
    gw.write(unit, G_APPLY, &[1])?;
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
