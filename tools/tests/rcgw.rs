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

/// The PLC's pseudo-terminal and the TCP address rc-gateway-host prints when it starts.
fn lines_of(stdout: &mut BufReader<std::process::ChildStdout>) -> (String, String) {
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
    (pty, tcp)
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
        let (pty, tcp) = lines_of(&mut stdout);
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

// ---- Firmware update (issue 37): keys, signing, the transfer, the restart into the new
// firmware, its trial, confirmation and rollback, on rc-gateway-host's board model (--dfu).

/// A scratch directory, removed when dropped.
struct Scratch(PathBuf);

impl Scratch {
    fn new(name: &str) -> Scratch {
        let dir = std::env::temp_dir().join(format!("rcgw-test-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("temp dir");
        Scratch(dir)
    }

    fn path(&self, name: &str) -> String {
        self.0.join(name).to_string_lossy().into_owned()
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// rcgw without a line (key, sign).
fn offline(args: &[&str]) -> Output {
    rcgw(&[], args)
}

/// An application binary of `len` bytes, different for each `seed`.
fn app(len: usize, seed: u32) -> Vec<u8> {
    (0..len as u32)
        .map(|i| (i.wrapping_mul(31 + seed) ^ (i / 977) ^ seed) as u8)
        .collect()
}

/// `bytes` written to `dir/name.app`, signed with the TEST key (or `key`) into `dir/name`:
/// its path.
fn signed(dir: &Scratch, name: &str, bytes: &[u8], version: &str, extra: &[&str]) -> String {
    let app_path = dir.path(&format!("{name}.app"));
    std::fs::write(&app_path, bytes).expect("write app");
    let out = dir.path(name);
    let mut args = vec!["sign", &app_path, "--version", version, "--out", &out];
    if extra.contains(&"--key") {
        // Test bytes, not a firmware holding the key (`key_in_the_firmware_...` checks that).
        args.push("--unchecked");
    } else {
        args.push("--test-key");
    }
    args.extend_from_slice(extra);
    let o = offline(&args);
    assert_eq!(o.status.code(), Some(0), "sign: {}", text(&o));
    out
}

/// rc-gateway-host as a whole board (`--dfu`): two simulated axes, a PTY and a TCP port, and its
/// control lines on a pipe (`restart` without any Modbus request).
struct Board {
    child: Child,
    stdin: std::process::ChildStdin,
    stdout: BufReader<ChildStdout>,
    pty: String,
    tcp: String,
}

impl Board {
    fn start(flash: &str, extra: &[&str]) -> Board {
        let mut child = Command::new(env!("CARGO_BIN_EXE_rc-gateway-host"))
            .args(["--plc-pty", "--modbus-tcp", "127.0.0.1:0", "--sim", "2"])
            .args(["--control", "--watchdog-ms", "0", "--dfu", flash])
            .args(extra)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start rc-gateway-host");
        let stdin = child.stdin.take().expect("stdin");
        let mut stdout = BufReader::new(child.stdout.take().expect("stdout"));
        let (pty, tcp) = lines_of(&mut stdout);
        Board {
            child,
            stdin,
            stdout,
            pty,
            tcp,
        }
    }

    fn rtu(&self) -> Vec<String> {
        vec!["--rtu".into(), self.pty.clone()]
    }

    fn tcp(&self) -> Vec<String> {
        vec!["--tcp".into(), self.tcp.clone()]
    }

    /// A control line and its JSON answer.
    fn control(&mut self, line: &str) -> serde_json::Value {
        use std::io::Write;
        writeln!(self.stdin, "{line}").expect("control line");
        self.stdin.flush().expect("flush");
        let mut answer = String::new();
        self.stdout.read_line(&mut answer).expect("answer");
        serde_json::from_str(&answer).expect("JSON answer")
    }

    /// A restart without a Modbus request (a power cycle, as far as the trial goes).
    fn power_cycle(&mut self) {
        let answer = self.control("restart");
        assert_eq!(answer["ok"], true, "{answer}");
        // The restart is carried out at the end of the pass that read the line.
        std::thread::sleep(std::time::Duration::from_millis(300));
    }

    /// `rcgw update --status --json`.
    fn status(&self) -> serde_json::Value {
        json(&self.tcp(), &["update", "--status"])
    }

    /// (running version, boot state) as `update --status` shows them.
    fn running(&self) -> (String, String) {
        let s = self.status();
        (
            s["running"].as_str().unwrap_or_default().to_string(),
            s["boot"].as_str().unwrap_or_default().to_string(),
        )
    }
}

impl Drop for Board {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// WATCHDOG, register 0x0006.
const WATCHDOG: u16 = 0x0006;

/// The version the host runs with an empty ACTIVE: its built-in one.
const BUILT_IN: &str = env!("CARGO_PKG_VERSION");

fn pair(a: &str, b: &str) -> (String, String) {
    (a.to_string(), b.to_string())
}

#[test]
fn key_new_sign_and_check() {
    let dir = Scratch::new("keys");
    let key = dir.path("release");
    let out = offline(&["key", "new", "--out", &key]);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out));
    let secret = std::fs::read(&key).expect("secret key");
    let public = std::fs::read(format!("{key}.pub")).expect("public key");
    assert_eq!((secret.len(), public.len()), (32, 32));
    let hex: String = public.iter().map(|b| format!("{b:02x}")).collect();
    assert!(
        String::from_utf8_lossy(&out.stdout).contains(&hex),
        "{}",
        text(&out)
    );
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(&key).expect("meta").permissions().mode();
        assert_eq!(mode & 0o777, 0o600, "{mode:o}");
    }
    // Never overwritten.
    let again = offline(&["key", "new", "--out", &key]);
    assert_eq!(again.status.code(), Some(2), "{}", text(&again));
    assert!(String::from_utf8_lossy(&again.stderr).contains("exists"));
    assert_eq!(std::fs::read(&key).expect("secret key"), secret);
    let other = dir.path("other");
    assert_eq!(
        offline(&["key", "new", "--out", &other]).status.code(),
        Some(0)
    );

    let image = signed(&dir, "fw.img", &app(5001, 1), "1.2.3", &["--key", &key]);
    let bytes = std::fs::read(&image).expect("image");
    // The application, 0xFF to a multiple of 8, the 96-byte trailer.
    assert_eq!(bytes.len(), 5008 + 96);
    assert_eq!(&bytes[..5001], &app(5001, 1)[..]);
    assert_eq!(&bytes[5008..5016], b"RCGWIMG1");
    let check = |image: &str, key: &[&str]| {
        let mut args = vec!["sign", "--check", image];
        args.extend_from_slice(key);
        offline(&args)
    };
    let good = check(&image, &["--pub", &format!("{key}.pub")]);
    assert_eq!(good.status.code(), Some(0), "{}", text(&good));
    assert!(
        String::from_utf8_lossy(&good.stdout).contains("version 1.2.3 for board 0x0475"),
        "{}",
        text(&good)
    );
    // Another key, the TEST key: exit 1, said clearly.
    for key in [vec!["--pub", &format!("{other}.pub")], vec!["--test-key"]] {
        let bad = check(&image, &key);
        assert_eq!(bad.status.code(), Some(1), "{}", text(&bad));
        assert!(
            String::from_utf8_lossy(&bad.stderr).contains("does NOT verify"),
            "{}",
            text(&bad)
        );
    }
    // Altered after signing (one bit of the application), or not an image at all.
    let mut altered = bytes.clone();
    altered[100] ^= 1;
    let altered_path = dir.path("altered.img");
    std::fs::write(&altered_path, &altered).expect("write");
    let bad = check(&altered_path, &["--pub", &format!("{key}.pub")]);
    assert_eq!(bad.status.code(), Some(1), "{}", text(&bad));
    let bad = check(&dir.path("fw.img.app"), &["--pub", &format!("{key}.pub")]);
    assert_eq!(bad.status.code(), Some(1), "{}", text(&bad));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("not a signed image"));
    // The TEST key: a loud warning, and its check passes only with the TEST key.
    let app_path = dir.path("fw.img.app");
    let test_img = dir.path("test.img");
    let t = offline(&[
        "sign",
        &app_path,
        "--test-key",
        "--version",
        "0.0.1",
        "--out",
        &test_img,
    ]);
    assert_eq!(t.status.code(), Some(0), "{}", text(&t));
    assert!(String::from_utf8_lossy(&t.stderr).contains("WARNING"));
    assert_eq!(check(&test_img, &["--test-key"]).status.code(), Some(0));
    // Bad input: exit 2.
    for args in [
        vec![
            "sign",
            &app_path,
            "--key",
            &key,
            "--version",
            "1.2",
            "--out",
            &test_img,
        ],
        vec![
            "sign",
            &app_path,
            "--key",
            &app_path,
            "--version",
            "1.2.3",
            "--out",
            &test_img,
        ],
        vec!["sign", "--check", &test_img, "--pub", &app_path],
        vec![
            "sign",
            &image,
            "--key",
            &key,
            "--version",
            "1.2.3",
            "--out",
            &test_img,
        ],
    ] {
        let o = offline(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", text(&o));
    }
}

#[test]
fn update_restart_runs_the_new_version_on_trial_then_confirmed_over_rtu_and_tcp() {
    let dir = Scratch::new("update-restart");
    let flash = dir.path("flash.bin");
    let gw = Board::start(&flash, &[]);
    assert_eq!(gw.running(), pair(BUILT_IN, "confirmed"));
    let idle = gw.status();
    assert_eq!(
        (
            &idle["state"],
            &idle["partition"],
            &idle["board"],
            &idle["marked"]
        ),
        (
            &serde_json::json!("idle"),
            &serde_json::json!(480 * 1024),
            &serde_json::json!(0x0475),
            &serde_json::Value::Null
        ),
        "{idle}"
    );
    // Over RTU: sent, checked and marked; the old version runs until the restart.
    let v1 = signed(&dir, "v1.img", &app(20_001, 1), "1.2.3", &[]);
    let out = ok(&gw.rtu(), &["update", &v1]);
    assert!(out.contains("marked 1.2.3"), "{out}");
    assert!(out.contains("rcgw restart"), "{out}");
    let s = gw.status();
    assert_eq!(
        (&s["state"], &s["marked"]),
        (&serde_json::json!("ready"), &serde_json::json!("1.2.3"))
    );
    assert_eq!(gw.running(), pair(BUILT_IN, "confirmed"));
    // The flash file: the image at DFU's start (0x0808_0000).
    let f = std::fs::read(&flash).expect("flash");
    assert_eq!(f.len(), 1024 * 1024);
    let v1_bytes = std::fs::read(&v1).expect("image");
    assert!(f[0x80000..0x80000 + v1_bytes.len()] == v1_bytes[..]);
    // Restart over RTU: the bootloader swaps it in, on trial; rcgw's reads confirm it.
    let out = ok(&gw.rtu(), &["restart"]);
    assert!(
        out.contains("running 1.2.3, on trial, confirmed now"),
        "{out}"
    );
    assert_eq!(gw.running(), pair("1.2.3", "confirmed"));
    let f = std::fs::read(&flash).expect("flash");
    assert!(
        f[0x8000..0x8000 + v1_bytes.len()] == v1_bytes[..],
        "ACTIVE holds v1"
    );
    // Confirmed: it stays at the next start.
    let again = json(&gw.tcp(), &["restart"]);
    assert_eq!(
        (&again["version"], &again["boot"]),
        (&serde_json::json!("1.2.3"), &serde_json::json!("confirmed")),
        "{again}"
    );
    assert!(again["uptime"].as_u64().expect("uptime") <= 1, "{again}");
    // Over TCP: the next version; restart over TCP (the connection is dropped and made again).
    let v2 = signed(&dir, "v2.img", &app(30_003, 2), "1.3.0", &[]);
    let done = json(&gw.tcp(), &["update", &v2]);
    assert_eq!(
        (&done["state"], &done["marked"]),
        (&serde_json::json!("ready"), &serde_json::json!("1.3.0")),
        "{done}"
    );
    let r = json(&gw.tcp(), &["restart"]);
    assert_eq!(
        (&r["version"], &r["boot"], &r["confirmed"]),
        (
            &serde_json::json!("1.3.0"),
            &serde_json::json!("on trial"),
            &serde_json::json!(true)
        ),
        "{r}"
    );
    assert_eq!(gw.running(), pair("1.3.0", "confirmed"));
    // VERSION itself (register 0x0000) reads the new version: 1.3 and 0.
    let version = modbus(&gw.tcp, 63, &[0x03, 0x00, 0x00, 0x00, 0x02]);
    assert_eq!(&version[..], &[0x03, 0x04, 0x01, 0x03, 0x00, 0x00]);
    // A restart without waiting says only that it was asked.
    let out = ok(&gw.rtu(), &["restart", "--no-wait"]);
    assert!(out.contains("restart requested"), "{out}");
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert_eq!(gw.running(), pair("1.3.0", "confirmed"));
}

#[test]
fn a_trial_never_confirmed_is_rolled_back_to_the_old_version() {
    let dir = Scratch::new("rollback");
    let flash = dir.path("flash.bin");
    let mut gw = Board::start(&flash, &[]);
    let v1 = signed(&dir, "v1.img", &app(12_000, 3), "2.0.0", &[]);
    json(&gw.tcp(), &["update", &v1]);
    // Two restarts with no Modbus request between: the trial never passes.
    gw.power_cycle();
    gw.power_cycle();
    assert_eq!(gw.running(), pair(BUILT_IN, "rolled back"));
    let shown = ok(&gw.tcp(), &["update", "--status"]);
    assert!(
        shown.contains(&format!("running    {BUILT_IN}, rolled back")),
        "{shown}"
    );
    // The old firmware confirmed itself with that read: the next start is a plain one.
    let r = ok(&gw.rtu(), &["restart"]);
    assert!(r.contains(&format!("running {BUILT_IN}, confirmed")), "{r}");
    // It takes an image again, and that one runs.
    let v2 = signed(&dir, "v2.img", &app(12_000, 4), "2.0.1", &[]);
    json(&gw.tcp(), &["update", &v2]);
    let r = ok(&gw.tcp(), &["restart"]);
    assert!(r.contains("running 2.0.1, on trial"), "{r}");
    // A trial whose first request is RESTART rolls back, and rcgw restart says so.
    let v3 = signed(&dir, "v3.img", &app(12_000, 5), "2.1.0", &[]);
    json(&gw.tcp(), &["update", &v3]);
    gw.power_cycle();
    let r = ok(&gw.tcp(), &["restart"]);
    assert!(
        r.contains("running 2.0.1, rolled back: the new image did not confirm"),
        "{r}"
    );
    // During a trial the DFU partition holds the previous firmware: a BEGIN that comes first
    // (no rcgw: a bare FC16) is taken, but its erase is refused (OnTrial).
    let v4 = signed(&dir, "v4.img", &app(12_000, 6), "2.2.0", &[]);
    json(&gw.tcp(), &["update", &v4]);
    gw.power_cycle();
    let mut pdu = vec![0x10, 0x07, 0x00, 0x00, 0x06, 12];
    for word in [1u16, 0, 12_096, 0x1234, 0x5678, 0x0475] {
        pdu.extend_from_slice(&word.to_be_bytes());
    }
    assert_eq!(modbus(&gw.tcp, 63, &pdu)[0], 0x10);
    let s = gw.status();
    assert_eq!(
        (&s["state"], &s["error"], &s["running"]),
        (
            &serde_json::json!("failed"),
            &serde_json::json!(
                "the running firmware is on trial: restart or wait for its confirmation"
            ),
            &serde_json::json!("2.2.0")
        ),
        "{s}"
    );
    // That reply confirmed the trial; the new firmware stays.
    let r = ok(&gw.tcp(), &["restart"]);
    assert!(r.contains("running 2.2.0, confirmed"), "{r}");
}

#[test]
fn refused_images_leave_the_old_version_running() {
    let dir = Scratch::new("refused");
    let flash = dir.path("flash.bin");
    let key = dir.path("release");
    assert_eq!(
        offline(&["key", "new", "--out", &key]).status.code(),
        Some(0)
    );
    // The board verifies with this key, not the TEST key.
    let gw = Board::start(&flash, &["--update-key", &format!("{key}.pub")]);
    let good = signed(&dir, "good.img", &app(9_000, 6), "3.0.0", &["--key", &key]);
    let bytes = std::fs::read(&good).expect("image");
    // Unsigned: refused by rcgw before anything is sent (exit 2).
    let plain = dir.path("plain.bin");
    std::fs::write(&plain, app(9_000, 6)).expect("write");
    fails(
        &gw.rtu(),
        &["update", &plain],
        2,
        &["not a signed image", "rcgw sign"],
    );
    // Truncated (a cut download): no trailer at its end.
    let cut = dir.path("cut.img");
    std::fs::write(&cut, &bytes[..bytes.len() - 10]).expect("write");
    fails(&gw.tcp(), &["update", &cut], 2, &["not a signed image"]);
    // Another board's: named both, nothing sent; --board as a cross-check.
    let other = signed(
        &dir,
        "other.img",
        &app(9_000, 6),
        "3.0.0",
        &["--key", &key, "--board", "0x0429"],
    );
    fails(
        &gw.tcp(),
        &["update", &other],
        2,
        &["board 0x0429", "board 0x0475"],
    );
    fails(
        &gw.tcp(),
        &["update", &good, "--board", "0x0429"],
        2,
        &["0x0429", "0x0475"],
    );
    // Larger than ACTIVE (480 KiB): refused before anything is sent.
    let large = signed(
        &dir,
        "large.img",
        &app(480 * 1024, 7),
        "3.0.0",
        &["--key", &key],
    );
    fails(&gw.tcp(), &["update", &large], 2, &["491616", "491520"]);
    assert_eq!(gw.status()["state"], "idle", "nothing was sent");
    // Signed with the TEST key (another key than the board's): sent, refused at FINISH.
    let test = signed(&dir, "test.img", &app(9_000, 6), "3.0.0", &[]);
    fails(
        &gw.tcp(),
        &["update", &test],
        1,
        &["did not take the image 3.0.0", "signature does not match"],
    );
    let s = gw.status();
    assert_eq!(
        (&s["state"], &s["error"], &s["marked"]),
        (
            &serde_json::json!("failed"),
            &serde_json::json!("the image's signature does not match this firmware's key"),
            &serde_json::Value::Null
        ),
        "{s}"
    );
    let r = ok(&gw.rtu(), &["restart"]);
    assert!(r.contains(&format!("running {BUILT_IN}, confirmed")), "{r}");
    // The good one goes through.
    let done = json(&gw.rtu(), &["update", &good]);
    assert_eq!(done["marked"], "3.0.0", "{done}");
    let r = ok(&gw.tcp(), &["restart"]);
    assert!(r.contains("running 3.0.0, on trial"), "{r}");
}

#[test]
fn a_cut_transfer_leaves_the_old_version_and_resumes() {
    let dir = Scratch::new("cut");
    let flash = dir.path("flash.bin");
    let gw = Board::start(&flash, &[]);
    let image = signed(&dir, "v.img", &app(60_003, 8), "4.5.6", &[]);
    let size = std::fs::read(&image).expect("image").len() as u64;
    // Over RTU, cut off (the process killed) once a fifth of the image is in.
    let cut_at = |gw: &Board| {
        let mut cut = Command::new(env!("CARGO_BIN_EXE_rcgw"))
            .args(gw.rtu())
            .args(["update", &image])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("run rcgw");
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(20);
        loop {
            let s = gw.status();
            if s["next"].as_u64().unwrap_or(0) > size / 5 {
                break;
            }
            assert!(std::time::Instant::now() < deadline, "no progress: {s}");
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        cut.kill().expect("kill rcgw");
        cut.wait().expect("rcgw ended");
        let s = gw.status();
        assert_eq!(s["state"], "receiving", "{s}");
        let next = s["next"].as_u64().expect("next");
        assert!(next > size / 5 && next < size, "{s}");
        next
    };
    // Cut, then a restart: the transfer is forgotten, the old version runs.
    cut_at(&gw);
    let r = ok(&gw.tcp(), &["restart"]);
    assert!(r.contains(&format!("running {BUILT_IN}, confirmed")), "{r}");
    assert_eq!(gw.status()["state"], "idle");
    // Cut again, then resumed over TCP from where it stopped.
    let next = cut_at(&gw);
    let done = json(&gw.tcp(), &["update", &image]);
    assert_eq!(done["state"], "ready", "{done}");
    assert!(
        done["resumed_at"].as_u64().expect("resumed") >= next,
        "{done}"
    );
    // The same image again: it is there already, nothing is erased or sent.
    let again = json(&gw.tcp(), &["update", &image]);
    assert_eq!(
        (&again["already"], &again["state"], &again["refusals"]),
        (
            &serde_json::json!(true),
            &serde_json::json!("ready"),
            &done["refusals"]
        ),
        "{again}"
    );
    // The same application relabelled (same size, same CRC-32 of the file): not "already".
    let relabelled = signed(&dir, "w.img", &app(60_003, 8), "4.5.7", &[]);
    let sent = json(&gw.tcp(), &["update", &relabelled]);
    assert_eq!(
        (&sent["already"], &sent["marked"]),
        (&serde_json::Value::Null, &serde_json::json!("4.5.7")),
        "{sent}"
    );
    let r = ok(&gw.rtu(), &["restart"]);
    assert!(r.contains("running 4.5.7, on trial, confirmed now"), "{r}");
}

#[test]
fn the_host_restart_keeps_the_saved_settings_and_drops_tcp() {
    let dir = Scratch::new("restart-settings");
    let flash = dir.path("flash.bin");
    let gw = Board::start(&flash, &[]);
    // WATCHDOG written and saved, then written again and not saved: a restart starts with the
    // saved value, a factory reset with the defaults (the host's --watchdog-ms 0).
    assert_eq!(
        read_register(&gw.tcp, 63, 0x001A),
        0,
        "RESETCAUSE: power-on"
    );
    write_register(&gw.tcp, 63, WATCHDOG, 500);
    ok(&gw.tcp(), &["save"]);
    write_register(&gw.tcp, 63, WATCHDOG, 700);
    assert_eq!(read_register(&gw.tcp, 63, WATCHDOG), 700);
    // A TCP connection open across the restart is dropped.
    let mut stream = std::net::TcpStream::connect(&gw.tcp).expect("connect");
    let r = ok(&gw.rtu(), &["restart"]);
    assert!(r.contains(&format!("running {BUILT_IN}, confirmed")), "{r}");
    {
        use std::io::Read;
        stream
            .set_read_timeout(Some(std::time::Duration::from_secs(5)))
            .expect("timeout");
        let mut buf = [0u8; 16];
        let n = stream.read(&mut buf).unwrap_or(0);
        assert_eq!(n, 0, "the connection was not dropped");
    }
    assert_eq!(read_register(&gw.tcp, 63, WATCHDOG), 500);
    // RESETCAUSE: software.
    assert_eq!(read_register(&gw.tcp, 63, 0x001A), 2);
    ok(&gw.tcp(), &["factory-reset", "--yes"]);
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert_eq!(read_register(&gw.tcp, 63, WATCHDOG), 0);
}

#[test]
fn restart_fails_when_the_gateway_never_answers_again() {
    use std::io::{Read, Write};
    // A gateway that answers the RESTART write, then is gone (its port closed).
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = listener.local_addr().expect("addr").to_string();
    let server = std::thread::spawn(move || {
        let (mut s, _) = listener.accept().expect("accept");
        let mut request = [0u8; 12];
        s.read_exact(&mut request).expect("request");
        // FC06 at 0x001B (RESTART): echoed.
        assert_eq!(&request[7..10], &[0x06, 0x00, 0x1B], "{request:?}");
        s.write_all(&request).expect("reply");
    });
    let line = vec!["--tcp".to_string(), addr];
    let started = std::time::Instant::now();
    fails(
        &line,
        &["restart", "--wait", "2"],
        1,
        &["did not answer within 2 s"],
    );
    assert!(started.elapsed() < std::time::Duration::from_secs(8));
    server.join().expect("server");
}

#[test]
fn sign_refuses_an_application_that_does_not_hold_the_key() {
    let dir = Scratch::new("sign-key-inside");
    let key = dir.path("release");
    assert_eq!(
        offline(&["key", "new", "--out", &key]).status.code(),
        Some(0)
    );
    let public = std::fs::read(format!("{key}.pub")).expect("public key");
    let secret = std::fs::read(&key).expect("secret key");
    let sign = |name: &str, bytes: &[u8]| {
        let app = dir.path(&format!("{name}.bin"));
        std::fs::write(&app, bytes).expect("write app");
        let out = dir.path(&format!("{name}.img"));
        offline(&[
            "sign",
            &app,
            "--key",
            &key,
            "--version",
            "1.0.0",
            "--out",
            &out,
        ])
    };
    // Built without the key, or with the secret file in its place: refused, nothing written.
    let mut without = app(4000, 7);
    let refused = sign("without", &without);
    assert_eq!(refused.status.code(), Some(2), "{}", text(&refused));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("does not hold"));
    assert!(!std::path::Path::new(&dir.path("without.img")).exists());
    without[1000..1032].copy_from_slice(&secret);
    assert_eq!(sign("secret", &without).status.code(), Some(2));
    // Holding the public half (as a firmware built with RC_GATEWAY_UPDATE_KEY does): signed.
    without[2000..2032].copy_from_slice(&public);
    let ok = sign("with", &without);
    assert_eq!(ok.status.code(), Some(0), "{}", text(&ok));
}

// ---- The same update on an F429 board (`--board-id f429`): its 2 MiB flash, 128 KiB sectors
// for ACTIVE (0x0802_0000) and DFU (0x0812_0000), a 16 KiB STATE sector (0x0810_8000), 4-byte
// words, and images signed `--board f429` of up to 768 KiB.

/// ACTIVE, DFU and STATE of the F429 as offsets in its flash file (rc_boot::layout::F429).
const F429_ACTIVE: usize = 0x2_0000;
const F429_DFU: usize = 0x12_0000;
const F429_STATE: usize = 0x10_8000;
/// The F429's embassy-boot page: one 128 KiB sector.
const F429_SECTOR: usize = 128 * 1024;

#[test]
fn f429_update_restart_runs_the_new_version_on_trial_then_confirmed_over_rtu_and_tcp() {
    let dir = Scratch::new("f429-update-restart");
    let flash = dir.path("flash.bin");
    let gw = Board::start(&flash, &["--board-id", "f429"]);
    assert_eq!(gw.running(), pair(BUILT_IN, "confirmed"));
    let idle = gw.status();
    assert_eq!(
        (&idle["state"], &idle["partition"], &idle["board"]),
        (
            &serde_json::json!("idle"),
            &serde_json::json!(768 * 1024),
            &serde_json::json!(0x0429)
        ),
        "{idle}"
    );
    // The whole 2 MiB, erased.
    let f = std::fs::read(&flash).expect("flash");
    assert_eq!(f.len(), 2 * 1024 * 1024);
    assert!(f.iter().all(|&b| b == 0xFF));
    // Over RTU: sent into DFU, checked and marked in STATE.
    let v1 = signed(
        &dir,
        "v1.img",
        &app(20_001, 11),
        "1.2.3",
        &["--board", "f429"],
    );
    let v1_bytes = std::fs::read(&v1).expect("image");
    let out = ok(&gw.rtu(), &["update", &v1]);
    assert!(out.contains("marked 1.2.3"), "{out}");
    let f = std::fs::read(&flash).expect("flash");
    assert!(
        f[F429_DFU..F429_DFU + v1_bytes.len()] == v1_bytes[..],
        "DFU holds v1"
    );
    // The rest of DFU's first sector is erased, and so is everything outside DFU and STATE.
    assert!(f[F429_DFU + v1_bytes.len()..F429_DFU + F429_SECTOR]
        .iter()
        .all(|&b| b == 0xFF));
    assert!(f[..F429_STATE].iter().all(|&b| b == 0xFF));
    assert!(f[F429_STATE + 16 * 1024..F429_DFU]
        .iter()
        .all(|&b| b == 0xFF));
    assert!(
        f[F429_STATE..F429_STATE + 16].iter().any(|&b| b != 0xFF),
        "the swap mark"
    );
    // Restart over RTU: swapped in, on trial; rcgw's reads confirm it.
    let out = ok(&gw.rtu(), &["restart"]);
    assert!(
        out.contains("running 1.2.3, on trial, confirmed now"),
        "{out}"
    );
    assert_eq!(gw.running(), pair("1.2.3", "confirmed"));
    let f = std::fs::read(&flash).expect("flash");
    assert!(
        f[F429_ACTIVE..F429_ACTIVE + v1_bytes.len()] == v1_bytes[..],
        "ACTIVE holds v1"
    );
    // Over TCP: the next version, its restart over TCP.
    let v2 = signed(
        &dir,
        "v2.img",
        &app(30_003, 12),
        "1.3.0",
        &["--board", "f429"],
    );
    let v2_bytes = std::fs::read(&v2).expect("image");
    let done = json(&gw.tcp(), &["update", &v2]);
    assert_eq!(done["marked"], "1.3.0", "{done}");
    let r = json(&gw.tcp(), &["restart"]);
    assert_eq!(
        (&r["version"], &r["boot"], &r["confirmed"]),
        (
            &serde_json::json!("1.3.0"),
            &serde_json::json!("on trial"),
            &serde_json::json!(true)
        ),
        "{r}"
    );
    assert_eq!(gw.running(), pair("1.3.0", "confirmed"));
    // embassy-boot swapped in 128 KiB pages: v2 in ACTIVE, and v1 (ACTIVE's first sector) kept
    // one whole sector up in DFU, where a revert would take it from.
    let f = std::fs::read(&flash).expect("flash");
    assert!(f[F429_ACTIVE..F429_ACTIVE + v2_bytes.len()] == v2_bytes[..]);
    let kept = F429_DFU + F429_SECTOR;
    assert!(
        f[kept..kept + v1_bytes.len()] == v1_bytes[..],
        "DFU's second sector holds the previous ACTIVE"
    );
    // Confirmed: it stays at the next start.
    let again = json(&gw.rtu(), &["restart"]);
    assert_eq!(
        (&again["version"], &again["boot"]),
        (&serde_json::json!("1.3.0"), &serde_json::json!("confirmed")),
        "{again}"
    );
}

#[test]
fn f429_a_trial_never_confirmed_is_rolled_back_to_the_old_version() {
    let dir = Scratch::new("f429-rollback");
    let flash = dir.path("flash.bin");
    let mut gw = Board::start(&flash, &["--board-id", "0x0429"]);
    let v1 = signed(
        &dir,
        "v1.img",
        &app(12_000, 13),
        "2.0.0",
        &["--board", "f429"],
    );
    json(&gw.rtu(), &["update", &v1]);
    // Two restarts with no Modbus request between: the trial never passes.
    gw.power_cycle();
    gw.power_cycle();
    assert_eq!(gw.running(), pair(BUILT_IN, "rolled back"));
    let f = std::fs::read(&flash).expect("flash");
    assert!(
        f[F429_ACTIVE..F429_ACTIVE + F429_SECTOR]
            .iter()
            .all(|&b| b == 0xFF),
        "ACTIVE back to what it was: erased"
    );
    let r = ok(&gw.rtu(), &["restart"]);
    assert!(r.contains(&format!("running {BUILT_IN}, confirmed")), "{r}");
    // A version that confirms, then one whose trial is cut by a restart: back to the first.
    let v2 = signed(
        &dir,
        "v2.img",
        &app(12_000, 14),
        "2.0.1",
        &["--board", "f429"],
    );
    json(&gw.rtu(), &["update", &v2]);
    let r = ok(&gw.rtu(), &["restart"]);
    assert!(r.contains("running 2.0.1, on trial, confirmed now"), "{r}");
    let v3 = signed(
        &dir,
        "v3.img",
        &app(12_000, 15),
        "2.1.0",
        &["--board", "f429"],
    );
    json(&gw.tcp(), &["update", &v3]);
    gw.power_cycle();
    let r = ok(&gw.rtu(), &["restart"]);
    assert!(
        r.contains("running 2.0.1, rolled back: the new image did not confirm"),
        "{r}"
    );
    let v2_bytes = std::fs::read(&v2).expect("image");
    let f = std::fs::read(&flash).expect("flash");
    assert!(f[F429_ACTIVE..F429_ACTIVE + v2_bytes.len()] == v2_bytes[..]);
}

#[test]
fn an_f429_host_refuses_an_l475_image_before_sending() {
    let dir = Scratch::new("f429-refused");
    let flash = dir.path("flash.bin");
    let gw = Board::start(&flash, &["--board-id", "F429"]);
    // Signed for the L475 (rcgw sign's default board): named both, nothing sent.
    let l475 = signed(&dir, "l475.img", &app(9_000, 16), "3.0.0", &[]);
    fails(
        &gw.rtu(),
        &["update", &l475],
        2,
        &["board 0x0475", "board 0x0429"],
    );
    fails(
        &gw.tcp(),
        &["update", &l475],
        2,
        &["board 0x0475", "board 0x0429"],
    );
    // Larger than the F429's ACTIVE (768 KiB), though it would fit its DFU.
    let large = signed(
        &dir,
        "large.img",
        &app(768 * 1024, 17),
        "3.0.0",
        &["--board", "f429"],
    );
    fails(&gw.rtu(), &["update", &large], 2, &["786528", "786432"]);
    assert_eq!(gw.status()["state"], "idle", "nothing was sent");
    // The F429's own goes through.
    let good = signed(
        &dir,
        "good.img",
        &app(9_000, 16),
        "3.0.0",
        &["--board", "f429"],
    );
    assert_eq!(json(&gw.rtu(), &["update", &good])["marked"], "3.0.0");
    let r = ok(&gw.rtu(), &["restart"]);
    assert!(r.contains("running 3.0.0, on trial"), "{r}");
}

#[test]
fn the_host_refuses_a_board_id_without_a_layout() {
    let dir = Scratch::new("board-unknown");
    let flash = dir.path("flash.bin");
    let out = Command::new(env!("CARGO_BIN_EXE_rc-gateway-host"))
        .args(["--plc-pty", "--sim", "1", "--no-control", "--dfu", &flash])
        .args(["--board-id", "0x1234"])
        .stdin(Stdio::null())
        .output()
        .expect("run rc-gateway-host");
    assert_eq!(out.status.code(), Some(2), "{}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("0x1234") && stderr.contains("l475") && stderr.contains("f429"),
        "{}",
        text(&out)
    );
    assert!(!std::path::Path::new(&flash).exists(), "no flash file made");
    // A file of the other board's size is refused too: the L475's 1 MiB is no F429 flash.
    std::fs::write(&flash, vec![0xFFu8; 1024 * 1024]).expect("write");
    let out = Command::new(env!("CARGO_BIN_EXE_rc-gateway-host"))
        .args(["--plc-pty", "--sim", "1", "--no-control", "--dfu", &flash])
        .args(["--board-id", "f429"])
        .stdin(Stdio::null())
        .output()
        .expect("run rc-gateway-host");
    assert_ne!(out.status.code(), Some(0), "{}", text(&out));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("2097152"),
        "{}",
        text(&out)
    );
}
