//! `rc-gateway-host`'s command line, run as a user would: what it says about bad input (the
//! runs themselves are tested with Modbus masters in scripts/e2e.sh and scripts/interop.sh).

use std::process::{Command, Output, Stdio};

fn gateway(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_rc-gateway-host"))
        .args(args)
        .stdin(Stdio::null())
        .output()
        .expect("run rc-gateway-host")
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Exited with `code`, saying `text` on standard error.
fn fails_with(out: &Output, code: i32, text: &str) {
    assert_eq!(out.status.code(), Some(code), "{}", stderr(out));
    assert!(stderr(out).contains(text), "{}", stderr(out));
}

#[test]
fn a_device_that_is_not_a_serial_port_is_named() {
    for args in [
        &["--plc-pty", "--bus", "/dev/null", "--no-control"][..],
        &["--plc", "/dev/null", "--sim", "1", "--no-control"][..],
    ] {
        let out = gateway(args);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {}", stderr(&out));
        assert!(
            stderr(&out).contains("/dev/null: not a serial port"),
            "{args:?}: {}",
            stderr(&out)
        );
    }
    let out = gateway(&["--plc-pty", "--bus", "/nonexistent/ttyUSB9", "--no-control"]);
    fails_with(&out, 1, "/nonexistent/ttyUSB9: ");
}

#[test]
fn a_negative_lead_or_stroke_is_refused_with_a_reason() {
    for flag in ["--lead-mm", "--stroke-mm"] {
        let out = gateway(&["--plc-pty", "--sim", "1", "--no-control", flag, "-3"]);
        assert_eq!(out.status.code(), Some(2), "{flag}");
        assert!(
            stderr(&out).contains("\"-3\": a lead or stroke is a length, more than 0 mm"),
            "{flag}: {}",
            stderr(&out)
        );
    }
}

#[test]
fn the_unit_range_is_that_of_modbus() {
    for unit in ["0", "248", "300"] {
        let out = gateway(&["--plc-pty", "--sim", "1", "--no-control", "--unit", unit]);
        assert_eq!(out.status.code(), Some(2), "{unit}");
        assert!(
            stderr(&out).contains("a Modbus unit id is 1-247"),
            "{unit}: {}",
            stderr(&out)
        );
        assert!(!stderr(&out).contains("0..=255"), "{}", stderr(&out));
    }
}
