//! `rcgw status`: every enabled axis as the PLC sees it, FAILSAFE, the LEDs and the settings
//! that wait for APPLY.

use std::io::IsTerminal;
use std::time::Duration;

use protocol::modbus::Exception;
use protocol::plc::map::*;
use protocol::plc::Reason;
use protocol::AlarmCode;
use serde_json::{json, Value};

use crate::link::{Fail, Gw};
use crate::print_json;
use crate::settings::Settings;

/// A LINK register's value in words.
pub fn link_name(link: u16) -> &'static str {
    ["unknown", "online", "offline", "offline, owed a stop"]
        .get(usize::from(link))
        .copied()
        .unwrap_or("?")
}

fn command_text(cmst: u16, cmer: u16, cmct: u16) -> String {
    match cmst {
        0 => "none".into(),
        1 => format!("#{cmct} running"),
        2 => format!("#{cmct} done"),
        3 => {
            let text = Reason::from_code((cmer >> 8) as u8).map_or("unknown reason", Reason::text);
            let code = cmer & 0xFF;
            if code != 0 {
                format!(
                    "#{cmct} failed: {text} (code {code:02X}: {})",
                    AlarmCode(code as u8).text()
                )
            } else {
                format!("#{cmct} failed: {text}")
            }
        }
        other => format!("CMST {other}"),
    }
}

fn axis_status(gw: &mut Gw, axis: u8) -> Result<Value, Fail> {
    let unit = gw.axis_unit(axis);
    let Some(ext) = gw.probe(unit, CMST, 4)? else {
        // Enabled (AXISCFG) but its unit not served: enabled, or AXISBASE changed, pending
        // until APPLY.
        return Ok(json!({
            "axis": axis,
            "unit": unit,
            "link": "not served",
            "last_command": "-",
            "served": false,
        }));
    };
    let (cmst, cmer, link, cmct) = (ext[0], ext[1], ext[2], ext[3]);
    let mut v = json!({
        "axis": axis,
        "unit": unit,
        "link": link_name(link),
        "last_command": command_text(cmst, cmer, cmct),
        "cmst": cmst, "cmer": cmer, "cmct": cmct,
    });
    match gw.try_read(unit, PNOW, 8)? {
        Ok(r) => {
            let pnow = (u32::from(r[0]) << 16 | u32::from(r[1])) as i32;
            let (almc, dss1, dsse) = (r[2], r[5], r[7]);
            v["servo"] = json!(dss1 & DSS1_SV != 0);
            v["homed"] = json!(dss1 & DSS1_HEND != 0);
            v["in_position"] = json!(dss1 & DSS1_PEND != 0);
            v["moving"] = json!(dsse & DSSE_MOVE != 0);
            v["position_mm"] = json!(f64::from(pnow) / 100.0);
            v["alarm"] = if almc != 0 {
                json!({"code": format!("{almc:02X}"), "text": AlarmCode(almc as u8).text()})
            } else {
                Value::Null
            };
        }
        Err(Exception::ServerDeviceFailure) => {}
        Err(e) => return Err(Fail::Device(format!("{}: {e}", gw.at(unit, PNOW)))),
    }
    Ok(v)
}

fn status_once(gw: &mut Gw) -> Result<Value, Fail> {
    let unit = gw.unit;
    let g = gw.read(unit, 0, 6)?;
    let enabled = Settings::read_enabled(gw)?;
    let mut axes = Vec::new();
    for n in enabled {
        axes.push(axis_status(gw, n)?);
    }
    let pending = pending_settings(gw, &axes)?;
    let failsafe = g[4];
    let all_online = axes.iter().all(|a| a["link"] == "online");
    let alarm = axes.iter().any(|a| !a["alarm"].is_null());
    let alarm_led = failsafe != 0 || !all_online || alarm;
    let mut causes = Vec::new();
    if failsafe & 1 != 0 {
        causes.push("PLC watchdog");
    }
    if failsafe & 2 != 0 {
        causes.push("stop input");
    }
    Ok(json!({
        "port": gw.link.name,
        "unit": unit,
        "version": format!("{}.{}.{}", g[0] >> 8, g[0] & 0xFF, g[1]),
        "uptime_s": u32::from(g[2]) << 16 | u32::from(g[3]),
        "failsafe": {"latched": failsafe != 0, "causes": causes, "trips": g[5]},
        "leds": {
            "run": "blinking: the gateway task runs (it answers)",
            "bus_link": if all_online { "on: every enabled axis answers" } else { "off: an enabled axis does not answer" },
            "alarm": if alarm_led { "on: FAILSAFE latched, an axis offline or in alarm" } else { "off" },
        },
        "axes": axes,
        "pending": pending,
    }))
}

/// Signs that settings wait for APPLY (registers read the pending values): UNITID not the unit
/// that answers, an enabled axis whose unit is not served.
fn pending_settings(gw: &mut Gw, axes: &[Value]) -> Result<Vec<String>, Fail> {
    let mut pending = Vec::new();
    let unit_id = gw.get(G_UNIT_ID)?;
    if gw.unit != 255 && u16::from(gw.unit) != unit_id {
        pending.push(format!(
            "UNITID reads {unit_id}, the gateway answers as unit {}",
            gw.unit
        ));
    }
    let unserved: Vec<String> = axes
        .iter()
        .filter(|a| a["served"] == false)
        .map(|a| format!("axis {} (unit {})", a["axis"], a["unit"]))
        .collect();
    if !unserved.is_empty() {
        pending.push(format!(
            "enabled but not served: {} (enabled or AXISBASE {} written, not applied)",
            unserved.join(", "),
            gw.base
        ));
    }
    Ok(pending)
}

/// The note on pending settings, for text output.
fn pending_text(pending: &[String]) -> String {
    if pending.is_empty() {
        return String::new();
    }
    format!(
        "SETTINGS PENDING: {}; `rcgw apply` makes them take effect (or SAVE and RESTART)\n",
        pending.join("; ")
    )
}

fn status_text(s: &Value) -> String {
    let mut out = format!(
        "gateway unit {} on {}: firmware {}, up {} s\n",
        s["unit"],
        s["port"].as_str().unwrap_or(""),
        s["version"].as_str().unwrap_or(""),
        s["uptime_s"]
    );
    let fs = &s["failsafe"];
    if fs["latched"] == true {
        let causes: Vec<&str> = fs["causes"]
            .as_array()
            .map(|a| a.iter().filter_map(|c| c.as_str()).collect())
            .unwrap_or_default();
        out += &format!(
            "FAILSAFE: LATCHED ({}); no motion until acknowledged (rcgw ack); trips {}\n",
            causes.join(", "),
            fs["trips"]
        );
    } else {
        out += &format!("FAILSAFE: clear (trips {})\n", fs["trips"]);
    }
    out += &pending_text(
        &s["pending"]
            .as_array()
            .map(|p| {
                p.iter()
                    .filter_map(|x| x.as_str().map(String::from))
                    .collect::<Vec<_>>()
            })
            .unwrap_or_default(),
    );
    for led in ["run", "bus_link", "alarm"] {
        out += &format!(
            "LED {:<9} {}\n",
            led.replace('_', " "),
            s["leds"][led].as_str().unwrap_or("")
        );
    }
    out += &format!(
        "{:<4} {:<4} {:<8} {:<5} {:<5} {:<6} {:>9}  {:<28} {}\n",
        "axis", "unit", "link", "servo", "homed", "moving", "pos mm", "alarm", "last command"
    );
    let yes = |v: &Value| match v.as_bool() {
        Some(true) => "yes",
        Some(false) => "no",
        None => "-",
    };
    for a in s["axes"].as_array().into_iter().flatten() {
        let pos = a["position_mm"]
            .as_f64()
            .map_or("-".to_string(), |p| format!("{p:.2}"));
        let alarm = if a["alarm"].is_null() {
            "-".to_string()
        } else {
            format!(
                "{} {}",
                a["alarm"]["code"].as_str().unwrap_or(""),
                a["alarm"]["text"].as_str().unwrap_or("")
            )
        };
        out += &format!(
            "{:<4} {:<4} {:<8} {:<5} {:<5} {:<6} {:>9}  {:<28} {}\n",
            a["axis"].to_string(),
            a["unit"].to_string(),
            a["link"].as_str().unwrap_or(""),
            yes(&a["servo"]).replace("yes", "on").replace("no", "off"),
            yes(&a["homed"]),
            yes(&a["moving"]),
            pos,
            alarm,
            a["last_command"].as_str().unwrap_or("")
        );
    }
    out
}

/// `rcgw status`, once or `--watch`.
pub fn status(
    gw: &mut Gw,
    json: bool,
    watch: bool,
    interval: f64,
    count: Option<u64>,
) -> Result<(), Fail> {
    if !(0.05..=3600.0).contains(&interval) {
        return Err(Fail::Input(format!("--interval {interval}: 0.05-3600 s")));
    }
    let mut n = 0u64;
    loop {
        let s = status_once(gw)?;
        if json {
            if watch {
                outln!("{s}");
            } else {
                print_json(&s);
            }
        } else {
            if watch && std::io::stdout().is_terminal() {
                out!("\x1b[2J\x1b[H");
            }
            out!("{}", status_text(&s));
        }
        n += 1;
        if !watch || count.is_some_and(|c| n >= c) {
            return Ok(());
        }
        std::thread::sleep(Duration::from_secs_f64(interval));
    }
}
