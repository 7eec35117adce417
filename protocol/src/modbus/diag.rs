//! FC08 Diagnostics on a serial line (Serial Line §6.1, Application Protocol §6.8): the
//! sub-functions, and the serial-line counters they return.
//!
//! The gateway is one device on the PLC line, whatever unit id a request carries (its own or an
//! axis'): every unit it serves answers FC08, and all of them report the same port counters.
//! The counters count from power-up or the last Restart Communications / Clear Counters, as
//! 16-bit values that wrap (the reply has 16 bits). They are kept as differences from a
//! snapshot of the slave's own (never cleared) [`SlaveCounters`], which the gateway's PLCLINK
//! registers show as they are: one set of counts, two views.
//!
//! | Sub | Name | Counts |
//! |---|---|---|
//! | 0x00 | Return Query Data | (echo) |
//! | 0x01 | Restart Communications Option | clears the counters, leaves Listen Only mode |
//! | 0x02 | Return Diagnostic Register | the unit's status word ([`DataModel::diagnostic_register`](super::DataModel::diagnostic_register)) |
//! | 0x04 | Force Listen Only Mode | no reply; nothing is answered or carried out until 0x01 |
//! | 0x0A | Clear Counters and Diagnostic Register | (the register is live status: nothing to clear) |
//! | 0x0B | Return Bus Message Count | frames with a good CRC, any unit |
//! | 0x0C | Return Bus Communication Error Count | bursts with a bad CRC |
//! | 0x0D | Return Bus Exception Error Count | exception replies sent |
//! | 0x0E | Return Server Message Count | frames to a unit served, or broadcast |
//! | 0x0F | Return Server No Response Count | of those, frames not answered (broadcasts, Listen Only) |
//! | 0x10 | Return Server NAK Count | 0: the gateway never answers NAK (07) |
//! | 0x11 | Return Server Busy Count | 0: busy is exception 04 here, never 06 |
//! | 0x12 | Return Bus Character Overrun Count | bursts longer than a frame (the receive buffer overran) |
//! | 0x14 | Clear Overrun Counter and Flag | |
//!
//! 0x03 (Change ASCII Input Delimiter) is for ASCII mode: like any other sub-function it
//! answers 01. The data field of every sub-function but 0x00 is two bytes: 0x0000, or for 0x01
//! 0x0000 / 0xFF00 (also clear the event log, which this slave does not keep); anything else
//! answers 03.

use super::counters::SlaveCounters;

/// An FC08 sub-function other than Return Query Data.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u16)]
pub enum Diagnostic {
    /// 0x01: clear the counters and leave Listen Only mode (answered first, unless in it).
    RestartCommunications = 0x01,
    /// 0x02: the diagnostic register.
    DiagnosticRegister = 0x02,
    /// 0x04: stop answering until [`Diagnostic::RestartCommunications`].
    ForceListenOnly = 0x04,
    /// 0x0A: clear the counters.
    ClearCounters = 0x0A,
    /// 0x0B.
    BusMessageCount = 0x0B,
    /// 0x0C.
    BusCommunicationErrorCount = 0x0C,
    /// 0x0D.
    BusExceptionErrorCount = 0x0D,
    /// 0x0E.
    ServerMessageCount = 0x0E,
    /// 0x0F.
    ServerNoResponseCount = 0x0F,
    /// 0x10.
    ServerNakCount = 0x10,
    /// 0x11.
    ServerBusyCount = 0x11,
    /// 0x12.
    BusCharacterOverrunCount = 0x12,
    /// 0x14.
    ClearOverrunCounter = 0x14,
}

impl Diagnostic {
    /// Every supported sub-function.
    pub const ALL: [Diagnostic; 13] = [
        Diagnostic::RestartCommunications,
        Diagnostic::DiagnosticRegister,
        Diagnostic::ForceListenOnly,
        Diagnostic::ClearCounters,
        Diagnostic::BusMessageCount,
        Diagnostic::BusCommunicationErrorCount,
        Diagnostic::BusExceptionErrorCount,
        Diagnostic::ServerMessageCount,
        Diagnostic::ServerNoResponseCount,
        Diagnostic::ServerNakCount,
        Diagnostic::ServerBusyCount,
        Diagnostic::BusCharacterOverrunCount,
        Diagnostic::ClearOverrunCounter,
    ];

    /// The sub-function code (the discriminant: no table to look it up in).
    pub const fn code(self) -> u16 {
        self as u16
    }

    /// The sub-function with this code, if supported.
    pub fn from_code(code: u16) -> Option<Diagnostic> {
        Some(match code {
            0x01 => Diagnostic::RestartCommunications,
            0x02 => Diagnostic::DiagnosticRegister,
            0x04 => Diagnostic::ForceListenOnly,
            0x0A => Diagnostic::ClearCounters,
            0x0B => Diagnostic::BusMessageCount,
            0x0C => Diagnostic::BusCommunicationErrorCount,
            0x0D => Diagnostic::BusExceptionErrorCount,
            0x0E => Diagnostic::ServerMessageCount,
            0x0F => Diagnostic::ServerNoResponseCount,
            0x10 => Diagnostic::ServerNakCount,
            0x11 => Diagnostic::ServerBusyCount,
            0x12 => Diagnostic::BusCharacterOverrunCount,
            0x14 => Diagnostic::ClearOverrunCounter,
            _ => return None,
        })
    }

    /// Whether `data` is an allowed data field for it.
    pub const fn accepts(self, data: u16) -> bool {
        match self {
            Diagnostic::RestartCommunications => data == 0x0000 || data == 0xFF00,
            _ => data == 0x0000,
        }
    }
}

/// The serial-line counters of Serial Line §6.1 at one moment, from the slave's counts: bus
/// messages, bus errors, exceptions, server messages, no response, overruns (an array, so
/// that a sub-function's counter is found by its place rather than by a match of its own).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct LineCounts(pub(super) [u32; 6]);

// Where each count is in [`LineCounts`].
const BUS_MESSAGES: usize = 0;
const BUS_ERRORS: usize = 1;
const EXCEPTIONS: usize = 2;
const SERVER_MESSAGES: usize = 3;
const NO_RESPONSE: usize = 4;
/// The overrun count, which FC08 sub-function 0x14 clears alone.
pub(super) const OVERRUNS: usize = 5;

impl LineCounts {
    pub(super) const ZERO: LineCounts = LineCounts([0; 6]);

    pub(super) fn of(c: &SlaveCounters) -> LineCounts {
        // In the order of the places above.
        LineCounts([
            c.frames,
            c.crc_errors,
            c.illegal_function
                .wrapping_add(c.illegal_data_address)
                .wrapping_add(c.illegal_data_value)
                .wrapping_add(c.server_device_failure),
            c.served,
            c.unanswered,
            c.too_long,
        ])
    }

    /// The counter a sub-function returns, counted since `since`.
    pub(super) fn value(&self, since: &LineCounts, sub: Diagnostic) -> Option<u16> {
        let at = match sub {
            Diagnostic::BusMessageCount => BUS_MESSAGES,
            Diagnostic::BusCommunicationErrorCount => BUS_ERRORS,
            Diagnostic::BusExceptionErrorCount => EXCEPTIONS,
            Diagnostic::ServerMessageCount => SERVER_MESSAGES,
            Diagnostic::ServerNoResponseCount => NO_RESPONSE,
            Diagnostic::BusCharacterOverrunCount => OVERRUNS,
            Diagnostic::ServerNakCount | Diagnostic::ServerBusyCount => return Some(0),
            _ => return None,
        };
        let (now, then) = (self.0.get(at)?, since.0.get(at)?);
        Some((now.wrapping_sub(*then) & 0xFFFF) as u16)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `from_code` knows the sub-functions of [`Diagnostic::ALL`], and no other code.
    #[test]
    fn from_code_is_the_inverse_of_code() {
        for code in 0..=u16::MAX {
            let expected = Diagnostic::ALL.into_iter().find(|d| d.code() == code);
            assert_eq!(Diagnostic::from_code(code), expected, "{code:#06x}");
        }
        assert_eq!(Diagnostic::ClearOverrunCounter.code(), 0x14);
    }
}
