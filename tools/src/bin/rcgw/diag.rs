//! `rcgw diag`: the counters, per axis, of the bus, of the PLC line, FC08's and TCP's; the
//! reset cause and where the settings came from.

use protocol::modbus::Diagnostic;
use protocol::plc::map::*;
use serde_json::{json, Value};

use crate::link::{Fail, Gw};
use crate::print_json;
use crate::settings::Settings;
use crate::status::link_name;

fn long(r: &[u16], i: usize) -> u32 {
    u32::from(r.get(2 * i).copied().unwrap_or(0)) << 16
        | u32::from(r.get(2 * i + 1).copied().unwrap_or(0))
}

/// `rcgw diag`.
pub fn diag(gw: &mut Gw, json: bool) -> Result<(), Fail> {
    let unit = gw.unit;
    let g = gw.read(unit, 0, G_AXIS_BASE + 1)?;
    let settings = Settings::read(gw)?;
    let mut axes = Vec::new();
    for n in settings.enabled() {
        let d = gw.read(unit, G_DIAG + G_DIAG_LEN * u16::from(n), G_DIAG_LEN)?;
        let last = d[15];
        axes.push(json!({
            "axis": n,
            "frames": long(&d, 0), "replies": long(&d, 1), "timeouts": long(&d, 2),
            "bcc_errors": long(&d, 3), "bad_replies": long(&d, 4), "retries": long(&d, 5),
            "rejections": long(&d, 6),
            "link": link_name(d[14]),
            "last_error": match last >> 8 { 0 => "none".to_string(), 1 => "time-out".into(), 3 => format!("rejected, code {:02X}", last & 0xFF), _ => format!("{last:#06x}") },
        }));
    }
    let bus = gw.read(unit, G_BUS, G_BUS_LEN)?;
    let plc = gw.read(unit, G_PLC, G_PLC_LEN)?;
    let fc08 = if gw.link.is_rtu() {
        let mut c = serde_json::Map::new();
        for (name, sub) in [
            ("diagnostic_register", Diagnostic::DiagnosticRegister),
            ("bus_messages", Diagnostic::BusMessageCount),
            ("bus_crc_errors", Diagnostic::BusCommunicationErrorCount),
            ("bus_exceptions", Diagnostic::BusExceptionErrorCount),
            ("server_messages", Diagnostic::ServerMessageCount),
            ("server_no_response", Diagnostic::ServerNoResponseCount),
            ("character_overruns", Diagnostic::BusCharacterOverrunCount),
        ] {
            c.insert(name.into(), json!(gw.diagnostic(sub)?));
        }
        Value::Object(c)
    } else {
        Value::Null
    };
    let tcp = match gw.try_read(unit, G_TCP, G_TCP_LEN)? {
        Ok(t) => json!({"accepted": long(&t, 0), "refused": long(&t, 1), "replaced": long(&t, 2),
                        "closed_idle": long(&t, 3), "mbap_errors": long(&t, 4), "frames": long(&t, 5)}),
        Err(_) => Value::Null,
    };
    let reset = [
        "power-on",
        "hardware watchdog",
        "software",
        "reset pin",
        "other",
    ];
    let source = [
        "defaults (nothing stored)",
        "flash",
        "defaults (stored settings unreadable)",
    ];
    let save_status = ["none", "saving", "saved", "failed"];
    let out = json!({
        "reset_cause": reset.get(usize::from(g[usize::from(G_RESET_CAUSE)])).copied().unwrap_or("?"),
        "config_source": source.get(usize::from(g[usize::from(G_CONFIG_SOURCE)])).copied().unwrap_or("?"),
        "config_errors": g[usize::from(G_CONFIG_ERRORS)],
        "save_status": save_status.get(usize::from(g[usize::from(G_SAVE_STATUS)])).copied().unwrap_or("?"),
        "save_count": u32::from(g[usize::from(G_SAVE_COUNT)]) << 16 | u32::from(g[usize::from(G_SAVE_COUNT) + 1]),
        "uptime_s": long(&g, 1),
        "failsafe_trips": g[usize::from(G_FAILSAFE_COUNT)],
        "axes": axes,
        "bus": {"unsolicited": long(&bus, 0), "events_lost": long(&bus, 1), "queue_full": long(&bus, 2), "establishments": long(&bus, 3), "stops_owed": long(&bus, 4), "broadcast_refusals": long(&bus, 5)},
        "plc_line": {"frames": long(&plc, 0), "crc_errors": long(&plc, 1), "exceptions": long(&plc, 2), "replies": long(&plc, 3),
                     "other_units": long(&plc, 4), "broadcasts": long(&plc, 5), "malformed": long(&plc, 6)},
        "fc08": fc08,
        "tcp": tcp,
    });
    if json {
        print_json(&out);
        return Ok(());
    }
    outln!(
        "gateway unit {unit} on {}: reset cause {}, settings from {} (unreadable at a start: {}), last save {}, saves {}, up {} s, FAILSAFE trips {}",
        gw.link.name,
        out["reset_cause"].as_str().unwrap_or(""),
        out["config_source"].as_str().unwrap_or(""),
        out["config_errors"],
        out["save_status"].as_str().unwrap_or(""),
        out["save_count"],
        out["uptime_s"],
        out["failsafe_trips"]
    );
    outln!(
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
    );
    for a in out["axes"].as_array().into_iter().flatten() {
        outln!(
            "{:<4} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:<8} {}",
            a["axis"].to_string(),
            a["frames"].to_string(),
            a["replies"].to_string(),
            a["timeouts"].to_string(),
            a["bcc_errors"].to_string(),
            a["bad_replies"].to_string(),
            a["retries"].to_string(),
            a["rejections"].to_string(),
            a["link"].as_str().unwrap_or(""),
            a["last_error"].as_str().unwrap_or("")
        );
    }
    let line = |name: &str, v: &Value| {
        let parts: Vec<String> = v
            .as_object()
            .into_iter()
            .flatten()
            .map(|(k, v)| format!("{} {v}", k.replace('_', " ")))
            .collect();
        outln!("{name}: {}", parts.join(", "));
    };
    line("bus", &out["bus"]);
    line("PLC line", &out["plc_line"]);
    if out["fc08"].is_null() {
        outln!("FC08: serial line only (not on TCP)");
    } else {
        line("FC08", &out["fc08"]);
    }
    if !out["tcp"].is_null() {
        line("TCP", &out["tcp"]);
    }
    Ok(())
}
