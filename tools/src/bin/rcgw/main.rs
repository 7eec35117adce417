//! `rcgw`: configure, watch, back up and restore a gateway and every controller's point table
//! from a PC, through the gateway's PLC port (Modbus RTU on a serial port or a pseudo-terminal,
//! or Modbus TCP).
//!
//! ```text
//! $ rcgw --rtu /dev/ttyUSB0 status --watch
//! $ rcgw --tcp 192.168.1.100:502 config show > gateway.toml
//! $ rcgw --tcp 192.168.1.100:502 config apply gateway.toml --save
//! $ rcgw --rtu /dev/ttyUSB0 backup line3.toml
//! $ rcgw --rtu /dev/ttyUSB0 restore line3.toml --dry-run
//! ```
//!
//! Exit status 0 on success, 1 on a line or device error, 2 on bad input; every message names
//! the port, the unit and the register.

/// Text on standard output ([`emit`]).
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::emit(&format!($($arg)*))
    };
}

/// A line on standard output ([`emit`]).
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::emit(&format!("{}\n", format_args!($($arg)*)))
    };
}

mod link;
mod points;
mod settings;

use std::io::IsTerminal;
use std::process::ExitCode;
use std::time::Duration;

use clap::{ArgGroup, Parser, Subcommand};
use protocol::axes::AXES;
use protocol::modbus::{Diagnostic, Exception};
use protocol::plc::map::*;
use protocol::plc::Reason;
use protocol::AlarmCode;
use serde_json::{json, Value};

use crate::link::{Fail, Gw, Link};
use crate::points::Row;
use crate::settings::{Section, Settings};

/// Configure, watch, back up and restore an IAI Robo Cylinder gateway over Modbus RTU or TCP.
#[derive(Parser, Debug)]
#[command(name = "rcgw", version)]
#[command(group(ArgGroup::new("line").required(true).args(["rtu", "tcp"])))]
struct Cli {
    /// Modbus RTU on this serial device (or pseudo-terminal).
    #[arg(long, global = true, value_name = "PATH")]
    rtu: Option<String>,
    /// --rtu: the PLC line's rate, bit/s.
    #[arg(long, global = true, default_value_t = 115_200)]
    baud: u32,
    /// --rtu: the PLC line's parity.
    #[arg(long, global = true, default_value = "none", value_parser = ["none", "odd", "even"])]
    parity: String,
    /// Modbus TCP to this HOST:PORT.
    #[arg(long, global = true, value_name = "HOST:PORT")]
    tcp: Option<String>,
    /// The gateway's unit id (UNITID; on TCP 255 reaches it too).
    #[arg(long, global = true, default_value_t = 63, value_parser = clap::value_parser!(u8).range(1..=255))]
    unit: u8,
    /// JSON on standard output, for scripts.
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Every enabled axis as the PLC sees it, FAILSAFE and the LEDs.
    Status {
        /// Redraw until interrupted.
        #[arg(long)]
        watch: bool,
        /// --watch: seconds between redraws.
        #[arg(long, default_value_t = 0.5)]
        interval: f64,
        /// --watch: stop after this many redraws.
        #[arg(long)]
        count: Option<u64>,
    },
    /// The gateway's settings as TOML: show, compare with a file, apply a file.
    Config {
        #[command(subcommand)]
        action: ConfigCmd,
    },
    /// Settings, version, identity and the point table of every online axis, to one TOML file.
    Backup { file: String },
    /// Settings and point tables from a backup: only what differs is written, then verified.
    Restore {
        file: String,
        /// Show what would change; write nothing.
        #[arg(long)]
        dry_run: bool,
        /// SAVE the settings after restoring them.
        #[arg(long)]
        save: bool,
    },
    /// Write APPLY and wait for the establishment: the pending settings (bus rate, RTIM, PLC
    /// line, UNITID, AXISBASE, axes enabled) take effect, e.g. after a config apply that failed.
    Apply,
    /// Counters: per axis, bus, PLC line, FC08; reset cause and config source.
    Diag,
    /// Acknowledge FAILSAFE.
    Ack,
    /// Store the settings in flash (SAVE).
    Save,
    /// Restart the gateway (the saved settings take effect).
    Restart,
    /// Erase the stored settings and restart with the defaults.
    FactoryReset {
        /// Yes, erase them.
        #[arg(long)]
        yes: bool,
    },
}

#[derive(Subcommand, Debug)]
enum ConfigCmd {
    /// Every setting, as TOML (or JSON).
    Show,
    /// What applying FILE would change.
    Diff { file: String },
    /// Check every value of FILE, write what differs, APPLY when needed.
    Apply {
        file: String,
        /// SAVE afterwards.
        #[arg(long)]
        save: bool,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = run(&cli);
    if result.is_err() && std::io::stderr().is_terminal() {
        // The progress line, cleared before the message.
        eprint!("\r\x1b[K");
    }
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(Fail::Device(m)) => {
            eprintln!("rcgw: {m}");
            ExitCode::from(1)
        }
        Err(Fail::Input(m)) => {
            eprintln!("rcgw: {m}");
            ExitCode::from(2)
        }
    }
}

/// Text written to standard output. A closed pipe (`rcgw status --watch | head -2`) ends the
/// run cleanly, exit 0: the reader has what it wanted.
fn emit(text: &str) {
    use std::io::Write;
    let mut stdout = std::io::stdout().lock();
    if let Err(e) = stdout
        .write_all(text.as_bytes())
        .and_then(|()| stdout.flush())
    {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        eprintln!("rcgw: standard output: {e}");
        std::process::exit(1);
    }
}

fn connect(cli: &Cli) -> Result<Gw, Fail> {
    let link = match (&cli.rtu, &cli.tcp) {
        (Some(path), _) => Link::rtu(
            path,
            cli.baud,
            link::parity_of(&cli.parity).unwrap_or(serialport::Parity::None),
        )?,
        (None, Some(addr)) => Link::tcp(addr)?,
        (None, None) => return Err(Fail::Input("--rtu PATH or --tcp HOST:PORT".into())),
    };
    let mut gw = Gw {
        link,
        unit: cli.unit,
        base: 1,
    };
    gw.base = gw.get(G_AXIS_BASE)? as u8;
    Ok(gw)
}

/// A file read and parsed as TOML: bad input (exit 2) if not.
fn read_toml(path: &str) -> Result<toml::Table, Fail> {
    let text = std::fs::read_to_string(path).map_err(|e| Fail::Input(format!("{path}: {e}")))?;
    text.parse::<toml::Table>()
        .map_err(|e| Fail::Input(format!("{path}: not valid TOML: {e}")))
}

fn bad_file(path: &str, errors: Vec<String>) -> Fail {
    Fail::Input(format!(
        "{path}: {} error(s), nothing written:\n  {}",
        errors.len(),
        errors.join("\n  ")
    ))
}

fn print_json(value: &Value) {
    outln!(
        "{}",
        serde_json::to_string_pretty(value).unwrap_or_default()
    );
}

fn run(cli: &Cli) -> Result<(), Fail> {
    // Files are checked before the line is opened: a bad file writes nothing.
    match &cli.command {
        Cmd::Config {
            action: ConfigCmd::Diff { file } | ConfigCmd::Apply { file, .. },
        } => {
            let doc = read_toml(file)?;
            Settings::from_toml(&doc, &[], false).map_err(|e| bad_file(file, e))?;
        }
        Cmd::Restore { file, .. } => {
            load_backup(file)?;
        }
        Cmd::FactoryReset { yes: false } => {
            return Err(Fail::Input(
                "factory-reset erases every stored setting: add --yes".into(),
            ))
        }
        _ => {}
    }
    let mut gw = connect(cli)?;
    match &cli.command {
        Cmd::Status {
            watch,
            interval,
            count,
        } => status(&mut gw, cli.json, *watch, *interval, *count),
        Cmd::Config { action } => config(&mut gw, cli.json, action),
        Cmd::Backup { file } => backup(&mut gw, cli.json, file),
        Cmd::Restore {
            file,
            dry_run,
            save,
        } => restore(&mut gw, cli.json, file, *dry_run, *save),
        Cmd::Apply => apply_pending(&mut gw, cli.json),
        Cmd::Diag => diag(&mut gw, cli.json),
        Cmd::Ack => ack(&mut gw, cli.json),
        Cmd::Save => {
            let count = settings::save(&mut gw)?;
            if cli.json {
                print_json(&json!({"saved": true, "save_count": count}));
            } else {
                outln!("saved (SAVECOUNT {count})");
            }
            Ok(())
        }
        Cmd::Restart => {
            gw.set(G_RESTART, 1)?;
            if cli.json {
                print_json(&json!({"restart": true}));
            } else {
                outln!("restart requested: the gateway restarts with its saved settings");
            }
            Ok(())
        }
        Cmd::FactoryReset { .. } => {
            gw.set(G_FACTORY, FACTORY_KEY)?;
            if cli.json {
                print_json(&json!({"factory_reset": true}));
            } else {
                outln!("factory reset: the stored settings are erased, the gateway restarts with the defaults");
            }
            Ok(())
        }
    }
}

// ------------------------------------------------------------------ status

fn link_name(link: u16) -> &'static str {
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

/// `rcgw apply`: APPLY, once nothing moves, and the establishment awaited.
fn apply_pending(gw: &mut Gw, json: bool) -> Result<(), Fail> {
    let enabled = Settings::read_enabled(gw)?;
    if let Some(why) = settings::busy(gw, &enabled)? {
        return Err(Fail::Device(format!(
            "{} unit {}: APPLY not written: the gateway refuses it while anything moves or runs: {why}",
            gw.link.name, gw.unit
        )));
    }
    settings::apply(gw)?;
    let enabled = Settings::read_enabled(gw)?;
    let units: Vec<u8> = enabled.iter().map(|&n| gw.axis_unit(n)).collect();
    if json {
        print_json(
            &json!({"applied": true, "unit": gw.unit, "axis_base": gw.base, "axes": enabled, "axis_units": units}),
        );
    } else {
        outln!(
            "APPLY done: gateway unit {}, axes {:?} at units {:?}; the bus was established again",
            gw.unit,
            enabled,
            units
        );
    }
    Ok(())
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

fn status(
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

// ------------------------------------------------------------------ config

fn config(gw: &mut Gw, json: bool, action: &ConfigCmd) -> Result<(), Fail> {
    let now = Settings::read(gw)?;
    match action {
        ConfigCmd::Show => {
            if json {
                print_json(&now.to_json());
            } else {
                outln!(
                    "# rcgw config show: gateway unit {} on {}",
                    gw.unit,
                    gw.link.name
                );
                out!("{}", now.to_toml());
            }
            Ok(())
        }
        ConfigCmd::Diff { file } | ConfigCmd::Apply { file, .. } => {
            let doc = read_toml(file)?;
            let wanted = Settings::from_toml(&doc, &[], false).map_err(|e| bad_file(file, e))?;
            if wanted.has_network() && !now.has_network() {
                return Err(Fail::Input(format!(
                    "{file}: [network]: this gateway has no network settings ({} answers exception 02: a build without TCP)",
                    gw.at(gw.unit, G_NET)
                )));
            }
            let whole = now.merged(&wanted).check_whole();
            if !whole.is_empty() {
                return Err(bad_file(file, whole));
            }
            let changes = now.diff(&wanted);
            let phases = settings::plan(&now, &changes).map_err(|e| bad_file(file, vec![e]))?;
            let apply = matches!(action, ConfigCmd::Apply { .. });
            let save = matches!(action, ConfigCmd::Apply { save: true, .. });
            let applied = if apply {
                settings::write_changes(gw, &phases)?
            } else {
                false
            };
            let saved = if save {
                Some(settings::save(gw)?)
            } else {
                None
            };
            if json {
                print_json(&json!({
                    "changes": changes.iter().map(|c| c.json()).collect::<Vec<_>>(),
                    "phases": phases.len(),
                    "written": apply,
                    "applied": applied,
                    "saved": saved.is_some(),
                }));
            } else {
                if changes.is_empty() {
                    outln!("no change");
                }
                for c in &changes {
                    outln!("{}", c.line());
                }
                if let [first, _] = phases.as_slice() {
                    outln!(
                        "in two steps: {} first, then APPLY, then the rest (the gateway refuses them in one)",
                        keys(first)
                    );
                }
                if changes.iter().any(|c| c.on_restart()) {
                    outln!("[network] addresses take effect after SAVE and RESTART (--save, then rcgw restart)");
                }
                if apply && !changes.is_empty() {
                    outln!("{} setting(s) written", changes.len());
                }
                if applied {
                    outln!("APPLY done: the bus was established again");
                }
                if let Some(count) = saved {
                    outln!("saved (SAVECOUNT {count})");
                }
            }
            Ok(())
        }
    }
}

// ------------------------------------------------------------------ backup and restore

/// The backup's format.
const FORMAT: i64 = 1;

struct Backup {
    settings: Settings,
    points: Vec<(u8, Vec<(u16, Row)>)>,
}

fn load_backup(path: &str) -> Result<Backup, Fail> {
    let doc = read_toml(path)?;
    let mut errors = Vec::new();
    match doc.get("backup").and_then(|b| b.as_table()) {
        None => errors.push("[backup] missing: not an rcgw backup".to_string()),
        Some(b) => {
            for (key, value) in b {
                match (key.as_str(), value) {
                    ("format" | "version" | "axes" | "online", _) => {}
                    ("identity", toml::Value::Table(_)) => {}
                    _ => errors.push(format!(
                        "[backup] {key}: unknown key (format, version, axes, online, [backup.identity])"
                    )),
                }
            }
            if b.get("format").and_then(|f| f.as_integer()) != Some(FORMAT) {
                errors.push(format!("[backup] format: {FORMAT} expected"));
            }
            match b.get("axes").and_then(|a| a.as_integer()) {
                Some(n) if n == AXES as i64 => {}
                Some(n) => errors.push(format!(
                    "[backup] axes = {n}: a backup of a gateway with {n} axes; this one has {AXES}"
                )),
                None => errors.push("[backup] axes missing".into()),
            }
        }
    }
    let settings = match Settings::from_toml(&doc, &["backup"], true) {
        Ok(s) => s,
        Err(e) => {
            errors.extend(e);
            Settings::default()
        }
    };
    let mut points = Vec::new();
    let axes = doc.get("axis").and_then(|a| a.as_table());
    let count = axes.map_or(0, |a| a.len());
    if errors.is_empty() && count != AXES {
        errors.push(format!(
            "{count} [axis.N] tables: a backup of another axis count (this gateway has {AXES})"
        ));
    }
    for (n, table) in axes.into_iter().flatten() {
        let Ok(n) = settings::axis_number(n) else {
            continue;
        };
        if let Some(list) = table.get("point") {
            let rows = points::from_toml(n, list, &mut errors);
            points.push((n, rows));
        }
    }
    if !errors.is_empty() {
        return Err(bad_file(path, errors));
    }
    Ok(Backup { settings, points })
}

fn progress(enabled: bool, text: &str) {
    if enabled {
        eprint!("\r\x1b[K{text}");
    }
}

fn bar(done: usize, total: usize) -> String {
    let width = 24;
    let filled = done * width / total.max(1);
    format!(
        "[{}{}] {done}/{total}",
        "#".repeat(filled),
        "-".repeat(width - filled)
    )
}

fn backup(gw: &mut Gw, json: bool, file: &str) -> Result<(), Fail> {
    let settings = Settings::read(gw)?;
    let unit = gw.unit;
    let v = gw.read(unit, G_VERSION, 2)?;
    let version = format!("{}.{}.{}", v[0] >> 8, v[0] & 0xFF, v[1]);
    let identity = gw.identity()?;
    let mut online = Vec::new();
    let mut unserved = Vec::new();
    for n in settings.enabled() {
        let axis_unit = gw.axis_unit(n);
        match gw.probe(axis_unit, LINK, 1)? {
            Some(link) if link.first() == Some(&1) => online.push(n),
            Some(_) => {}
            None => unserved.push(format!("axis {n} (unit {axis_unit})")),
        }
    }
    if !unserved.is_empty() {
        eprintln!(
            "rcgw: settings pending: enabled but not served: {} (enabled or AXISBASE written, not applied): their point tables are not in the backup; `rcgw apply`, then back up again",
            unserved.join(", ")
        );
    }
    let show = std::io::stderr().is_terminal();
    let total = online.len() * usize::from(protocol::plc::table::ROWS);
    let mut tables = Vec::new();
    for (i, &n) in online.iter().enumerate() {
        let rows = points::read_table(gw, n, &mut |p| {
            let done = i * usize::from(protocol::plc::table::ROWS) + usize::from(p);
            progress(
                show,
                &format!("backup: axis {n} point {p:>2} {}", bar(done, total)),
            );
        })?;
        tables.push((n, rows));
    }
    progress(show, "");
    // Rows the position table would refuse (a stroke reduced since, a negative position, no
    // acceleration): left out, so that restore takes the file; said in it and on stderr.
    let mut omitted: Vec<(u8, usize, String)> = Vec::new();
    for (n, rows) in &mut tables {
        let cfg = settings.axis_cfg(*n);
        for (p, row) in rows.iter_mut().enumerate() {
            if row.is_empty() {
                continue;
            }
            if let Err(why) = points::check(row, &cfg) {
                omitted.push((*n, p, format!("{} ({why})", row.text())));
                *row = Row::default();
            }
        }
    }
    for (n, p, why) in &omitted {
        eprintln!(
            "rcgw: axis {n} point {p}: left out of the backup: the position table would refuse it: {why}"
        );
    }
    let mut text = format!(
        "# rcgw backup of gateway unit {unit}\n\n[backup]\nformat = {FORMAT}\nversion = \"{version}\"\naxes = {AXES}\nonline = [{}]\n\n[backup.identity]\n",
        online.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(", ")
    );
    let names = [
        "vendor",
        "product_code",
        "revision",
        "vendor_url",
        "product_name",
        "model_name",
    ];
    for (id, value) in &identity {
        let key = names
            .get(usize::from(*id))
            .map_or(format!("object_{id:02x}"), |n| n.to_string());
        text += &format!("{key} = {}\n", toml::Value::String(value.clone()));
    }
    text += &settings.to_toml_with(&|section| match section {
        Section::Axis(n) => {
            let mut text = tables
                .iter()
                .find(|(a, _)| *a == n)
                .map_or(String::new(), |(_, rows)| points::to_toml(n, rows));
            for (_, p, why) in omitted.iter().filter(|(a, _, _)| *a == n) {
                text += &format!(
                    "\n# point {p} left out: the position table would refuse it: {}\n",
                    why.replace('\n', " ")
                );
            }
            text
        }
        _ => String::new(),
    });
    std::fs::write(file, &text).map_err(|e| Fail::Input(format!("{file}: {e}")))?;
    let counts: Vec<Value> = tables
        .iter()
        .map(|(n, rows)| {
            let no_speed: Vec<usize> = (0..rows.len())
                .filter(|&p| rows[p].is_empty() && rows[p] != Row::default())
                .filter(|p| !omitted.iter().any(|(a, q, _)| a == n && q == p))
                .collect();
            let left_out: Vec<usize> = omitted.iter().filter(|(a, _, _)| a == n).map(|(_, p, _)| *p).collect();
            json!({"axis": n, "points": rows.iter().filter(|r| !r.is_empty()).count(), "without_speed": no_speed, "left_out": left_out})
        })
        .collect();
    if json {
        print_json(&json!({"file": file, "version": version, "online": online, "axes": counts}));
    } else {
        outln!("backup of gateway unit {unit} (firmware {version}) written to {file}");
        for c in &counts {
            outln!("axis {}: {} point(s)", c["axis"], c["points"]);
            if c["without_speed"].as_array().is_some_and(|a| !a.is_empty()) {
                outln!(
                    "  points {} hold a position but no speed: not saved (the position table cannot write a row without a speed)",
                    c["without_speed"]
                );
            }
        }
        if online.is_empty() {
            outln!("no axis online: no point table saved");
        }
    }
    Ok(())
}

fn restore(gw: &mut Gw, json: bool, file: &str, dry_run: bool, save: bool) -> Result<(), Fail> {
    let b = load_backup(file)?;
    let now = Settings::read(gw)?;
    let mut wanted = b.settings.clone();
    let mut notes = Vec::new();
    if !now.has_network() && wanted.has_network() {
        wanted.values.retain(|(s, _), _| *s != Section::Network);
        notes.push(
            "[network] of the backup left out: this gateway has no network settings (a build without Modbus TCP)"
                .to_string(),
        );
    }
    // The gateway unit and the PLC line are the ones this connection uses: a backup of another
    // gateway would take them over; they are restored too (that is the point of a backup).
    let after = now.merged(&wanted);
    let mut whole = after.check_whole();
    for (n, rows) in &b.points {
        if !rows.is_empty() && after.word(Section::Axis(*n), "enabled") != Some(1) {
            whole.push(format!(
                "[[axis.{n}.point]]: axis {n} is not enabled ([axis.{n}] enabled = false): its {} row(s) cannot be written",
                rows.len()
            ));
        }
    }
    let changes = now.diff(&wanted);
    let phases = settings::plan(&now, &changes).unwrap_or_else(|e| {
        whole.push(e);
        Vec::new()
    });
    if !whole.is_empty() {
        return Err(bad_file(file, whole));
    }
    // Every row checked as the position table will check it, with the axis' settings as
    // they will be, before anything is written: a row it would refuse is skipped.
    let mut skipped = Vec::new();
    let mut tables: Vec<(u8, Vec<(u16, Row)>)> = Vec::new();
    for (n, rows) in &b.points {
        let cfg = after.axis_cfg(*n);
        let mut keep = Vec::new();
        for (p, row) in rows {
            match points::check(row, &cfg) {
                Ok(()) => keep.push((*p, *row)),
                Err(why) => skipped.push(format!(
                    "axis {n} point {p}: not restored: the position table would refuse it: {why}"
                )),
            }
        }
        tables.push((*n, keep));
    }
    let was_enabled = now.enabled();
    let applied = if dry_run {
        false
    } else {
        settings::write_changes(gw, &phases)?
    };
    let mut report = Vec::new();
    let mut missing = Vec::new();
    let show = std::io::stderr().is_terminal() && !dry_run;
    let mut rows_of = |gw: &mut Gw, report: &mut Vec<Value>| -> Result<(), Fail> {
        for (n, rows) in &tables {
            if dry_run && !was_enabled.contains(n) {
                report.push(json!({"axis": n, "enabled_on_apply": true, "rows": rows.len(), "written": [], "unchanged": 0, "not_in_backup": []}));
                continue;
            }
            let axis_unit = gw.axis_unit(*n);
            // Not served (0A, 02, silence): not online. LINK 0 (unknown: its first exchange
            // still under way, as right after a start or an APPLY): waited for, at most 3 s.
            let deadline = std::time::Instant::now() + Duration::from_secs(3);
            let online = loop {
                match gw.probe(axis_unit, LINK, 1)? {
                    Some(l) if l.first() == Some(&0) && std::time::Instant::now() < deadline => {
                        std::thread::sleep(Duration::from_millis(50))
                    }
                    Some(l) => break l.first() == Some(&1),
                    None => break false,
                }
            };
            if !online {
                missing.push(format!(
                    "axis {n} (unit {axis_unit}): not online: its {} point(s) not restored",
                    rows.len()
                ));
                continue;
            }
            let mut written = Vec::new();
            let mut unchanged = 0;
            let mut kept = Vec::new();
            let table = points::read_table(gw, *n, &mut |p| {
                progress(show, &format!("restore: axis {n} reading point {p:>2}"));
            })?;
            let entry_of = |written: &Vec<Value>, unchanged, kept: &Vec<usize>| json!({"axis": n, "written": written, "unchanged": unchanged, "not_in_backup": kept});
            for (point, row) in rows {
                let current = table.get(usize::from(*point)).copied().unwrap_or_default();
                if current == *row {
                    unchanged += 1;
                    continue;
                }
                progress(show, &format!("restore: axis {n} writing point {point:>2}"));
                let mut entry = json!({"point": point, "from": if current.is_empty() { Value::Null } else { json!(current.text()) }, "to": row.text()});
                if !dry_run {
                    match points::write_row(gw, *n, *point, row) {
                        Ok(stored) => {
                            if stored != *row {
                                entry["stored"] = json!(stored.text());
                            }
                        }
                        Err(e) => {
                            report.push(entry_of(&written, unchanged, &kept));
                            return Err(e);
                        }
                    }
                }
                written.push(entry);
            }
            for (point, row) in table.iter().enumerate() {
                if !row.is_empty()
                    && !b.points.iter().any(|(a, rows)| {
                        a == n && rows.iter().any(|(p, _)| usize::from(*p) == point)
                    })
                {
                    kept.push(point);
                }
            }
            report.push(entry_of(&written, unchanged, &kept));
        }
        Ok(())
    };
    let outcome = rows_of(gw, &mut report);
    progress(show, "");
    let saved = match (&outcome, save && !dry_run) {
        (Ok(()), true) => Some(settings::save(gw)?),
        _ => None,
    };
    if json {
        print_json(&json!({
            "dry_run": dry_run,
            "settings": changes.iter().map(|c| c.json()).collect::<Vec<_>>(),
            "applied": applied,
            "axes": report,
            "not_restored": missing,
            "skipped": skipped,
            "notes": notes,
            "saved": saved.is_some(),
            "save_count": saved,
            "complete": outcome.is_ok(),
        }));
    } else {
        let verb = if dry_run { "would change" } else { "changed" };
        outln!("settings: {} {verb}", changes.len());
        for c in &changes {
            outln!("  {}", c.line());
        }
        if let [first, _] = phases.as_slice() {
            outln!(
                "  in two steps: {} first, then APPLY, then the rest",
                keys(first)
            );
        }
        if changes.iter().any(|c| c.on_restart()) {
            outln!("  [network] addresses take effect after SAVE and RESTART");
        }
        for n in &notes {
            outln!("  {n}");
        }
        if applied {
            outln!("  APPLY done: the bus was established again");
        }
        for r in &report {
            if r["enabled_on_apply"] == true {
                outln!(
                    "axis {}: enabled on APPLY; its {} row(s) compared after it",
                    r["axis"],
                    r["rows"]
                );
                continue;
            }
            let written = r["written"].as_array().map_or(0, |w| w.len());
            outln!(
                "axis {}: {written} point(s) {}, {} unchanged",
                r["axis"],
                if dry_run {
                    "would be written"
                } else {
                    "written and verified"
                },
                r["unchanged"]
            );
            for w in r["written"].as_array().into_iter().flatten() {
                outln!(
                    "  point {}: {} -> {}",
                    w["point"],
                    w["from"].as_str().unwrap_or("empty"),
                    w["to"].as_str().unwrap_or("")
                );
                if let Some(stored) = w["stored"].as_str() {
                    outln!("    stored as {stored} (the controller's resolution)");
                }
            }
            for p in r["not_in_backup"].as_array().into_iter().flatten() {
                outln!("  point {p}: holds data the backup has empty: left as it is (a row cannot be emptied over Modbus)");
            }
        }
        for m in &missing {
            outln!("{m}");
        }
        for k in &skipped {
            outln!("{k}");
        }
        if let Some(count) = saved {
            outln!("saved (SAVECOUNT {count})");
        }
    }
    outcome.map_err(|e| match e {
        Fail::Device(m) | Fail::Input(m) => Fail::Device(format!(
            "{m}\n  restore stopped there: the report above is what was done"
        )),
    })?;
    if !missing.is_empty() {
        return Err(Fail::Device(format!(
            "{}: {} axis/axes of the backup not online: check their controllers, then restore again",
            gw.link.name,
            missing.len()
        )));
    }
    if !skipped.is_empty() {
        return Err(Fail::Input(format!(
            "{file}: {} row(s) skipped (the position table would refuse them), the rest restored:\n  {}",
            skipped.len(),
            skipped.join("\n  ")
        )));
    }
    Ok(())
}

// ------------------------------------------------------------------ diag, ack

fn long(r: &[u16], i: usize) -> u32 {
    u32::from(r.get(2 * i).copied().unwrap_or(0)) << 16
        | u32::from(r.get(2 * i + 1).copied().unwrap_or(0))
}

fn diag(gw: &mut Gw, json: bool) -> Result<(), Fail> {
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

fn ack(gw: &mut Gw, json: bool) -> Result<(), Fail> {
    let before = gw.get(G_FAILSAFE)?;
    if before == 0 {
        if json {
            print_json(&json!({"failsafe": 0, "acknowledged": false, "latched": false}));
        } else {
            outln!("FAILSAFE is clear: nothing to acknowledge");
        }
        return Ok(());
    }
    let unit = gw.unit;
    match gw.try_write(unit, G_FAILSAFE, &[0])? {
        Ok(()) => {}
        Err(Exception::IllegalDataValue) => {
            return Err(Fail::Device(format!(
                "{}: not acknowledged (exception 03): the cause is still there{}",
                gw.at(unit, G_FAILSAFE),
                if before & 2 != 0 {
                    ": the stop input is open; close the stop chain, then ack again"
                } else {
                    ": the stop input is open"
                }
            )))
        }
        Err(e) => return Err(Fail::Device(format!("{}: {e}", gw.at(unit, G_FAILSAFE)))),
    }
    let after = gw.get(G_FAILSAFE)?;
    if json {
        print_json(
            &json!({"failsafe": after, "was": before, "acknowledged": true, "latched": after != 0}),
        );
    } else {
        outln!("FAILSAFE acknowledged (was {before:#04x}, now {after:#04x})");
    }
    Ok(())
}

/// The settings of a write's first phase, as the file names them: `[gateway] unit_id, ...`.
fn keys(changes: &[settings::Change]) -> String {
    changes
        .iter()
        .map(|c| format!("{} {}", settings::section_name(c.section), c.key))
        .collect::<Vec<_>>()
        .join(", ")
}
