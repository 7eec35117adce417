//! `rcgw diag`: the counters, per axis, of the bus, of the PLC line, FC08's and TCP's; the
//! reset cause and where the settings came from.

use std::fmt;

use protocol::modbus::Diagnostic;
use protocol::plc::map::*;
use serde::ser::SerializeMap;
use serde::{Serialize, Serializer};

use crate::link::{Fail, Gw};
use crate::print_json;
use crate::settings::Settings;
use crate::status::link_name;

/// A block of counters, each named once: a JSON object (`{"frames": 12, ...}`) and a text
/// line (`frames 12, ...`, `_` read as a space).
#[derive(Debug)]
pub struct Counters(pub Vec<(&'static str, u32)>);

impl Serialize for Counters {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(Some(self.0.len()))?;
        for (name, value) in &self.0 {
            map.serialize_entry(name, value)?;
        }
        map.end()
    }
}

impl fmt::Display for Counters {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, (name, value)) in self.0.iter().enumerate() {
            let comma = if i == 0 { "" } else { ", " };
            write!(f, "{comma}{} {value}", name.replace('_', " "))?;
        }
        Ok(())
    }
}

/// An axis' counters (`axes[]` in the JSON).
#[derive(Serialize, Debug)]
pub struct AxisDiag {
    pub axis: u8,
    pub frames: u32,
    pub replies: u32,
    pub timeouts: u32,
    pub bcc_errors: u32,
    pub bad_replies: u32,
    pub retries: u32,
    pub rejections: u32,
    pub link: &'static str,
    pub last_error: String,
}

/// `rcgw diag`'s report: the JSON as serialised, the text by [`fmt::Display`].
#[derive(Serialize, Debug)]
pub struct Diag {
    /// The gateway unit and the line, for the text's first line.
    #[serde(skip)]
    pub unit: u8,
    #[serde(skip)]
    pub port: String,
    pub reset_cause: &'static str,
    pub config_source: &'static str,
    pub config_errors: u16,
    pub save_status: &'static str,
    pub save_count: u32,
    pub uptime_s: u32,
    pub failsafe_trips: u16,
    pub axes: Vec<AxisDiag>,
    pub bus: Counters,
    pub plc_line: Counters,
    /// FC08's counters: serial line only, `null` on TCP.
    pub fc08: Option<Counters>,
    /// Modbus TCP's: `null` on a build without it.
    pub tcp: Option<Counters>,
}

fn long(r: &[u16], i: usize) -> u32 {
    u32::from(r.get(2 * i).copied().unwrap_or(0)) << 16
        | u32::from(r.get(2 * i + 1).copied().unwrap_or(0))
}

/// `names[i]`, `?` past the end.
fn name_of(names: &[&'static str], i: u16) -> &'static str {
    names.get(usize::from(i)).copied().unwrap_or("?")
}

fn read(gw: &mut Gw) -> Result<Diag, Fail> {
    let unit = gw.unit;
    let g = gw.read(unit, 0, G_AXIS_BASE + 1)?;
    let settings = Settings::read(gw)?;
    let mut axes = Vec::new();
    for n in settings.enabled() {
        let d = gw.read(unit, G_DIAG + G_DIAG_LEN * u16::from(n), G_DIAG_LEN)?;
        let last = d[15];
        axes.push(AxisDiag {
            axis: n,
            frames: long(&d, 0),
            replies: long(&d, 1),
            timeouts: long(&d, 2),
            bcc_errors: long(&d, 3),
            bad_replies: long(&d, 4),
            retries: long(&d, 5),
            rejections: long(&d, 6),
            link: link_name(d[14]),
            last_error: match last >> 8 {
                0 => "none".to_string(),
                1 => "time-out".into(),
                3 => format!("rejected, code {:02X}", last & 0xFF),
                _ => format!("{last:#06x}"),
            },
        });
    }
    let bus = gw.read(unit, G_BUS, G_BUS_LEN)?;
    let plc = gw.read(unit, G_PLC, G_PLC_LEN)?;
    let fc08 = if gw.link.is_rtu() {
        let mut c = Vec::new();
        for (name, sub) in [
            ("diagnostic_register", Diagnostic::DiagnosticRegister),
            ("bus_messages", Diagnostic::BusMessageCount),
            ("bus_crc_errors", Diagnostic::BusCommunicationErrorCount),
            ("bus_exceptions", Diagnostic::BusExceptionErrorCount),
            ("server_messages", Diagnostic::ServerMessageCount),
            ("server_no_response", Diagnostic::ServerNoResponseCount),
            ("character_overruns", Diagnostic::BusCharacterOverrunCount),
        ] {
            c.push((name, u32::from(gw.diagnostic(sub)?)));
        }
        Some(Counters(c))
    } else {
        None
    };
    // The names of a block of 32-bit counters, in register order.
    let block = |regs: &[u16], names: &[&'static str]| {
        Counters(
            names
                .iter()
                .enumerate()
                .map(|(i, &name)| (name, long(regs, i)))
                .collect(),
        )
    };
    let tcp = gw.try_read(unit, G_TCP, G_TCP_LEN)?.ok().map(|t| {
        block(
            &t,
            &[
                "accepted",
                "refused",
                "replaced",
                "closed_idle",
                "mbap_errors",
                "frames",
            ],
        )
    });
    let at = |address: u16| g[usize::from(address)];
    Ok(Diag {
        unit,
        port: gw.link.name.clone(),
        reset_cause: name_of(
            &[
                "power-on",
                "hardware watchdog",
                "software",
                "reset pin",
                "other",
            ],
            at(G_RESET_CAUSE),
        ),
        config_source: name_of(
            &[
                "defaults (nothing stored)",
                "flash",
                "defaults (stored settings unreadable)",
            ],
            at(G_CONFIG_SOURCE),
        ),
        config_errors: at(G_CONFIG_ERRORS),
        save_status: name_of(&["none", "saving", "saved", "failed"], at(G_SAVE_STATUS)),
        save_count: u32::from(at(G_SAVE_COUNT)) << 16 | u32::from(at(G_SAVE_COUNT + 1)),
        uptime_s: long(&g, 1),
        failsafe_trips: at(G_FAILSAFE_COUNT),
        axes,
        bus: block(
            &bus,
            &[
                "unsolicited",
                "events_lost",
                "queue_full",
                "establishments",
                "stops_owed",
                "broadcast_refusals",
            ],
        ),
        plc_line: block(
            &plc,
            &[
                "frames",
                "crc_errors",
                "exceptions",
                "replies",
                "other_units",
                "broadcasts",
                "malformed",
            ],
        ),
        fc08,
        tcp,
    })
}

impl fmt::Display for Diag {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "gateway unit {} on {}: reset cause {}, settings from {} (unreadable at a start: {}), last save {}, saves {}, up {} s, FAILSAFE trips {}",
            self.unit,
            self.port,
            self.reset_cause,
            self.config_source,
            self.config_errors,
            self.save_status,
            self.save_count,
            self.uptime_s,
            self.failsafe_trips
        )?;
        writeln!(
            f,
            "{:<4} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:<8} last error",
            "axis",
            "frames",
            "replies",
            "time-outs",
            "BCC err",
            "bad repl",
            "retries",
            "rejected",
            "link"
        )?;
        for a in &self.axes {
            writeln!(
                f,
                "{:<4} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:<8} {}",
                a.axis,
                a.frames,
                a.replies,
                a.timeouts,
                a.bcc_errors,
                a.bad_replies,
                a.retries,
                a.rejections,
                a.link,
                a.last_error
            )?;
        }
        writeln!(f, "bus: {}", self.bus)?;
        writeln!(f, "PLC line: {}", self.plc_line)?;
        match &self.fc08 {
            Some(fc08) => writeln!(f, "FC08: {fc08}")?,
            None => writeln!(f, "FC08: serial line only (not on TCP)")?,
        }
        if let Some(tcp) = &self.tcp {
            writeln!(f, "TCP: {tcp}")?;
        }
        Ok(())
    }
}

/// `rcgw diag`.
pub fn diag(gw: &mut Gw, json: bool) -> Result<(), Fail> {
    let report = read(gw)?;
    if json {
        print_json(&report);
    } else {
        out!("{report}");
    }
    Ok(())
}
