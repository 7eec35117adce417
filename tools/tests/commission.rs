//! `rc-commission` run as a user would, against the simulated controllers on a pseudo-terminal
//! (`rc-sim --pty`) exactly as against a USB-RS485 adapter: scan, establishment, status, servo,
//! homing, moves, jog, stop, alarm reset, the point table to and from files, and the sniffer.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Child, Command, Output, Stdio};
use std::sync::{Mutex, MutexGuard};

use protocol::{Axis, Command as RcCommand, Request};

/// `rc-sim --pty` with `args`, killed when dropped.
struct Sim {
    child: Child,
    pty: String,
    /// One simulator at a time: each test runs two real-time processes over a pseudo-terminal,
    /// and a dozen of them at once on a 2-core host starved the answers past every time-out
    /// (CI: "axis 0: no reply").
    _alone: MutexGuard<'static, ()>,
}

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

impl Sim {
    fn start(args: &[&str]) -> Sim {
        let alone = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let mut child = Command::new(env!("CARGO_BIN_EXE_rc-sim"))
            .arg("--pty")
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start rc-sim");
        let mut first = String::new();
        BufReader::new(child.stdout.take().expect("stdout"))
            .read_line(&mut first)
            .expect("rc-sim's first line");
        let pty = first
            .strip_prefix("PTY ")
            .expect("PTY line")
            .trim()
            .to_string();
        Sim {
            child,
            pty,
            _alone: alone,
        }
    }

    /// `rc-commission --port <pty> <args>`.
    fn run(&self, args: &[&str]) -> Output {
        commission(&[&["--port", &self.pty], args].concat())
    }
}

impl Drop for Sim {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn commission(args: &[&str]) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_rc-commission"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start rc-commission");
    // Bounded: every command ends by itself (time-outs of its own); this only guards the test.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
    while child.try_wait().expect("wait").is_none() {
        assert!(
            std::time::Instant::now() < deadline,
            "rc-commission {args:?} hangs"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.wait_with_output().expect("output")
}

fn stdout(out: &Output) -> String {
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Exited with `code`, saying `text` on standard error.
fn fails_with(out: &Output, code: i32, text: &str) {
    assert_eq!(out.status.code(), Some(code), "{}", stderr(out));
    assert!(stderr(out).contains(text), "{}", stderr(out));
}

/// Succeeds, and returns standard output.
fn ok(out: Output) -> String {
    assert_eq!(
        out.status.code(),
        Some(0),
        "stdout: {}\nstderr: {}",
        stdout(&out),
        stderr(&out)
    );
    stdout(&out)
}

/// The options of a commissioned axis on rc-sim: its rate and RTIM, the simulated actuator's
/// lead (8 mm) and motor-end homing with exact negation.
const AXIS: [&str; 10] = [
    "--baud",
    "38400",
    "--rtim",
    "3",
    "--lead",
    "8",
    "--home",
    "motor",
    "--twos",
    "--ppr=800",
];

fn with_axis<'a>(args: &[&'a str]) -> Vec<&'a str> {
    [&AXIS[..], args].concat()
}

#[test]
fn scan_finds_exactly_the_axes_there_at_their_rate() {
    let sim = Sim::start(&["--axes", "0,2", "--baud", "38400", "--rtim", "3"]);
    let out = ok(sim.run(&["--rtim", "3", "scan", "--rates", "9600,38400,115200"]));
    let found: Vec<(String, String)> = out
        .lines()
        .skip(1)
        .map(|l| {
            let mut words = l.split_whitespace();
            (
                words.next().unwrap_or("").to_string(),
                words.next().unwrap_or("").to_string(),
            )
        })
        .collect();
    assert_eq!(
        found,
        [("0".into(), "38400".into()), ("2".into(), "38400".into())],
        "{out}"
    );
    // Nobody at a rate nobody runs: a failure with a hint.
    let none = sim.run(&["--rtim", "3", "scan", "--rates", "9600"]);
    fails_with(&none, 1, "no axis answered");
}

#[test]
fn establishment_moves_the_axes_to_the_new_rate() {
    // Controllers at their power-up rate; the PTY carries no break: rc-sim takes the switch to
    // 9600 bit/s followed by silence for one.
    let sim = Sim::start(&[
        "--axes",
        "0,1",
        "--baud",
        "9600",
        "--rtim",
        "3",
        "--slow-baud-is-break",
    ]);
    let out = ok(sim.run(&[
        "--baud",
        "9600",
        "establish",
        "--to",
        "115200",
        "--axes",
        "0,1",
    ]));
    assert!(out.contains("axis  0: at 115200 bit/s"), "{out}");
    assert!(out.contains("axis  1: at 115200 bit/s"), "{out}");
    let status = ok(sim.run(&["--baud", "115200", "--rtim", "3", "status", "1"]));
    assert!(status.contains("axis 1 at 115200 bit/s"), "{status}");
    let old = sim.run(&["--baud", "9600", "--rtim", "3", "status", "1"]);
    assert_eq!(old.status.code(), Some(1), "nobody left at 9600 bit/s");
    assert!(
        stderr(&old).contains("no reply at 9600 bit/s"),
        "{}",
        stderr(&old)
    );
}

fn position_mm(status: &str) -> f64 {
    let at = status.find("position ").expect("position") + "position ".len();
    status[at..]
        .split_whitespace()
        .next()
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no position in {status}"))
}

#[test]
fn servo_home_move_jog_and_stop() {
    let sim = Sim::start(&["--axes", "0,", "--baud", "38400", "--rtim", "3"]);
    let off = ok(sim.run(&with_axis(&["servo", "0", "off"])));
    assert!(off.contains("servo off"), "{off}");
    ok(sim.run(&with_axis(&["servo", "0", "on"])));
    let homed = ok(sim.run(&with_axis(&["home", "0"])));
    assert!(homed.contains("homed, in position"), "{homed}");
    assert_eq!(position_mm(&homed), 0.0);
    let moved = ok(sim.run(&with_axis(&["move", "0", "--mm", "25.5"])));
    assert_eq!(position_mm(&moved), 25.5, "{moved}");
    let fast = ok(sim.run(&with_axis(&[
        "move", "0", "--mm", "40", "--speed", "200", "--accel", "0.5",
    ])));
    assert_eq!(position_mm(&fast), 40.0, "{fast}");
    let jogged = ok(sim.run(&with_axis(&["jog", "0", "-5"])));
    assert_eq!(position_mm(&jogged), 35.0, "{jogged}");
    let stopped = ok(sim.run(&with_axis(&["stop", "0"])));
    assert_eq!(position_mm(&stopped), 35.0, "a stop at rest moves nothing");
    // Beyond what a frame can carry: refused before anything is sent. (Within it, the
    // controller's soft limits hold the axis inside its stroke.)
    let far = sim.run(&with_axis(&["move", "0", "--mm", "-50000000"]));
    assert_eq!(far.status.code(), Some(1), "{}", stdout(&far));
    assert!(stderr(&far).contains("out of range"), "{}", stderr(&far));
}

#[test]
fn an_alarm_is_reported_in_words_and_reset() {
    let sim = Sim::start(&["--axes", "0,", "--baud", "38400", "--rtim", "3"]);
    ok(sim.run(&with_axis(&["home", "0"])));
    // Point 9 was never written: the controller answers the move with alarm B1.
    let refused = sim.run(&with_axis(&["move", "0", "--point", "9"]));
    fails_with(&refused, 1, "alarm B1");
    let status = ok(sim.run(&with_axis(&["status", "0"])));
    assert!(status.contains("alarm B1"), "{status}");
    let reset = ok(sim.run(&with_axis(&["alarm-reset", "0"])));
    assert!(reset.contains("no alarm"), "{reset}");
}

fn temp(name: &str, content: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("rc-commission-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let path = dir.join(name);
    std::fs::write(&path, content).expect("write");
    path
}

#[test]
fn point_table_from_a_file_with_a_dry_run_first_then_back_to_a_file() {
    let sim = Sim::start(&["--axes", "0,", "--baud", "38400", "--rtim", "3"]);
    let table = "\
[[point]]
point = 1
position_mm = 10.0
speed_mm_s = 100.0
accel_g = 0.3
band_mm = 0.1

[[point]]
point = 2
position_mm = 30.0
speed_mm_s = 50.0
accel_g = 0.2
band_mm = 0.1
";
    let file = temp("table.toml", table);
    let file = file.to_str().expect("path");
    let dry = ok(sim.run(&with_axis(&[
        "points",
        "write",
        "0",
        "--file",
        file,
        "--dry-run",
    ])));
    assert!(dry.contains("~ point  1: empty -> 10.00 mm"), "{dry}");
    assert!(dry.contains("2 of 2 points would be stored"), "{dry}");
    let empty = ok(sim.run(&with_axis(&["points", "read", "0"])));
    assert_eq!(
        empty.lines().count(),
        1,
        "the dry run wrote nothing: {empty}"
    );

    let written = ok(sim.run(&with_axis(&["points", "write", "0", "--file", file])));
    assert!(
        written.contains("2 of 2 points stored and verified"),
        "{written}"
    );
    let again = ok(sim.run(&with_axis(&["points", "write", "0", "--file", file])));
    assert!(
        again.contains("0 of 2 points stored"),
        "nothing rewritten: {again}"
    );

    let csv = temp("back.csv", "");
    let csv = csv.to_str().expect("path");
    ok(sim.run(&with_axis(&["points", "read", "0", "--file", csv])));
    assert_eq!(
        std::fs::read_to_string(csv).expect("read"),
        "point,position_mm,speed_mm_s,accel_g,band_mm\n\
         1,10.00,100.00,0.30,0.10\n\
         2,30.00,50.00,0.20,0.10\n"
    );
    // The CSV read back is a valid input, and changes nothing.
    let same = ok(sim.run(&with_axis(&["points", "write", "0", "--file", csv])));
    assert!(same.contains("0 of 2 points stored"), "{same}");
    let moved = ok(sim.run(&with_axis(&["move", "0", "--point", "2"])));
    assert_eq!(position_mm(&moved), 30.0, "{moved}");

    let bad = temp(
        "bad.csv",
        "point,position_mm,speed_mm_s,accel_g,band_mm\n1,10,x,0.3,0.1\n",
    );
    let out = points_write(&sim, &bad, &[]);
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr(&out).contains("bad.csv:2"), "{}", stderr(&out));
}

#[test]
fn sniff_decodes_what_is_on_the_line() {
    let (master, _slave, path) = rc_tools::pty::open_raw(None).expect("pty");
    let path = path.to_str().expect("path").to_string();
    let sniffer = std::thread::spawn(move || {
        commission(&[
            "--port",
            &path,
            "--baud",
            "9600",
            "sniff",
            "--seconds",
            "1.5",
        ])
    });
    std::thread::sleep(std::time::Duration::from_millis(400));
    let request = Request::new(Axis::new(3).expect("axis"), RcCommand::Status);
    let mut line = std::fs::File::from(std::os::fd::OwnedFd::from(master));
    line.write_all(&request.emit().to_bytes()).expect("write");
    line.write_all(b"noise").expect("write");
    line.write_all(&request.emit().to_bytes()).expect("write");
    let out = ok(sniffer.join().expect("sniffer"));
    let frames: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).expect("JSON line"))
        .collect();
    let requests = frames
        .iter()
        .filter(|f| f.to_string().contains("\"axis\":3"))
        .count();
    assert_eq!(requests, 2, "{out}");
}

#[test]
fn an_absent_axis_is_a_clear_error() {
    let sim = Sim::start(&["--axes", "0,", "--baud", "38400", "--rtim", "3"]);
    let out = sim.run(&with_axis(&["status", "5"]));
    fails_with(&out, 1, "axis 5: no reply at 38400 bit/s");
}

/// `points write` with `file`, failing: standard error.
/// `points write 0 --file FILE EXTRA...` on axis 0 of `sim`.
fn points_write(sim: &Sim, file: &std::path::Path, extra: &[&str]) -> Output {
    let file = file.to_str().expect("path");
    sim.run(&with_axis(
        &[&["points", "write", "0", "--file", file][..], extra].concat(),
    ))
}

fn refused(sim: &Sim, file: &std::path::Path, extra: &[&str]) -> String {
    let out = points_write(sim, file, extra);
    assert_eq!(out.status.code(), Some(1), "{}", stdout(&out));
    stderr(&out)
}

#[test]
fn rows_the_controller_would_lose_or_clamp_are_refused_and_nothing_is_written() {
    // rc-sim's axis: 100 mm stroke, soft limits at the stroke.
    let sim = Sim::start(&["--axes", "0,", "--baud", "38400", "--rtim", "3"]);
    let table = temp(
        "lossy.csv",
        "point,position_mm,speed_mm_s,accel_g,band_mm\n\
         1,10,100,0.3,0.1\n\
         2,20,0,0.3,0.1\n\
         3,-5,100,0.3,0.1\n\
         4,500,100,0.3,0.1\n\
         5,30,100,0,0.1\n",
    );
    let err = refused(&sim, &table, &[]);
    assert!(err.contains("nothing written: 4 of 5 rows"), "{err}");
    assert!(
        err.contains("lossy.csv:3: point 2: speed 0 mm/s"),
        "the row and the reason: {err}"
    );
    assert!(
        err.contains("lossy.csv:4: point 3: position -5.00 mm: behind the home end"),
        "{err}"
    );
    assert!(
        err.contains(
            "lossy.csv:5: point 4: position 500.00 mm: beyond the controller's soft limit"
        ),
        "{err}"
    );
    assert!(
        err.contains("lossy.csv:6: point 5: acceleration 0.00 G"),
        "{err}"
    );
    assert!(!err.contains("point 1:"), "row 1 is fine: {err}");
    let table_now = ok(sim.run(&with_axis(&["points", "read", "0"])));
    assert_eq!(
        table_now.lines().count(),
        1,
        "not even the good row was written: {table_now}"
    );

    // Within the soft limits but beyond the stroke declared: refused as well; the same rows
    // in TOML name their lines too.
    let short = temp(
        "short.toml",
        "[[point]]\npoint = 1\nposition_mm = 10.0\nspeed_mm_s = 100.0\naccel_g = 0.3\nband_mm = 0.1\n\n\
         [[point]]\npoint = 2\nposition_mm = 60.0\nspeed_mm_s = 100.0\naccel_g = 0.3\nband_mm = 0.1\n",
    );
    let err = refused(&sim, &short, &["--stroke", "50"]);
    assert!(
        err.contains("short.toml:8: point 2: position 60.00 mm: beyond the stroke, 50.00 mm"),
        "{err}"
    );
    let negative = points_write(&sim, &short, &["--stroke", "-3"]);
    assert_eq!(negative.status.code(), Some(2), "bad input");
    assert!(
        stderr(&negative).contains("`-3`: a stroke is a length, more than 0 mm"),
        "{}",
        stderr(&negative)
    );
    let fine = ok(points_write(&sim, &short, &["--stroke", "100"]));
    assert!(fine.contains("2 of 2 points stored and verified"), "{fine}");
}

#[test]
fn a_bad_file_is_reported_without_a_bus() {
    let table = temp(
        "offline.csv",
        "point,position_mm,speed_mm_s,accel_g,band_mm\n1,10,0,0.3,0.1\n",
    );
    let out = commission(&with_axis(&[
        "--port",
        "/nonexistent/tty",
        "points",
        "write",
        "0",
        "--file",
        table.to_str().expect("path"),
    ]));
    fails_with(&out, 1, "offline.csv:2: point 1: speed 0 mm/s");
}

#[test]
fn csv_columns_are_read_by_their_header_in_any_order() {
    let sim = Sim::start(&["--axes", "0,", "--baud", "38400", "--rtim", "3"]);
    let table = temp(
        "reordered.csv",
        "speed_mm_s, point ,band_mm,position_mm,accel_g\n100,4,0.1,12.5,0.3\n",
    );
    let written = ok(points_write(&sim, &table, &[]));
    assert!(
        written.contains("~ point  4: empty -> 12.50 mm at 100.00 mm/s, 0.30 G, band 0.10 mm"),
        "{written}"
    );
    let back = ok(sim.run(&with_axis(&["points", "read", "0"])));
    assert_eq!(
        back,
        "point,position_mm,speed_mm_s,accel_g,band_mm\n4,12.50,100.00,0.30,0.10\n"
    );

    for (name, content, expected) in [
        (
            "unknown.csv",
            "point,position_mm,speed,accel_g,band_mm\n1,10,100,0.3,0.1\n",
            "unknown.csv:1: unknown column `speed`",
        ),
        (
            "missing.csv",
            "point,position_mm,accel_g,band_mm\n1,10,0.3,0.1\n",
            "missing.csv:1: no column `speed_mm_s`",
        ),
        (
            "headerless.csv",
            "1,10,100,0.3,0.1\n",
            "headerless.csv:1: the first line must be the header",
        ),
        (
            "short_row.csv",
            "point,position_mm,speed_mm_s,accel_g,band_mm\n1,10,100,0.3\n",
            "short_row.csv:2: 4 fields, the header has 5",
        ),
        (
            "decimals.csv",
            "point,position_mm,speed_mm_s,accel_g,band_mm\n1,10.005,100,0.3,0.1\n",
            "decimals.csv:2: position_mm: `10.005` has more than 2 decimals",
        ),
    ] {
        let err = refused(&sim, &temp(name, content), &[]);
        assert!(err.contains(expected), "{name}: {err}");
    }
}

#[test]
fn unknown_toml_keys_are_refused_by_name() {
    let sim = Sim::start(&["--axes", "0,", "--baud", "38400", "--rtim", "3"]);
    let typo = temp(
        "typo.toml",
        "[[point]]\npoint = 1\nposition_mm = 10.0\nspeed_mm_s = 100.0\naccel_g = 0.3\nband_mm = 0.1\nspeed = 50.0\n",
    );
    let err = refused(&sim, &typo, &[]);
    assert!(err.contains("typo.toml"), "{err}");
    assert!(err.contains("unknown field `speed`"), "{err}");
    let top = temp("top.toml", "axis = 0\n[[point]]\npoint = 1\nposition_mm = 10.0\nspeed_mm_s = 100.0\naccel_g = 0.3\nband_mm = 0.1\n");
    let err = refused(&sim, &top, &[]);
    assert!(err.contains("unknown field `axis`"), "{err}");
    let empty = ok(sim.run(&with_axis(&["points", "read", "0"])));
    assert_eq!(empty.lines().count(), 1, "nothing written: {empty}");
}

#[test]
fn a_port_that_is_not_a_serial_port_and_a_negative_lead_are_explained() {
    let out = commission(&["--port", "/dev/null", "status", "0"]);
    fails_with(&out, 1, "/dev/null: not a serial port");
    let out = commission(&["--port", "/dev/null", "--lead", "-3", "status", "0"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("lead `-3` must be between 0.01 and 655.35 mm"),
        "not 'unexpected argument': {}",
        stderr(&out)
    );
    let out = commission(&[
        "--port",
        "/dev/null",
        "--lead",
        "8",
        "--home",
        "motor",
        "move",
        "0",
        "--mm",
        "5",
        "--speed",
        "-5",
    ]);
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr(&out).contains("must be >= 0"), "{}", stderr(&out));
}
