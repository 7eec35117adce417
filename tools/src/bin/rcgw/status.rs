//! `rcgw status`: every enabled axis as the PLC sees it, FAILSAFE, the LEDs and the settings
//! that wait for APPLY.

use std::fmt;
use std::io::IsTerminal;
use std::time::Duration;

use protocol::modbus::Exception;
use protocol::plc::map::*;
use protocol::plc::Reason;
use protocol::AlarmCode;
use serde::Serialize;

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

/// An axis as `status` shows it (`axes[]` in its JSON).
#[derive(Serialize, Debug)]
pub struct AxisStatus {
    pub axis: u8,
    pub unit: u8,
    pub link: &'static str,
    pub last_command: String,
    /// `false` only: the axis is enabled but its unit not served (pending until APPLY); the
    /// key is absent for an axis that answers.
    #[serde(skip_serializing_if = "is_true")]
    pub served: bool,
    /// Its command registers, when its unit answers.
    #[serde(flatten)]
    pub command: Option<CommandRegs>,
    /// Its drive, when the controller answers (02 04 of an axis offline: absent).
    #[serde(flatten)]
    pub drive: Option<Drive>,
}

fn is_true(v: &bool) -> bool {
    *v
}

/// CMST, CMER and CMCT as read.
#[derive(Serialize, Debug)]
pub struct CommandRegs {
    pub cmst: u16,
    pub cmer: u16,
    pub cmct: u16,
}

/// What the controller reports: DSS1's and DSSE's bits, PNOW, ALMC.
#[derive(Serialize, Debug)]
pub struct Drive {
    pub servo: bool,
    pub homed: bool,
    pub in_position: bool,
    pub moving: bool,
    pub position_mm: f64,
    /// `null` in JSON when there is none.
    pub alarm: Option<Alarm>,
}

/// An alarm: its code in hex and its text.
#[derive(Serialize, Debug)]
pub struct Alarm {
    pub code: String,
    pub text: &'static str,
}

/// FAILSAFE: latched or not, why, how often.
#[derive(Serialize, Debug)]
pub struct Failsafe {
    pub latched: bool,
    pub causes: Vec<&'static str>,
    pub trips: u16,
}

/// What each LED shows, in words.
#[derive(Serialize, Debug)]
pub struct Leds {
    pub run: &'static str,
    pub bus_link: &'static str,
    pub alarm: &'static str,
}

/// `rcgw status`'s report: the JSON as serialised, the text by [`fmt::Display`].
#[derive(Serialize, Debug)]
pub struct Status {
    pub port: String,
    pub unit: u8,
    pub version: String,
    pub uptime_s: u32,
    pub failsafe: Failsafe,
    pub leds: Leds,
    pub axes: Vec<AxisStatus>,
    pub pending: Vec<String>,
}

fn axis_status(gw: &mut Gw, axis: u8) -> Result<AxisStatus, Fail> {
    let unit = gw.axis_unit(axis);
    let Some(ext) = gw.probe(unit, CMST, 4)? else {
        // Enabled (AXISCFG) but its unit not served: enabled, or AXISBASE changed, pending
        // until APPLY.
        return Ok(AxisStatus {
            axis,
            unit,
            link: "not served",
            last_command: "-".into(),
            served: false,
            command: None,
            drive: None,
        });
    };
    let (cmst, cmer, link, cmct) = (ext[0], ext[1], ext[2], ext[3]);
    let drive = match gw.try_read(unit, PNOW, 8)? {
        Ok(r) => {
            let pnow = (u32::from(r[0]) << 16 | u32::from(r[1])) as i32;
            let (almc, dss1, dsse) = (r[2], r[5], r[7]);
            Some(Drive {
                servo: dss1 & DSS1_SV != 0,
                homed: dss1 & DSS1_HEND != 0,
                in_position: dss1 & DSS1_PEND != 0,
                moving: dsse & DSSE_MOVE != 0,
                position_mm: f64::from(pnow) / 100.0,
                alarm: (almc != 0).then(|| Alarm {
                    code: format!("{almc:02X}"),
                    text: AlarmCode(almc as u8).text(),
                }),
            })
        }
        Err(Exception::ServerDeviceFailure) => None,
        Err(e) => return Err(Fail::Device(format!("{}: {e}", gw.at(unit, PNOW)))),
    };
    Ok(AxisStatus {
        axis,
        unit,
        link: link_name(link),
        last_command: command_text(cmst, cmer, cmct),
        served: true,
        command: Some(CommandRegs { cmst, cmer, cmct }),
        drive,
    })
}

fn status_once(gw: &mut Gw) -> Result<Status, Fail> {
    let unit = gw.unit;
    let g = gw.read(unit, 0, 6)?;
    let enabled = Settings::read_enabled(gw)?;
    let mut axes = Vec::new();
    for n in enabled {
        axes.push(axis_status(gw, n)?);
    }
    let pending = pending_settings(gw, &axes)?;
    let failsafe = g[4];
    let all_online = axes.iter().all(|a| a.link == "online");
    let alarm = axes
        .iter()
        .any(|a| a.drive.as_ref().is_some_and(|d| d.alarm.is_some()));
    let alarm_led = failsafe != 0 || !all_online || alarm;
    let mut causes = Vec::new();
    if failsafe & 1 != 0 {
        causes.push("PLC watchdog");
    }
    if failsafe & 2 != 0 {
        causes.push("stop input");
    }
    Ok(Status {
        port: gw.link.name.clone(),
        unit,
        version: format!("{}.{}.{}", g[0] >> 8, g[0] & 0xFF, g[1]),
        uptime_s: u32::from(g[2]) << 16 | u32::from(g[3]),
        failsafe: Failsafe {
            latched: failsafe != 0,
            causes,
            trips: g[5],
        },
        leds: Leds {
            run: "blinking: the gateway task runs (it answers)",
            bus_link: if all_online {
                "on: every enabled axis answers"
            } else {
                "off: an enabled axis does not answer"
            },
            alarm: if alarm_led {
                "on: FAILSAFE latched, an axis offline or in alarm"
            } else {
                "off"
            },
        },
        axes,
        pending,
    })
}

/// Signs that settings wait for APPLY (registers read the pending values): UNITID not the unit
/// that answers, an enabled axis whose unit is not served.
fn pending_settings(gw: &mut Gw, axes: &[AxisStatus]) -> Result<Vec<String>, Fail> {
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
        .filter(|a| !a.served)
        .map(|a| format!("axis {} (unit {})", a.axis, a.unit))
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

impl fmt::Display for Status {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "gateway unit {} on {}: firmware {}, up {} s",
            self.unit, self.port, self.version, self.uptime_s
        )?;
        let fs = &self.failsafe;
        if fs.latched {
            writeln!(
                f,
                "FAILSAFE: LATCHED ({}); no motion until acknowledged (rcgw ack); trips {}",
                fs.causes.join(", "),
                fs.trips
            )?;
        } else {
            writeln!(f, "FAILSAFE: clear (trips {})", fs.trips)?;
        }
        f.write_str(&pending_text(&self.pending))?;
        for (name, led) in [
            ("run", self.leds.run),
            ("bus link", self.leds.bus_link),
            ("alarm", self.leds.alarm),
        ] {
            writeln!(f, "LED {name:<9} {led}")?;
        }
        writeln!(
            f,
            "{:<4} {:<4} {:<8} {:<5} {:<5} {:<6} {:>9}  {:<28} last command",
            "axis", "unit", "link", "servo", "homed", "moving", "pos mm", "alarm"
        )?;
        for a in &self.axes {
            let d = a.drive.as_ref();
            let flag = |get: fn(&Drive) -> bool, yes: &'static str, no: &'static str| {
                d.map_or("-", |d| if get(d) { yes } else { no })
            };
            let pos = d.map_or("-".to_string(), |d| format!("{:.2}", d.position_mm));
            let alarm = d
                .and_then(|d| d.alarm.as_ref())
                .map_or("-".to_string(), |a| format!("{} {}", a.code, a.text));
            writeln!(
                f,
                "{:<4} {:<4} {:<8} {:<5} {:<5} {:<6} {:>9}  {:<28} {}",
                a.axis,
                a.unit,
                a.link,
                flag(|d| d.servo, "on", "off"),
                flag(|d| d.homed, "yes", "no"),
                flag(|d| d.moving, "yes", "no"),
                pos,
                alarm,
                a.last_command
            )?;
        }
        Ok(())
    }
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
                outln!("{}", serde_json::to_string(&s).unwrap_or_default());
            } else {
                print_json(&s);
            }
        } else {
            if watch && std::io::stdout().is_terminal() {
                out!("\x1b[2J\x1b[H");
            }
            out!("{s}");
        }
        n += 1;
        if !watch || count.is_some_and(|c| n >= c) {
            return Ok(());
        }
        std::thread::sleep(Duration::from_secs_f64(interval));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The JSON of each kind of axis keeps the keys (and their order) scripts read: an axis
    /// not served has `served: false` and nothing else, one offline no drive keys, one that
    /// answers `alarm` as `null` or an object.
    #[test]
    fn axis_json_keys() {
        let not_served = AxisStatus {
            axis: 3,
            unit: 4,
            link: "not served",
            last_command: "-".into(),
            served: false,
            command: None,
            drive: None,
        };
        assert_eq!(
            serde_json::to_string(&not_served).unwrap(),
            r#"{"axis":3,"unit":4,"link":"not served","last_command":"-","served":false}"#
        );
        let offline = AxisStatus {
            link: "offline",
            last_command: "none".into(),
            served: true,
            command: Some(CommandRegs {
                cmst: 0,
                cmer: 0,
                cmct: 0,
            }),
            ..not_served
        };
        assert_eq!(
            serde_json::to_string(&offline).unwrap(),
            r#"{"axis":3,"unit":4,"link":"offline","last_command":"none","cmst":0,"cmer":0,"cmct":0}"#
        );
        let alarm = AxisStatus {
            drive: Some(Drive {
                servo: true,
                homed: false,
                in_position: true,
                moving: false,
                position_mm: 12.5,
                alarm: Some(Alarm {
                    code: "0E".into(),
                    text: "x",
                }),
            }),
            ..offline
        };
        assert_eq!(
            serde_json::to_string(&alarm).unwrap(),
            r#"{"axis":3,"unit":4,"link":"offline","last_command":"none","cmst":0,"cmer":0,"cmct":0,"servo":true,"homed":false,"in_position":true,"moving":false,"position_mm":12.5,"alarm":{"code":"0E","text":"x"}}"#
        );
    }
}
