//! Faults injected into a running simulation from another thread: what a test or the demo does
//! to the controllers while a real master is connected (a cut wire, an alarm, a power cycle).
//!
//! `rc-sim --control` reads them as lines on standard input ([`Control::parse`]):
//!
//! ```text
//! silent 2 on        axis 2 stops answering (it still hears and executes commands)
//! silent 2 off       it answers again
//! cut 2 on           the wire to axis 2 is cut: it hears nothing and answers nothing, and a
//!                    move it is making goes on (what a master cannot tell from `silent`, but
//!                    what it sends meanwhile is lost: the first frame after the mend is the
//!                    first the axis hears)
//! cut 2 off          the wire is mended
//! alarm 2 E0         axis 2 raises error E0 (80-FF only: 01-7F are warnings, not alarms)
//! power 2 500        axis 2 loses power now, for 500 ms
//! where 2            the log (`--log`) notes axis 2's position, target and motion: the truth a
//!                    test checks the master's view against (nothing changes)
//! ```

use protocol::alarm::{AlarmCode, Level};
use protocol::Axis;

use super::super::bus::Bus;

/// One change to the running bus.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Control {
    /// The axis stops answering (`true`) or answers again.
    Silent(Axis, bool),
    /// The wire to the axis is cut (`true`: it hears nothing, answers nothing and goes on with
    /// what it was doing) or mended.
    Cut(Axis, bool),
    /// The axis raises an error-level alarm.
    Alarm(Axis, AlarmCode),
    /// The axis loses power now for this many milliseconds.
    PowerCycle(Axis, u32),
    /// Nothing changes: the log notes where the axis is ([`Control::report`]).
    Where(Axis),
}

impl Control {
    /// Parse one control line (see the module documentation, `tools/src/sim/realtime/control.rs`).
    pub fn parse(line: &str) -> Result<Control, String> {
        let words: Vec<&str> = line.split_whitespace().collect();
        let axis = |text: Option<&&str>| {
            text.and_then(|t| t.parse::<u8>().ok())
                .and_then(Axis::new)
                .ok_or_else(|| format!("{line:?}: the second word is an axis, 0-15"))
        };
        let on_off = |word: &str| match words.get(2).copied() {
            Some("on") if words.len() == 3 => Ok(true),
            Some("off") if words.len() == 3 => Ok(false),
            _ => Err(format!("{line:?}: {word} AXIS on|off")),
        };
        match words.first().copied() {
            Some("silent") => Ok(Control::Silent(axis(words.get(1))?, on_off("silent")?)),
            Some("cut") => Ok(Control::Cut(axis(words.get(1))?, on_off("cut")?)),
            Some("alarm") => {
                let code = words
                    .get(2)
                    .and_then(|t| u8::from_str_radix(t, 16).ok())
                    .map(AlarmCode)
                    .ok_or_else(|| format!("{line:?}: alarm AXIS CODE (hex, 80-FF)"))?;
                if code.level() != Level::Error {
                    return Err(format!("{line:?}: {code:?} is not an error (80-FF)"));
                }
                Ok(Control::Alarm(axis(words.get(1))?, code))
            }
            Some("power") => {
                let ms = words
                    .get(2)
                    .and_then(|t| t.parse::<u32>().ok())
                    .filter(|&ms| ms > 0)
                    .ok_or_else(|| format!("{line:?}: power AXIS MILLISECONDS"))?;
                Ok(Control::PowerCycle(axis(words.get(1))?, ms))
            }
            Some("where") if words.len() == 2 => Ok(Control::Where(axis(words.get(1))?)),
            _ => Err(format!(
                "{line:?}: expected `silent AXIS on|off`, `cut AXIS on|off`, `alarm AXIS CODE`, \
                 `power AXIS MS` or `where AXIS`"
            )),
        }
    }

    /// The axis it changes.
    pub fn axis(self) -> Axis {
        match self {
            Control::Silent(axis, _)
            | Control::Cut(axis, _)
            | Control::Alarm(axis, _)
            | Control::PowerCycle(axis, _)
            | Control::Where(axis) => axis,
        }
    }

    /// Apply it to `bus`, whose time is now. Fails for an axis that is not on the bus.
    pub fn apply(self, bus: &mut Bus) -> Result<(), String> {
        let axis = self.axis();
        if bus.controller(axis).is_none() {
            return Err(format!("axis {} is not on the bus", axis.get()));
        }
        match self {
            Control::Silent(axis, silent) => bus.set_silent(axis, silent),
            Control::Cut(axis, cut) => bus.set_cut(axis, cut),
            Control::Alarm(axis, code) => bus
                .inject_alarm(axis, code)
                .map_err(|code| format!("{code:?} refused"))?,
            Control::PowerCycle(axis, ms) => {
                let now = bus.now();
                bus.schedule_power_cycle(axis, now, u64::from(ms) * 1_000);
            }
            Control::Where(_) => {}
        }
        Ok(())
    }

    /// What the log notes for it once applied: for [`Control::Where`], the controller's present
    /// position and target (pulses, as PNOW and PCMD read), whether a move or homing runs
    /// and PFIN.
    pub fn report(self, bus: &Bus) -> String {
        match self {
            Control::Where(axis) => match bus.controller(axis) {
                Some(c) => format!(
                    "where: axis {} position {} target {} moving {} homing {} pfin {}",
                    axis.get(),
                    c.position(),
                    c.target(),
                    c.moving(),
                    c.homing(),
                    c.pfin()
                ),
                None => format!("where: axis {} not on the bus", axis.get()),
            },
            other => format!("control: {other:?}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_parse_and_bad_ones_are_refused() {
        let a2 = Axis::new(2).unwrap();
        assert_eq!(Control::parse("silent 2 on"), Ok(Control::Silent(a2, true)));
        assert_eq!(
            Control::parse(" silent 2 off "),
            Ok(Control::Silent(a2, false))
        );
        assert_eq!(
            Control::parse("alarm 2 E0"),
            Ok(Control::Alarm(a2, AlarmCode(0xE0)))
        );
        assert_eq!(
            Control::parse("power 2 500"),
            Ok(Control::PowerCycle(a2, 500))
        );
        assert_eq!(Control::parse("where 2"), Ok(Control::Where(a2)));
        assert_eq!(Control::parse("cut 2 on"), Ok(Control::Cut(a2, true)));
        assert_eq!(Control::parse(" cut  2 off"), Ok(Control::Cut(a2, false)));
        for bad in [
            "",
            "silent 16 on",
            "silent 2",
            "silent 2 on now",
            "cut 2",
            "cut 16 on",
            "cut 2 yes",
            "cut on",
            "cut 2 off 3",
            "alarm 2 41",
            "alarm 2 zz",
            "power 2 0",
            "fly 2",
            "where",
            "where 2 3",
        ] {
            assert!(Control::parse(bad).is_err(), "{bad:?}");
        }
    }
}
