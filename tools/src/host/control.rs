//! Control lines read on standard input: each one gets exactly one JSON line on standard output.

use protocol::alarm::AlarmCode;
use protocol::Axis;

/// One control line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Control {
    /// `alarm <axis> <hex code>`: raise an alarm (80-FF) on a simulated axis.
    Alarm(Axis, AlarmCode),
    /// `stats`: counters and the state of every axis.
    Stats,
    /// `stop-input on|off`: the gateway's stop input (as the PIO *STP safety input).
    StopInput(bool),
    /// `restart`: restart the gateway as a reset does (the bootloader runs; no Modbus request
    /// needed, so a trial can be left unconfirmed).
    Restart,
    /// `quit`: end the run.
    Quit,
    /// `help`: the list of commands.
    Help,
}

/// What `help` answers.
pub const HELP: &str =
    "alarm <axis> <hex code> | stats | stop-input on|off | restart | quit | help";

/// Read one line (surrounding blanks ignored); `None` for an empty line.
pub fn parse(line: &str) -> Option<Result<Control, String>> {
    let mut words = line.split_whitespace();
    let command = words.next()?;
    let args: Vec<&str> = words.collect();
    Some(match (command, args.as_slice()) {
        ("alarm", [axis, code]) => parse_alarm(axis, code),
        ("stats", []) => Ok(Control::Stats),
        ("stop-input", ["on" | "1"]) => Ok(Control::StopInput(true)),
        ("stop-input", ["off" | "0"]) => Ok(Control::StopInput(false)),
        ("restart", []) => Ok(Control::Restart),
        ("quit" | "exit", []) => Ok(Control::Quit),
        ("help", []) => Ok(Control::Help),
        _ => Err(format!("{:?}: expected {HELP}", line.trim())),
    })
}

fn parse_alarm(axis: &str, code: &str) -> Result<Control, String> {
    let axis = axis
        .parse::<u8>()
        .ok()
        .and_then(Axis::new)
        .ok_or_else(|| format!("{axis:?}: an axis is 0-15"))?;
    let digits = code.trim_start_matches("0x").trim_start_matches("0X");
    let code = u8::from_str_radix(digits, 16)
        .map_err(|_| format!("{code:?}: a hexadecimal alarm code such as D8"))?;
    Ok(Control::Alarm(axis, AlarmCode(code)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines() {
        assert_eq!(
            parse("alarm 0 D8"),
            Some(Ok(Control::Alarm(Axis::new(0).unwrap(), AlarmCode(0xD8))))
        );
        assert_eq!(
            parse(" alarm 2 0xb1 "),
            Some(Ok(Control::Alarm(Axis::new(2).unwrap(), AlarmCode(0xB1))))
        );
        assert_eq!(parse("stats"), Some(Ok(Control::Stats)));
        assert_eq!(parse("stop-input on"), Some(Ok(Control::StopInput(true))));
        assert_eq!(parse("quit"), Some(Ok(Control::Quit)));
        assert_eq!(parse("restart"), Some(Ok(Control::Restart)));
        assert_eq!(parse("   "), None);
        assert!(matches!(parse("alarm 16 D8"), Some(Err(_))));
        assert!(matches!(parse("alarm 0 XY"), Some(Err(_))));
        assert!(matches!(parse("stats now"), Some(Err(_))));
    }
}
