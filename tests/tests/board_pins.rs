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
