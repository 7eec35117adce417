//! `rcframe`: encode and decode IAI Robo Cylinder frames, for people debugging an RS485 bus.
//!
//! It is a thin command line over the `protocol` crate, so what it prints is what the gateway
//! sends and understands.
//!
//! **Encode** any command: the 14 characters between STX and ETX (as the vendor documents print
//! frames), or with `--hex` the 16 bytes on the wire. Values in mm, mm/s and G are converted with
//! `protocol::units` (up to 2 decimals, parsed exactly).
//!
//! ```text
//! $ rcframe encode 0 n
//! 0n000000000082
//! $ rcframe encode C a --mm 56.8 --lead 6 --home motor
//! CaFFFFE26A00F6
//! $ rcframe encode 2 v --mm-s 100 --g 0.2 --lead 2.5
//! 2v22EE001D602F
//! $ rcframe encode 0 h a --mm 100 --lead 10 --home motor --twos
//! 0haFFFFE0C00D7
//! $ rcframe encode 0 R4 --address 7400 --hex
//! 02 30 52 34 30 30 30 30 37 34 30 30 30 38 46 03
//! $ rcframe encode enq
//! 02 05 05 05 05 05 05 05 05 05 05 05 05 05 05 03
//! ```
//!
//! **Decode** one frame into one JSON line (fields by name, status bits, alarm text, the BCC
//! check; the fields are decoded even when the BCC is wrong). Exit status 0 if the frame is
//! valid, 1 if not.
//!
//! ```text
//! $ rcframe decode U0R4FFFF167AFE --lead 12 --home motor
//! {"frame":"U0R4FFFF167AFE","axis":0,"direction":"response","code":"R4",
//!  "value":{"hex":"FFFF167A","decimal":4294907514},"pulses":-59782,"mm":896.72,"bcc_ok":true}
//! $ rcframe decode CmFFFFE26A00F6
//! {..., "code":"m","pulses":-7574,"wire":"FFFFE26A","bcc_ok":false,"bcc_expected":"EA",
//!  "bcc_received":"F6"}
//! ```
//!
//! **Captures**: a hex dump of several frames (argument, `--file`, or `-` for standard input;
//! whitespace, commas, `0x` and `#` comments allowed) goes byte by byte through the gateway's
//! deframer, which resynchronises over noise: one JSON line per packet or rejected candidate,
//! and with `--summary` a final count. Exit status 0 if at least one packet was found and every
//! candidate was valid; 1 otherwise (noise only says so on standard error). An empty capture
//! (no hex bytes at all) is bad input.
//!
//! ```text
//! $ rcframe decode --file capture.txt --summary
//! ```
//!
//! Bad command-line input: a message on standard error and exit status 2.

use clap::{Parser, Subcommand};
use protocol::alarm::AlarmCode;
use rc_tools::rcframe::{decode, encode};
use std::process::ExitCode;

/// Encode and decode IAI Robo Cylinder serial frames, for debugging an RS485 bus.
#[derive(Parser, Debug)]
#[command(name = "rcframe", version)]
struct Cli {
    #[command(subcommand)]
    mode: Mode,
}

#[derive(Subcommand, Debug)]
enum Mode {
    /// Print the frame of a command: `rcframe encode <axis> <command> [options]`
    Encode(encode::EncodeArgs),
    /// Decode a frame or a capture into JSON lines
    Decode(decode::DecodeArgs),
    /// The alarm table (complete edition §8): `rcframe alarm E0` for one code, or every code
    /// 01-FF as JSON lines `{"code":"E0","level":"Error","text":...}` without an argument
    Alarm {
        /// An alarm code in hex (the controller's status reply and ALMC show it).
        code: Option<String>,
    },
}

/// `rcframe alarm [CODE]`.
fn alarm(code: Option<&str>) -> Result<bool, String> {
    let line = |code: AlarmCode| {
        serde_json::json!({
            "code": format!("{:02X}", code.0),
            "level": format!("{:?}", code.level()),
            "text": code.text(),
        })
    };
    match code {
        Some(text) => {
            let code = u8::from_str_radix(text.trim_start_matches("0x"), 16)
                .map_err(|_| format!("{text:?}: an alarm code is hex, 00-FF"))?;
            println!("{}", line(AlarmCode(code)));
        }
        None => {
            for code in 1..=u8::MAX {
                if AlarmCode(code).info().is_some() {
                    println!("{}", line(AlarmCode(code)));
                }
            }
        }
    }
    Ok(true)
}

/// Exit status for bad command-line input, as clap uses.
const USAGE: u8 = 2;

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.mode {
        Mode::Encode(args) => encode::run(args).map(|line| {
            println!("{line}");
            true
        }),
        Mode::Decode(args) => decode::run(args),
        Mode::Alarm { code } => alarm(code.as_deref()),
    };
    match result {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::FAILURE,
        Err(message) => {
            eprintln!("rcframe: {message}");
            ExitCode::from(USAGE)
        }
    }
}
