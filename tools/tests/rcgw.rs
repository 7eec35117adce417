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
        Gateway::with_axes(name, 2)
    }

    fn with_axes(name: &str, sims: u8) -> Gateway {
        Gateway::with_args(name, sims, &[])
    }

    fn with_args(name: &str, sims: u8, extra: &[&str]) -> Gateway {
        let sims = sims.to_string();
        let mut child = Command::new(env!("CARGO_BIN_EXE_rc-gateway-host"))
            .args(["--plc-pty", "--modbus-tcp", "127.0.0.1:0", "--sim", &sims])
            .args(["--no-control", "--watchdog-ms", "0", "--points"])
            .args(extra)
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

    /// Once every simulated axis is online (they come online one after the other).
    fn online(self) -> Gateway {
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
        loop {
            let s = json(&self.tcp(), &["status"]);
            let axes = s["axes"].as_array().cloned().unwrap_or_default();
            if axes.iter().all(|a| a["link"] == "online") {
                return self;
            }
            assert!(std::time::Instant::now() < deadline, "axes not online: {s}");
            std::thread::sleep(std::time::Duration::from_millis(100));
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
    // A row beyond the stroke: skipped and reported, the rest restored, exit 2.
    let far = good.clone() + &POINTS.replace("80.00", "100.01");
    let far = gw.file("far.toml", &far);
    fails(
        &tcp,
        &["restore", &far],
        2,
        &[
            "axis 1 point 7: not restored",
            "position_mm = 100.01: outside 0.00-100.00",
        ],
    );
    let settings_only = gw.file("settings.toml", "[gateway]\nretries = 1\n");
    fails(&tcp, &["restore", &settings_only], 2, &["[backup] missing"]);
    assert_eq!(before, ok(&tcp, &["config", "show"]));
}

// ------------------------------------------------------------------ the review's findings

/// One Modbus TCP request to the gateway: the reply's PDU.
fn modbus(addr: &str, unit: u8, pdu: &[u8]) -> Vec<u8> {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(addr).expect("connect");
    let mut frame = vec![0, 1, 0, 0];
    frame.extend_from_slice(&(pdu.len() as u16 + 1).to_be_bytes());
    frame.push(unit);
    frame.extend_from_slice(pdu);
    s.write_all(&frame).expect("send");
    let mut head = [0u8; 7];
    s.read_exact(&mut head).expect("MBAP header");
    let mut body = vec![0; usize::from(u16::from_be_bytes([head[4], head[5]])) - 1];
    s.read_exact(&mut body).expect("PDU");
    body
}

fn write_register(addr: &str, unit: u8, register: u16, value: u16) -> Vec<u8> {
    let [a, b] = register.to_be_bytes();
    let [c, d] = value.to_be_bytes();
    modbus(addr, unit, &[6, a, b, c, d])
}

fn read_register(addr: &str, unit: u8, register: u16) -> u16 {
    let [a, b] = register.to_be_bytes();
    let r = modbus(addr, unit, &[3, a, b, 0, 1]);
    assert_eq!(r.len(), 4, "{r:?}");
    u16::from_be_bytes([r[2], r[3]])
}

/// Axis 0 (unit 1): servo on, homed, then a direct move to 90 mm at 1 mm/s (minutes).
fn start_slow_move(addr: &str) {
    write_register(addr, 1, 0x0D00, 0x1000);
    std::thread::sleep(std::time::Duration::from_millis(200));
    write_register(addr, 1, 0x0D00, 0x1010);
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while read_register(addr, 1, 0x9F00) != 2 {
        assert!(std::time::Instant::now() < deadline, "homing did not end");
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    let values: [u16; 7] = [0, 9000, 0, 10, 0, 100, 30];
    let mut pdu = vec![0x10, 0x99, 0x00, 0, 7, 14];
    pdu.extend(values.iter().flat_map(|v| v.to_be_bytes()));
    assert_eq!(modbus(addr, 1, &pdu)[0], 0x10);
    while read_register(addr, 1, 0x9007) & 1 << 5 == 0 {
        assert!(
            std::time::Instant::now() < deadline,
            "the move did not start"
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}

/// Finding 1: an APPLY needed while an axis moves writes nothing; `rcgw apply` recovers
/// pending settings; `status` survives a pending AXISBASE.
#[test]
fn apply_waits_for_an_idle_bus_and_rcgw_apply_recovers() {
    let gw = Gateway::with_axes("idle", 3).online();
    let tcp = gw.tcp();
    start_slow_move(&gw.tcp);
    let change = gw.file("change.toml", "[gateway]\nretries = 3\nbus_rtim_ms = 5\n");
    fails(
        &tcp,
        &["config", "apply", &change],
        1,
        &["axis 0 (unit 1) runs a command", "nothing written"],
    );
    let diff = ok(&tcp, &["config", "diff", &change]);
    assert!(diff.contains("bus_rtim_ms: 3 -> 5"), "{diff}");
    assert!(diff.contains("retries: 2 -> 3"), "{diff}");
    fails(
        &tcp,
        &["apply"],
        1,
        &["APPLY not written", "axis 0 (unit 1)"],
    );
    // Stop the move; a pending AXISBASE (written by a PLC, not applied).
    modbus(&gw.tcp, 1, &[5, 0x04, 0x2C, 0xFF, 0x00]);
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
    while read_register(&gw.tcp, 1, 0x9007) & 1 << 5 != 0 {
        assert!(
            std::time::Instant::now() < deadline,
            "the move did not stop"
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    assert_eq!(write_register(&gw.tcp, 63, 0x0020, 10)[0], 6);
    let status = ok(&tcp, &["status"]);
    assert!(status.contains("SETTINGS PENDING"), "{status}");
    assert!(status.contains("rcgw apply"), "{status}");
    let applied = json(&tcp, &["apply"]);
    assert_eq!(
        applied["axis_units"],
        serde_json::json!([10, 11, 12]),
        "{applied}"
    );
    let s = json(&tcp, &["status"]);
    assert_eq!(s["axes"][0]["unit"], 10, "{s}");
    assert_eq!(s["axes"][2]["link"], "online", "{s}");
    assert_eq!(s["pending"], serde_json::json!([]), "{s}");
}

/// Finding 2: UNITID, AXISBASE and the axes enabled written in an order the gateway admits,
/// in two steps with an APPLY between when one does not do.
#[test]
fn unit_base_and_axes_are_written_in_an_order_the_gateway_admits() {
    let gw = Gateway::with_axes("order", 3).online();
    let tcp = gw.tcp();
    let moved = gw.file("moved.toml", "[gateway]\nunit_id = 5\naxis_base = 62\n");
    let j = json(&tcp, &["config", "apply", &moved]);
    assert_eq!(j["applied"], true, "{j}");
    let mut five = gw.tcp();
    five.extend(["--unit".into(), "5".into()]);
    let s = json(&five, &["status"]);
    assert_eq!(s["axes"][2]["unit"], 64, "{s}");
    assert_eq!(s["axes"][2]["link"], "online", "{s}");
    let back = gw.file("back.toml", "[gateway]\nunit_id = 63\naxis_base = 1\n");
    ok(&five, &["config", "apply", &back]);
    let three = gw.file(
        "three.toml",
        "[gateway]\nunit_id = 3\nretries = 1\n[axis.2]\nenabled = false\n",
    );
    let diff = ok(&tcp, &["config", "diff", &three]);
    assert!(
        diff.contains("in two steps: [axis.2] enabled first"),
        "{diff}"
    );
    let j = json(&tcp, &["config", "apply", &three]);
    assert_eq!(j["phases"], 2, "{j}");
    let mut unit3 = gw.tcp();
    unit3.extend(["--unit".into(), "3".into()]);
    let s = json(&unit3, &["status"]);
    assert_eq!(s["axes"].as_array().map(|a| a.len()), Some(2), "{s}");
    assert_eq!(json(&unit3, &["config", "show"])["gateway"]["retries"], 1);
}

/// Findings 3 and 4: rows checked as the position table checks them, before anything is
/// written; backup leaves out the rows restore would refuse.
#[test]
fn rows_are_checked_as_the_position_table_checks_them() {
    let gw = Gateway::start("rows").online();
    let tcp = gw.tcp();
    let b0 = gw.path("b0.toml");
    ok(&tcp, &["backup", &b0]);
    let good = std::fs::read_to_string(&b0).expect("b0");
    let before = ok(&tcp, &["config", "show"]);
    // Rows of an axis the backup does not enable: refused, nothing written.
    let other = good.replace("retries = 0", "retries = 2") + &POINTS.replace("axis.1.", "axis.5.");
    let other = gw.file("other.toml", &other);
    fails(
        &tcp,
        &["restore", &other],
        2,
        &["axis 5 is not enabled", "nothing written"],
    );
    assert_eq!(before, ok(&tcp, &["config", "show"]));
    // An acceleration and a speed the controller cannot hold: skipped and said, the rest
    // restored.
    let wild = good.clone()
        + &POINTS
            .replace("accel_g = 0.20", "accel_g = 5")
            .replace("speed_mm_s = 120.00", "speed_mm_s = 99999");
    let wild = gw.file("wild.toml", &wild);
    fails(
        &tcp,
        &["restore", &wild],
        2,
        &[
            "2 row(s) skipped",
            "axis 1 point 7: not restored",
            "accel_g = 5.00",
            "axis 1 point 2: not restored",
            "speed_mm_s = 99999.00",
        ],
    );
    // Seed point 7 at 80 mm, then reduce the stroke to 50 mm: backup leaves it out, says so,
    // and restore takes the file.
    let seeded = gw.file("seeded.toml", &(good + POINTS));
    ok(&tcp, &["restore", &seeded]);
    let short = gw.file("short.toml", "[axis.1]\nstroke_mm = 50\n");
    ok(&tcp, &["config", "apply", &short]);
    let b1 = gw.path("b1.toml");
    let out = rcgw(&tcp, &["backup", &b1]);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("axis 1 point 7: left out of the backup"),
        "{}",
        text(&out)
    );
    let file = std::fs::read_to_string(&b1).expect("b1");
    assert!(file.contains("# point 7 left out"), "{file}");
    assert!(!file.contains("point = 7"), "{file}");
    ok(&tcp, &["restore", &b1]);
}

/// Finding 5: a backup that enables an axis now disabled: the dry run says the rows are
/// compared after the APPLY; the restore compares them after it.
#[test]
fn restore_enables_an_axis_and_compares_its_rows_after_the_apply() {
    let gw = Gateway::with_axes("enable", 3).online();
    let tcp = gw.tcp();
    let b0 = gw.path("b0.toml");
    ok(&tcp, &["backup", &b0]);
    let seeded = std::fs::read_to_string(&b0).expect("b0") + &POINTS.replace("axis.1.", "axis.2.");
    let seeded = gw.file("seeded.toml", &seeded);
    ok(&tcp, &["restore", &seeded]);
    let b1 = gw.path("b1.toml");
    ok(&tcp, &["backup", &b1]);
    let off = gw.file("off.toml", "[axis.2]\nenabled = false\n");
    ok(&tcp, &["config", "apply", &off]);
    let dry = ok(&tcp, &["restore", &b1, "--dry-run"]);
    assert!(
        dry.contains("axis 2: enabled on APPLY; its 2 row(s) compared after it"),
        "{dry}"
    );
    let report = ok(&gw.rtu(), &["restore", &b1]);
    assert!(
        report.contains("axis 2: 0 point(s) written and verified, 2 unchanged"),
        "{report}"
    );
}

/// Finding 6: a closed pipe on standard output ends the run cleanly.
#[test]
fn a_closed_pipe_ends_status_watch_cleanly() {
    let gw = Gateway::start("pipe");
    let mut child = Command::new(env!("CARGO_BIN_EXE_rcgw"))
        .args(gw.tcp())
        .args(["status", "--watch", "--interval", "0.05", "--count", "1000"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("rcgw");
    let mut lines = BufReader::new(child.stdout.take().expect("stdout"));
    for _ in 0..2 {
        let mut line = String::new();
        lines.read_line(&mut line).expect("a line");
    }
    drop(lines);
    let out = child.wait_with_output().expect("wait");
    assert_eq!(out.status.code(), Some(0), "{}", text(&out));
}

/// Finding 7: values and ranges in the file's units; finding 9: unknown and duplicate keys;
/// finding 8: the reply time-out follows the line rate.
#[test]
fn messages_in_the_files_units_and_keys_checked() {
    let gw = Gateway::start("messages");
    let tcp = gw.tcp();
    let bad = gw.file(
        "units.toml",
        "[gateway]\nbus_baud_bps = -9600\npio_jog_mm_s = 700\nretries = -1\n[axis.1]\nlead_mm = 0\n[axis.01]\nhome = \"far\"\n",
    );
    let out = rcgw(&tcp, &["config", "diff", &bad]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    for says in [
        "bus_baud_bps = -9600: out of range (allowed: 9600, 14400, 19200, 28800, 38400, 57600, 76800, 115200 bit/s)",
        "pio_jog_mm_s = 700: out of range (allowed: 0.01-655.35 mm/s)",
        "retries = -1: out of range (allowed: 0-3)",
        "lead_mm = 0: out of range (allowed: 0.01-655.35 mm)",
        "[axis.01]: write the axis number as [axis.1]",
    ] {
        assert!(stderr.contains(says), "{says:?} not in {}", text(&out));
    }
    assert!(
        !stderr.contains("70000") && !stderr.contains("-96 "),
        "{}",
        text(&out)
    );
    let b = gw.path("b.toml");
    ok(&tcp, &["backup", &b]);
    let good = std::fs::read_to_string(&b).expect("backup");
    let point = gw.file("point.toml", &format!("point = 3\n{good}"));
    fails(&tcp, &["restore", &point], 2, &["unknown key \"point\""]);
    let formt = gw.file(
        "formt.toml",
        &good.replace("format = 1\n", "format = 1\nformt = 2\n"),
    );
    fails(
        &tcp,
        &["restore", &formt],
        2,
        &["[backup] formt: unknown key"],
    );
    let twice = gw.file("twice.toml", &format!("{good}\n[axis.01]\nlead_mm = 12\n"));
    fails(
        &tcp,
        &["restore", &twice],
        2,
        &["[axis.01]: write the axis number as [axis.1]"],
    );
    // 1200 bit/s: a request and its reply of 15 bytes take 137 ms on the line.
    let mut slow = gw.rtu();
    slow.extend(["--baud".into(), "1200".into(), "--unit".into(), "99".into()]);
    fails(&slow, &["status"], 1, &["no reply within 1137 ms"]);
}

/// Finding 10: restore --save --json reports the save; [network] addresses say when they take
/// effect.
#[test]
fn restore_reports_the_save_and_network_changes_say_when() {
    let gw = Gateway::start("save");
    let tcp = gw.tcp();
    let b = gw.path("b.toml");
    ok(&tcp, &["backup", &b]);
    let r = json(&tcp, &["restore", &b, "--save"]);
    assert_eq!(r["saved"], true, "{r}");
    assert!(r["save_count"].as_u64().is_some(), "{r}");
    let net = gw.file(
        "net.toml",
        "[network]\nip_prefix_bits = 16\ntcp_idle_s = 30\n",
    );
    let diff = ok(&tcp, &["config", "diff", &net]);
    assert!(
        diff.contains("[network] ip_prefix_bits: 24 -> 16 (after SAVE and RESTART)"),
        "{diff}"
    );
    assert!(diff.contains("[network] tcp_idle_s: 60 -> 30\n"), "{diff}");
}

#[test]
fn update_sends_an_image_resumes_a_cut_transfer_and_refuses_another_board() {
    let dfu = std::env::temp_dir().join(format!("rcgw-test-dfu-{}.bin", std::process::id()));
    let dfu_path = dfu.to_string_lossy().into_owned();
    let gw = Gateway::with_args(
        "update",
        2,
        &[
            "--dfu",
            &dfu_path,
            "--dfu-size",
            "131072",
            "--board-id",
            "0x0475",
        ],
    );
    let image: Vec<u8> = (0..100_003u32).map(|i| (i * 31 + i / 977) as u8).collect();
    let path = gw.path("image.bin");
    std::fs::write(&path, &image).expect("write image");
    let idle = json(&gw.tcp(), &["update", "--status"]);
    assert_eq!(
        (&idle["state"], &idle["partition"], &idle["board"]),
        (
            &serde_json::json!("idle"),
            &serde_json::json!(131072),
            &serde_json::json!(0x0475)
        )
    );
    // Over RTU, cut off (the process killed) once a fifth of the image is in.
    let mut cut = Command::new(env!("CARGO_BIN_EXE_rcgw"))
        .args(gw.rtu())
        .args(["update", &path, "--board", "0x0475"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("run rcgw");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(20);
    loop {
        let s = json(&gw.tcp(), &["update", "--status"]);
        if s["next"].as_u64().unwrap_or(0) > 20_000 {
            break;
        }
        assert!(std::time::Instant::now() < deadline, "no progress: {s}");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    cut.kill().expect("kill rcgw");
    cut.wait().expect("rcgw ended");
    let s = json(&gw.tcp(), &["update", "--status"]);
    assert_eq!(s["state"], "receiving", "{s}");
    let next = s["next"].as_u64().expect("next");
    assert!(next > 20_000 && next < 100_003, "{s}");
    // Again, over TCP: it goes on from there.
    let done = json(&gw.tcp(), &["update", &path, "--board", "0x0475"]);
    assert_eq!(done["state"], "ready", "{done}");
    assert!(
        done["resumed_at"].as_u64().expect("resumed") >= next,
        "{done}"
    );
    let flash = std::fs::read(&dfu).expect("the partition");
    assert_eq!(flash.len(), 131072);
    assert!(
        flash[..image.len()] == image[..],
        "the image in the partition"
    );
    let mark = std::fs::read_to_string(format!("{dfu_path}.marked")).expect("marked");
    assert_eq!(
        mark.trim(),
        format!("186a3 {}", done["crc32"].as_str().unwrap())
    );
    // The same image again: it is there already, nothing is erased or sent.
    let again = json(&gw.tcp(), &["update", &path, "--board", "0x0475"]);
    assert_eq!(
        (&again["already"], &again["state"], &again["refusals"]),
        (
            &serde_json::json!(true),
            &serde_json::json!("ready"),
            &done["refusals"]
        ),
        "{again}"
    );
    // Another board's image (told before anything is sent), a missing file, an image larger
    // than the partition.
    fails(
        &gw.rtu(),
        &["update", &path, "--board", "0x0429"],
        2,
        &["board 0x0429", "board 0x0475"],
    );
    assert_eq!(json(&gw.tcp(), &["update", "--status"])["state"], "ready");
    fails(
        &gw.tcp(),
        &["update", &gw.path("none.bin"), "--board", "1"],
        2,
        &["none.bin"],
    );
    let large = gw.path("large.bin");
    std::fs::write(&large, vec![0u8; 131073]).expect("write image");
    fails(
        &gw.tcp(),
        &["update", &large, "--board", "0x0475"],
        2,
        &["131073", "131072"],
    );
    let _ = std::fs::remove_file(&dfu);
    let _ = std::fs::remove_file(format!("{dfu_path}.marked"));
}
