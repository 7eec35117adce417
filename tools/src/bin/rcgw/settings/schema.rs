//! Every setting: its TOML key, its registers and how they read as a value, the values it
//! takes (from the register map's rows where they have them) and whether it waits for APPLY.

use protocol::plc::map::*;

use super::file::hundredths;

/// How a setting's registers read as a TOML value.
#[derive(Clone, Copy, Debug)]
pub(super) enum Kind {
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
    pub(super) fn width(self) -> u16 {
        match self {
            Kind::Hundredths32 | Kind::Ipv4 => 2,
            Kind::Ipv4List => 8,
            _ => 1,
        }
    }
}

/// One setting: its key, its first register (offset in the axis block for axis settings).
#[derive(Clone, Copy, Debug)]
pub(super) struct Field {
    pub(super) key: &'static str,
    pub(super) address: u16,
    pub(super) kind: Kind,
    /// The values the gateway takes, in the file's units, for messages: for a setting whose
    /// map row has its allowed values, what follows them ([`range_text`]).
    pub(super) range: &'static str,
}

/// The values a setting takes, in the file's units, for messages: a gateway or network
/// setting's from its map row (its spans, times the file's factor, with the unit its key
/// names), then the field's own words.
pub(super) fn range_text(section: Section, field: Field) -> String {
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
pub(super) fn on_apply(section: Section, field: Field) -> bool {
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

pub(super) const GATEWAY: &[Field] = &[
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

pub(super) const AXIS: &[Field] = &[
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

pub(super) const NETWORK: &[Field] = &[
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
    pub(super) fn name(self) -> String {
        match self {
            Section::Gateway => "[gateway]".into(),
            Section::Network => "[network]".into(),
            Section::Axis(n) => format!("[axis.{n}]"),
        }
    }

    pub(super) fn fields(self) -> &'static [Field] {
        match self {
            Section::Gateway => GATEWAY,
            Section::Network => NETWORK,
            Section::Axis(_) => AXIS,
        }
    }

    pub(super) fn base(self) -> u16 {
        match self {
            Section::Axis(n) => G_AXIS_CONFIG + G_AXIS_CONFIG_LEN * u16::from(n),
            _ => 0,
        }
    }
}

pub(super) fn field(section: Section, key: &str) -> Option<Field> {
    section.fields().iter().copied().find(|f| f.key == key)
}

/// A section's name as the file writes it (`[gateway]`).
pub fn section_name(section: Section) -> String {
    section.name()
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
