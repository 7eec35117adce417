//! The boards' pin choices against what holds a pin at a level no firmware controls: a board's
//! own pull-up beats an input's internal pull-down (the blue pill's USB pull-up on PA12 made an
//! open PC32 input read ON, and every CSTR was refused), and the JTAG pins are pulled up (or
//! down) from reset until the firmware takes them (an output there is ON through every reset).
//! No emulator runs the F103, so the board files themselves are read: every pin given to
//! `input(..)`, `output(..)`, `led(..)`, `indicator_on_fault(..)` or `driver_enable(..)`.

use std::path::Path;

/// The pins of `board` (`src/board/<board>.rs`) passed to the helper `helper`, as "PA12".
fn pins(board: &str, helper: &str) -> Vec<String> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../src/board")
        .join(format!("{board}.rs"));
    let source = std::fs::read_to_string(&path).expect("board file");
    let call = format!("{helper}(p.");
    source
        .match_indices(&call)
        // Not `fn input(` or a longer name that ends like it (`led(` in `indicator_led(`).
        .filter(|(at, _)| {
            !source[..*at]
                .chars()
                .last()
                .is_some_and(|c| c.is_alphanumeric() || c == '_')
        })
        .map(|(at, _)| {
            source[at + call.len()..]
                .chars()
                .take_while(char::is_ascii_alphanumeric)
                .collect()
        })
        .collect()
}

const OUTPUT_HELPERS: [&str; 4] = ["output", "led", "indicator_on_fault", "driver_enable"];

/// Pins held high or low from reset until the firmware configures them: the JTAG/SWD pins of
/// both chips (PA13 JTMS/SWDIO and PA15 JTDI and PB4 NJTRST pulled up, PA14 JTCK/SWCLK pulled
/// down; RM0008 §9.3.5, RM0351 §8.3.1).
const JTAG: [&str; 4] = ["PA13", "PA14", "PA15", "PB4"];

#[test]
fn the_reader_finds_the_boards_pins() {
    // A reader that finds nothing would pass the checks below vacuously.
    // The L475 file also holds the emulator build's IN6-IN9, OUT4, OUT5 and OUT9 (port E).
    for (board, emulator_inputs, emulator_outputs) in [("f103", 0, 0), ("l475", 4, 3)] {
        assert_eq!(
            pins(board, "input").len(),
            12 + emulator_inputs,
            "{board}: 11 PIO inputs and the stop input"
        );
        assert_eq!(
            pins(board, "output").len(),
            11 + emulator_outputs,
            "{board}: 11 PIO outputs"
        );
        let leds = pins(board, "led").len() + pins(board, "indicator_on_fault").len();
        assert_eq!(leds, 3, "{board}: three LEDs");
    }
    assert_eq!(
        pins("f103", "driver_enable").len(),
        2,
        "the F103's two GPIO driver enables"
    );
}

#[test]
fn no_output_led_or_driver_enable_on_a_pin_held_during_reset() {
    for board in ["f103", "l475"] {
        for helper in OUTPUT_HELPERS {
            for pin in pins(board, helper) {
                assert!(
                    !JTAG.contains(&pin.as_str()),
                    "{board}: {helper}({pin}) is held by a JTAG pull during reset"
                );
            }
        }
    }
}

#[test]
fn no_f103_input_on_a_pin_the_board_pulls_up() {
    // The blue pill: PA12 (USB D+) has a 1.5 kOhm pull-up to 3.3 V (R10).
    for pin in pins("f103", "input") {
        assert_ne!(pin, "PA12", "an open input on PA12 reads ON");
    }
    for helper in OUTPUT_HELPERS {
        assert!(
            !pins("f103", helper).contains(&"PA12".to_string()),
            "an output on PA12 would be ON during reset"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// docs/hardware.md's pin tables against the board files' own tables.

/// The pin names in `text` ("PA12"), in order.
fn pin_names(text: &str) -> Vec<String> {
    let bytes = text.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i + 2 < bytes.len() + 1 {
        let boundary = i == 0 || !bytes[i - 1].is_ascii_alphanumeric();
        if boundary
            && bytes[i] == b'P'
            && bytes.get(i + 1).is_some_and(|c| (b'A'..=b'K').contains(c))
        {
            let digits: String = text[i + 2..]
                .chars()
                .take_while(char::is_ascii_digit)
                .collect();
            let end = i + 2 + digits.len();
            let after_ok = bytes.get(end).is_none_or(|c| !c.is_ascii_alphanumeric());
            if !digits.is_empty() && digits.len() <= 2 && after_ok {
                out.push(text[i..end].to_string());
                i = end;
                continue;
            }
        }
        i += 1;
    }
    out
}

/// The signals a table row's first cell names, in order: "IN3", "OUT10", "stop", "bus DE",
/// "PLC TX", "LED alarm". Rows that name none (Ethernet, pins held or unused) give none.
fn signal_keys(cell: &str) -> Vec<String> {
    let cell = cell.replace("**", "");
    let lower = cell.to_lowercase();
    if lower.starts_with("led") {
        let mut found: Vec<(usize, &str)> = ["run", "link", "alarm"]
            .iter()
            .filter_map(|w| lower.find(w).map(|at| (at, *w)))
            .collect();
        found.sort();
        return found.into_iter().map(|(_, w)| format!("LED {w}")).collect();
    }
    if lower.starts_with("rs485") {
        let line = if lower.contains("plc") { "PLC" } else { "bus" };
        let mut found: Vec<(usize, &str)> = ["TX", "RX", "DE"]
            .iter()
            .filter_map(|w| cell.find(w).map(|at| (at, *w)))
            .collect();
        found.sort();
        return found
            .into_iter()
            .map(|(_, w)| format!("{line} {w}"))
            .collect();
    }
    if lower.starts_with("stop input") {
        return vec!["stop".into()];
    }
    // IN/OUT numbers, with ranges "IN0-IN5" expanded.
    let mut keys = Vec::new();
    let words: Vec<&str> = cell.split([' ', ',']).filter(|w| !w.is_empty()).collect();
    for word in words {
        for prefix in ["OUT", "IN"] {
            let Some(rest) = word.strip_prefix(prefix) else {
                continue;
            };
            let (first, last) = match rest.split_once('-') {
                Some((a, b)) => (a, b.trim_start_matches(prefix)),
                None => (rest, rest),
            };
            if let (Ok(a), Ok(b)) = (first.parse::<u8>(), last.parse::<u8>()) {
                keys.extend((a..=b).map(|n| format!("{prefix}{n}")));
            }
            break;
        }
    }
    keys
}

/// Signal -> pin from the rows of a markdown table (`rows`: each row's cells), pairing a row's
/// signals with its pins in order; a row whose counts differ is a problem.
fn pin_map(rows: &[Vec<String>], problems: &mut Vec<String>, what: &str) -> Vec<(String, String)> {
    let mut map = Vec::new();
    for cells in rows {
        let (Some(signal), Some(pins)) = (cells.first(), cells.get(1)) else {
            continue;
        };
        let keys = signal_keys(signal);
        if keys.is_empty() {
            continue;
        }
        let pins = pin_names(pins);
        if keys.len() != pins.len() {
            problems.push(format!(
                "{what}: row '{signal}' names {keys:?} but pins {pins:?}"
            ));
            continue;
        }
        map.extend(keys.into_iter().zip(pins));
    }
    map.sort();
    map
}

fn table_rows(lines: impl Iterator<Item = String>) -> Vec<Vec<String>> {
    lines
        .filter(|l| l.starts_with('|') && !l.starts_with("|---"))
        .map(|l| {
            l.trim_matches('|')
                .split('|')
                .map(|c| c.trim().to_string())
                .collect()
        })
        .collect()
}

/// The L475's pins for IN6-IN9, OUT4, OUT5 and OUT9, set up in its emulator build only (the board
/// routes them to no connector; `src/board/l475.rs`, "Emulator"): not the cabinet's.
const L475_EMULATOR_ONLY: [&str; 7] = ["PE7", "PE8", "PE9", "PE10", "PE11", "PE12", "PE13"];

/// docs/hardware.md's pin table of each board names, for every signal, the pin the board file's
/// own table (the comment at its top, next to the code) gives it: wiring a cabinet from the
/// document is wiring it as the firmware drives it.
#[test]
fn the_documented_pin_tables_match_the_board_files() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let doc = std::fs::read_to_string(root.join("docs/hardware.md")).expect("docs/hardware.md");
    let mut problems = Vec::new();
    for (board, heading) in [
        ("l475", "| Signal (B-L475E-IOT01A) |"),
        ("f103", "| Signal (STM32F103C8) |"),
        ("f429", "| Signal (NUCLEO-F429ZI) |"),
    ] {
        let start = doc
            .find(heading)
            .unwrap_or_else(|| panic!("no table {heading}"));
        let documented = table_rows(
            doc[start..]
                .lines()
                .skip(1)
                .take_while(|l| l.starts_with('|'))
                .map(str::to_string),
        );
        let source =
            std::fs::read_to_string(root.join(format!("src/board/{board}.rs"))).expect("board");
        let coded = table_rows(
            source
                .lines()
                .filter_map(|l| l.strip_prefix("//! "))
                .skip_while(|l| !l.starts_with("| Signal"))
                .skip(1)
                .take_while(|l| l.starts_with('|'))
                .map(str::to_string),
        );
        let doc_map = pin_map(&documented, &mut problems, &format!("hardware.md {board}"));
        let code_map = pin_map(&coded, &mut problems, &format!("src/board/{board}.rs"));
        assert!(
            code_map.len() >= 24,
            "{board}: only {} signals found in the board file's table: the scan is broken",
            code_map.len()
        );
        if doc_map != code_map {
            let only_doc: Vec<_> = doc_map.iter().filter(|p| !code_map.contains(p)).collect();
            let only_code: Vec<_> = code_map.iter().filter(|p| !doc_map.contains(p)).collect();
            problems.push(format!(
                "{board}: hardware.md has {only_doc:?}, the board file {only_code:?}"
            ));
        }
        // Every pin the board's code gives a helper is in the documented table.
        let documented_pins: Vec<String> = documented
            .iter()
            .filter_map(|cells| cells.get(1))
            .flat_map(|c| pin_names(c))
            .collect();
        for helper in ["input", "output", "led", "driver_enable"] {
            for pin in pins(board, helper) {
                let emulator_only = board == "l475" && L475_EMULATOR_ONLY.contains(&pin.as_str());
                if !documented_pins.contains(&pin) && !emulator_only {
                    problems.push(format!("{board}: {pin} ({helper}) not in hardware.md"));
                }
            }
        }
    }
    assert!(problems.is_empty(), "{problems:#?}");
}
