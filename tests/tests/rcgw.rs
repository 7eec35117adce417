//! `rcgw` against `rc-gateway-host` with simulated axes, over Modbus RTU (a pseudo-terminal)
//! and Modbus TCP (loopback): every command, the backup/restore round trip, and bad input.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, ChildStdout, Command, Output, Stdio};

/// A gateway on a PTY and a TCP port, with two simulated axes; killed when dropped.
struct Gateway {
    child: Child,
    _stdout: BufReader<ChildStdout>,
    pty: String,
    tcp: String,
    dir: PathBuf,
}

impl Gateway {
    fn start(name: &str) -> Gateway {
        let mut child = Command::new(env!("CARGO_BIN_EXE_rc-gateway-host"))
            .args(["--plc-pty", "--modbus-tcp", "127.0.0.1:0", "--sim", "2"])
            .args(["--no-control", "--watchdog-ms", "0", "--points"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start rc-gateway-host");
        let mut stdout = BufReader::new(child.stdout.take().expect("stdout"));
        let (mut pty, mut tcp) = (String::new(), String::new());
        while pty.is_empty() || tcp.is_empty() {
            let mut line = String::new();
            assert!(
                stdout.read_line(&mut line).expect("read") > 0,
                "gateway ended"
            );
            if let Some(p) = line.trim().strip_prefix("PLC ") {
                pty = p.to_string();
            } else if let Some(t) = line.trim().strip_prefix("TCP ") {
                tcp = t.to_string();
            }
        }
        let dir = std::env::temp_dir().join(format!("rcgw-test-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        Gateway {
            child,
            _stdout: stdout,
            pty,
            tcp,
            dir,
        }
    }

    fn rtu(&self) -> Vec<String> {
        vec!["--rtu".into(), self.pty.clone()]
    }

    fn tcp(&self) -> Vec<String> {
        vec!["--tcp".into(), self.tcp.clone()]
    }

    fn file(&self, name: &str, text: &str) -> String {
        let path = self.dir.join(name);
        std::fs::write(&path, text).expect("write file");
        path.to_string_lossy().into_owned()
    }

    fn path(&self, name: &str) -> String {
        self.dir.join(name).to_string_lossy().into_owned()
    }
}

impl Drop for Gateway {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn rcgw(line: &[String], args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_rcgw"))
        .args(line)
        .args(args)
        .stdin(Stdio::null())
        .output()
        .expect("run rcgw")
}

fn text(out: &Output) -> String {
    format!(
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        out.status.code(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

fn ok(line: &[String], args: &[&str]) -> String {
    let out = rcgw(line, args);
    assert_eq!(out.status.code(), Some(0), "{args:?}: {}", text(&out));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn json(line: &[String], args: &[&str]) -> serde_json::Value {
    let mut all = args.to_vec();
    all.push("--json");
    serde_json::from_str(&ok(line, &all)).expect("JSON")
}

fn fails(line: &[String], args: &[&str], code: i32, says: &[&str]) {
    let out = rcgw(line, args);
    assert_eq!(out.status.code(), Some(code), "{args:?}: {}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    for s in says {
        assert!(stderr.contains(s), "{args:?}: {s:?} not in {}", text(&out));
    }
}

#[test]
fn every_command_over_rtu_and_tcp() {
    let gw = Gateway::start("every");
    for line in [gw.rtu(), gw.tcp()] {
        let status = ok(&line, &["status"]);
        assert!(status.contains("FAILSAFE: clear"), "{status}");
        assert!(status.contains("online"), "{status}");
        let s = json(&line, &["status"]);
        assert_eq!(s["axes"].as_array().map(|a| a.len()), Some(2), "{s}");
        assert_eq!(s["axes"][1]["unit"], 2);
        assert_eq!(s["axes"][0]["link"], "online");
        let watch = ok(
            &line,
            &["status", "--watch", "--count", "2", "--interval", "0.1"],
        );
        assert_eq!(watch.matches("FAILSAFE").count(), 2, "{watch}");

        let show = ok(&line, &["config", "show"]);
        let doc: toml::Table = show.parse().expect("config show is TOML");
        assert_eq!(doc["gateway"]["unit_id"].as_integer(), Some(63));
        assert_eq!(doc["axis"]["1"]["enabled"].as_bool(), Some(true));
        assert_eq!(doc["network"]["tcp_max_connections"].as_integer(), Some(4));
        let j = json(&line, &["config", "show"]);
        assert_eq!(j["gateway"]["plc_baud_bps"], 115_200);

        let d = json(&line, &["diag"]);
        assert_eq!(d["axes"].as_array().map(|a| a.len()), Some(2), "{d}");
        assert!(d["plc_line"]["frames"].as_u64().unwrap_or(0) > 0, "{d}");
        // FC08 is serial-line only.
        assert_eq!(d["fc08"].is_null(), line[0] == "--tcp", "{d}");
        assert!(ok(&line, &["diag"]).contains("time-outs"));

        assert_eq!(json(&line, &["ack"])["latched"], false);
        assert!(ok(&line, &["ack"]).contains("nothing to acknowledge"));
        let saved = json(&line, &["save"]);
        assert_eq!(saved["saved"], true);
        assert!(ok(&line, &["save"]).contains("saved (SAVECOUNT"));
        assert!(json(&line, &["diag"])["save_count"].as_u64().unwrap_or(0) >= 2);
        fails(&line, &["factory-reset"], 2, &["--yes"]);
        assert_eq!(
            json(&line, &["factory-reset", "--yes"])["factory_reset"],
            true
        );
        assert_eq!(json(&line, &["restart"])["restart"], true);
    }
}

#[test]
fn config_apply_writes_what_differs_applies_and_saves() {
    let gw = Gateway::start("apply");
    let change = gw.file(
        "change.toml",
        "[gateway]\nretries = 3\nbus_rtim_ms = 5\nwatchdog_action = \"latch\"\n\n\
         [axis.1]\nlead_mm = 6\nstroke_mm = 150.5\nhome = \"far\"\n",
    );
    let diff = ok(&gw.tcp(), &["config", "diff", &change]);
    assert!(
        diff.contains("[gateway] bus_rtim_ms: 3 -> 5 (on APPLY)"),
        "{diff}"
    );
    assert!(
        diff.contains("[axis.1] stroke_mm: 100.00 -> 150.50"),
        "{diff}"
    );
    let applied = json(&gw.rtu(), &["config", "apply", &change, "--save"]);
    assert_eq!(
        applied["changes"].as_array().map(|c| c.len()),
        Some(6),
        "{applied}"
    );
    assert_eq!(applied["applied"], true);
    assert_eq!(applied["saved"], true);
    assert!(ok(&gw.tcp(), &["config", "diff", &change]).contains("no change"));
    let now = json(&gw.tcp(), &["config", "show"]);
    assert_eq!(now["gateway"]["bus_rtim_ms"], 5);
    assert_eq!(now["axis"]["1"]["home"], "far");
    // Only RETRIES differs: written at once, no APPLY.
    let again = gw.file("again.toml", "[gateway]\nretries = 1\n");
    let j = json(&gw.tcp(), &["config", "apply", &again]);
    assert_eq!(j["applied"], false, "{j}");
    assert_eq!(j["changes"].as_array().map(|c| c.len()), Some(1), "{j}");
    // The axes still answer after the APPLY.
    assert_eq!(json(&gw.rtu(), &["status"])["axes"][1]["link"], "online");
}

/// The points written into a backup file, as a user editing it would.
const POINTS: &str = "\n[[axis.1.point]]\npoint = 2\nposition_mm = 33.50\nspeed_mm_s = 120.00\n\
    accel_g = 0.30\nband_mm = 0.10\n\n[[axis.1.point]]\npoint = 7\nposition_mm = 80.00\n\
    speed_mm_s = 50.00\naccel_g = 0.20\nband_mm = 0.50\n";

#[test]
fn backup_change_restore_backup_is_identical() {
    let gw = Gateway::start("roundtrip");
    let b0 = gw.path("b0.toml");
    let out = ok(&gw.rtu(), &["backup", &b0]);
    assert!(out.contains("axis 1: 0 point(s)"), "{out}");
    // Seed two rows of axis 1 through a restore of the backup with them added.
    let seeded = std::fs::read_to_string(&b0).expect("b0") + POINTS;
    let seeded = gw.file("seeded.toml", &seeded);
    let r = json(&gw.tcp(), &["restore", &seeded]);
    assert_eq!(
        r["axes"][0]["written"].as_array().map(|w| w.len()),
        Some(2),
        "{r}"
    );
    let b1 = gw.path("b1.toml");
    let j = json(&gw.tcp(), &["backup", &b1]);
    assert_eq!(j["axes"][1]["points"], 2, "{j}");
    let first = std::fs::read_to_string(&b1).expect("b1");
    assert!(first.contains("[[axis.1.point]]\npoint = 7"), "{first}");

    // Change a row (a restore of an edited backup), then settings.
    let moved = first.replace("position_mm = 80.00", "position_mm = 90.00");
    let moved = gw.file("moved.toml", &moved);
    ok(&gw.rtu(), &["restore", &moved]);
    let change = gw.file(
        "change.toml",
        "[gateway]\nretries = 0\nbus_rtim_ms = 9\npio_axis = 1\n[axis.0]\nlead_mm = 12\n[network]\ntcp_idle_s = 5\n",
    );
    ok(&gw.rtu(), &["config", "apply", &change]);

    // A dry run says what would change and writes nothing.
    let dry = json(&gw.tcp(), &["restore", &b1, "--dry-run"]);
    assert_eq!(
        dry["settings"].as_array().map(|s| s.len()),
        Some(5),
        "{dry}"
    );
    assert_eq!(
        dry["axes"][0]["written"].as_array().map(|w| w.len()),
        Some(1),
        "{dry}"
    );
    let dry_again = json(&gw.tcp(), &["restore", &b1, "--dry-run"]);
    assert_eq!(dry, dry_again);

    let report = ok(&gw.rtu(), &["restore", &b1]);
    assert!(report.contains("settings: 5 changed"), "{report}");
    assert!(
        report.contains("axis 1: 1 point(s) written and verified, 1 unchanged"),
        "{report}"
    );
    assert!(report.contains("point 7: 90.00 mm"), "{report}");
    let b2 = gw.path("b2.toml");
    ok(&gw.tcp(), &["backup", &b2]);
    assert_eq!(first, std::fs::read_to_string(&b2).expect("b2"));
    // Nothing left to write.
    let r = json(&gw.rtu(), &["restore", &b2]);
    assert_eq!(r["settings"].as_array().map(|s| s.len()), Some(0), "{r}");
    assert_eq!(r["axes"][0]["unchanged"], 2, "{r}");
}

#[test]
fn bad_input_is_refused_with_the_port_unit_and_register() {
    let gw = Gateway::start("bad");
    let tcp = gw.tcp();
    // Wrong ports; a gateway that does not answer (another unit).
    fails(
        &["--rtu".into(), "/nonexistent/ttyUSB9".into()],
        &["status"],
        1,
        &["/nonexistent/ttyUSB9"],
    );
    fails(
        &["--rtu".into(), "/dev/null".into()],
        &["status"],
        1,
        &["/dev/null: not a serial port"],
    );
    fails(
        &["--tcp".into(), "127.0.0.1:1".into()],
        &["status"],
        1,
        &["127.0.0.1:1: cannot connect"],
    );
    fails(
        &["--tcp".into(), "no port".into()],
        &["status"],
        2,
        &["not a HOST:PORT"],
    );
    let mut silent = gw.rtu();
    silent.extend(["--unit".into(), "99".into()]);
    fails(
        &silent,
        &["status"],
        1,
        &[&gw.pty, "unit 99", "register 0x0020 (AXISBASE)", "no reply"],
    );
    let mut other = gw.tcp();
    other.extend(["--unit".into(), "99".into()]);
    fails(&other, &["diag"], 1, &["unit 99", "exception 0A"]);
    fails(&[], &["status"], 2, &["--rtu"]);

    // Malformed and out-of-range files: every problem named, nothing written.
    let before = ok(&tcp, &["config", "show"]);
    let malformed = gw.file("malformed.toml", "[gateway\nretries = 1\n");
    fails(
        &tcp,
        &["config", "apply", &malformed],
        2,
        &["not valid TOML"],
    );
    let bad = gw.file(
        "bad.toml",
        "colour = 1\n[gateway]\nretries = 2\nwatchdog_ms = 20\nplc_baud_bps = 115201\nbogus = 1\n\
         [axis.1]\nlead_mm = 6.123\nhome = \"left\"\n[axis.16]\nenabled = true\n",
    );
    fails(
        &tcp,
        &["config", "apply", &bad],
        2,
        &[
            "7 error(s), nothing written",
            "unknown key \"colour\"",
            "[gateway] watchdog_ms = 20: out of range (allowed: 0, 50-60000 ms) (register 0x0006)",
            "[gateway] plc_baud_bps = 115201: 115201 is not a multiple of 100",
            "[gateway] bogus: unknown key",
            "[axis.1] lead_mm = 6.123: 6.123: at most 2 decimals",
            "[axis.1] home = \"left\"",
            "[axis.16]: no such axis",
        ],
    );
    let clash = gw.file("clash.toml", "[gateway]\nretries = 0\nunit_id = 2\n");
    fails(
        &tcp,
        &["config", "apply", &clash],
        2,
        &["unit_id = 2: axis 1 is enabled"],
    );
    fails(
        &tcp,
        &["config", "diff", &gw.path("missing.toml")],
        2,
        &["missing.toml"],
    );
    assert_eq!(before, ok(&tcp, &["config", "show"]));

    // Backups: another axis count, a point out of range, not a backup.
    let b = gw.path("b.toml");
    ok(&tcp, &["backup", &b]);
    let good = std::fs::read_to_string(&b).expect("backup");
    let fewer = gw.file("fewer.toml", &good.replace("axes = 16", "axes = 8"));
    fails(
        &tcp,
        &["restore", &fewer],
        2,
        &["a backup of a gateway with 8 axes; this one has 16"],
    );
    let cut = good.find("\n[axis.8]").expect("axis 8");
    let eight = gw.file("eight.toml", good.get(..cut).unwrap_or(""));
    fails(
        &tcp,
        &["restore", &eight],
        2,
        &["8 [axis.N] tables: a backup of another axis count"],
    );
    let far = good.clone() + &POINTS.replace("80.00", "100.01");
    let far = gw.file("far.toml", &far);
    fails(
        &tcp,
        &["restore", &far],
        2,
        &["[[axis.1.point]] #2 position_mm = 100.01: out of range"],
    );
    let settings_only = gw.file("settings.toml", "[gateway]\nretries = 1\n");
    fails(&tcp, &["restore", &settings_only], 2, &["[backup] missing"]);
    assert_eq!(before, ok(&tcp, &["config", "show"]));
}
