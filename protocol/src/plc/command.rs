//! What the PLC sees of its commands, shared by every part of the gateway: the fate of an
//! axis' last command (CMST/CMER), why one failed, and the PLC-side state of an axis (the
//! registers and coils it wrote, the command CMST shows).

use super::map::DIRECT_MAX;
use super::write::Drg1;
use crate::engine::{JobError, JobId, JobKind};
use crate::time::Instant;
use crate::PositionNo;

/// The fate of an axis' last command, as CMST shows it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CommandState {
    /// No command yet.
    #[default]
    Idle = 0,
    /// Accepted, running.
    Taken = 1,
    /// Finished.
    Done = 2,
    /// Failed; CMER says why.
    Failed = 3,
}

/// Why a command failed: the high byte of CMER (the low byte carries the RC code, if any).
/// The discriminant is the code ([`Reason::code`], [`Reason::from_code`]); [`Reason::text`] says
/// it in words.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Reason {
    /// No failure.
    None = 0,
    /// No valid answer from the axis after the retries.
    Timeout = 1,
    /// An `m` got no answer: it may or may not have moved.
    OutcomeUnknown = 2,
    /// The controller rejected the command (low byte: its warning code).
    Rejected = 3,
    /// The axis went into alarm (low byte: the alarm code).
    Alarm = 4,
    /// The controller answered something else than expected.
    Unexpected = 5,
    /// A stop cancelled it.
    Cancelled = 6,
    /// The read-back differs from what was written.
    VerifyFailed = 7,
    /// The move did not complete within the motion time-out.
    WaitTimeout = 8,
    /// The gateway's job queue was full.
    QueueFull = 9,
    /// Refused: STP/EMG or the stop input is active, no motion may start.
    Paused = 10,
    /// The axis went offline before the command could run; it will not run late.
    Offline = 11,
    /// Refused: FAILSAFE is latched; no motion starts until it is acknowledged.
    Failsafe = 12,
    /// The discrete inputs selected no point the gateway can move to: PC16 or PC32 ON at a
    /// CSTR (pattern 0), or more than one ST input ON (patterns 4 and 5). Low byte: those
    /// inputs (PC1-PC32, or bit n = STn).
    PioInput = 13,
}

impl Reason {
    /// Every reason, in the order of its code (0 to 13): for tools that list or decode them.
    pub const ALL: [Reason; 14] = [
        Reason::None,
        Reason::Timeout,
        Reason::OutcomeUnknown,
        Reason::Rejected,
        Reason::Alarm,
        Reason::Unexpected,
        Reason::Cancelled,
        Reason::VerifyFailed,
        Reason::WaitTimeout,
        Reason::QueueFull,
        Reason::Paused,
        Reason::Offline,
        Reason::Failsafe,
        Reason::PioInput,
    ];

    /// The reason of a CMER value's high byte (`cmer >> 8`), if it is one.
    pub fn from_code(code: u8) -> Option<Reason> {
        Reason::ALL.get(usize::from(code)).copied()
    }

    /// What the reason means, in a few words, for a PLC programmer's or a tool's message
    /// ("" for [`Reason::None`]).
    pub const fn text(self) -> &'static str {
        match self {
            Reason::None => "",
            Reason::Timeout => "no answer from the axis",
            Reason::OutcomeUnknown => "outcome of an incremental move unknown",
            Reason::Rejected => "rejected by the controller",
            Reason::Alarm => "alarm",
            Reason::Unexpected => "unexpected answer",
            Reason::Cancelled => "cancelled by a stop",
            Reason::VerifyFailed => "verify failed",
            Reason::WaitTimeout => "motion time-out",
            Reason::QueueFull => "queue full",
            Reason::Paused => "refused: STP/EMG or the stop input",
            Reason::Offline => "the axis went offline",
            Reason::Failsafe => "refused: FAILSAFE latched",
            Reason::PioInput => "refused: the discrete inputs select no point",
        }
    }

    /// The CMER value: this reason in the high byte, `rc` (a controller code) in the low.
    pub const fn code(self, rc: u8) -> u16 {
        (self as u16) << 8 | rc as u16
    }

    /// The CMER value of a failed job.
    pub fn of(error: JobError) -> u16 {
        match error {
            JobError::Timeout => Reason::Timeout.code(0),
            JobError::OutcomeUnknown => Reason::OutcomeUnknown.code(0),
            JobError::Rejected(c) => Reason::Rejected.code(c.0),
            JobError::Alarm(c) => Reason::Alarm.code(c.0),
            JobError::Unexpected => Reason::Unexpected.code(0),
            JobError::Cancelled => Reason::Cancelled.code(0),
            JobError::VerifyFailed => Reason::VerifyFailed.code(0),
            JobError::WaitTimeout => Reason::WaitTimeout.code(0),
            JobError::Offline => Reason::Offline.code(0),
        }
    }
}

/// How a running command moves the axis: PEND and PM are masked until it is done, as a PCON
/// drops PEND when it accepts a start (the last status may predate the move), and GHMS shows
/// a home.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) enum Motion {
    /// It does not move the axis.
    #[default]
    None,
    /// A move.
    Move,
    /// The homing procedure.
    Home,
}

impl Motion {
    pub(super) fn of(kind: &JobKind) -> Motion {
        match kind {
            JobKind::Home(_) => Motion::Home,
            JobKind::MoveToPoint(..)
            | JobKind::DirectMove { .. }
            | JobKind::Jog { .. }
            | JobKind::MoveAbsolute(_)
            | JobKind::MoveRelative(_) => Motion::Move,
            _ => Motion::None,
        }
    }
}

/// The PLC-side state of one axis.
#[derive(Clone, Copy, Debug)]
pub(super) struct PlcAxis {
    pub(super) drg1: Drg1,
    pub(super) posr: PositionNo,
    pub(super) coil_alrs: bool,
    pub(super) coil_home: bool,
    pub(super) state: CommandState,
    pub(super) reason: u16,
    pub(super) taken: u16,
    /// The job of the command CMST shows, while it runs.
    pub(super) job: Option<JobId>,
    pub(super) motion: Motion,
    /// CMST shows a synchronized start whose moves have not started yet (no job of its own).
    pub(super) sync: bool,
    /// SON is held ON but the servo is off: try again then.
    pub(super) son_retry: Instant,
    /// The last direct move accepted, as written (0x9900 reads it back).
    pub(super) direct: [u16; DIRECT_MAX as usize],
}

impl PlcAxis {
    pub(super) const fn new() -> PlcAxis {
        PlcAxis {
            drg1: Drg1::NONE,
            posr: PositionNo::MIN,
            coil_alrs: false,
            coil_home: false,
            state: CommandState::Idle,
            reason: 0,
            taken: 0,
            job: None,
            motion: Motion::None,
            sync: false,
            son_retry: Instant::ZERO,
            direct: [0; DIRECT_MAX as usize],
        }
    }

    pub(super) fn son(&self) -> bool {
        self.drg1.son()
    }

    pub(super) fn paused(&self) -> bool {
        self.drg1.paused()
    }

    /// A command was taken (CMST 1, CMCT + 1).
    pub(super) fn take(&mut self, job: Option<JobId>, motion: Motion) {
        self.job = job;
        self.motion = motion;
        self.sync = false;
        self.state = CommandState::Taken;
        self.reason = 0;
        self.taken = self.taken.wrapping_add(1);
    }

    /// The command CMST shows failed.
    pub(super) fn fail(&mut self, reason: u16) {
        self.job = None;
        self.motion = Motion::None;
        self.sync = false;
        self.state = CommandState::Failed;
        self.reason = reason;
    }

    /// A motion command is taken and not finished.
    pub(super) fn starting(&self) -> bool {
        self.motion != Motion::None && self.state == CommandState::Taken
    }
}

#[cfg(test)]
mod tests {
    use super::Reason;

    /// `ALL` lists every reason at the index of its own code, so `from_code` decodes what
    /// `code` encodes.
    #[test]
    fn every_reason_decodes_from_its_code() {
        for (i, &reason) in Reason::ALL.iter().enumerate() {
            assert_eq!(reason as usize, i);
            assert_eq!(Reason::from_code(reason as u8), Some(reason));
            assert_eq!(
                Reason::from_code((reason.code(0x85) >> 8) as u8),
                Some(reason)
            );
            assert_eq!(reason.text().is_empty(), reason == Reason::None);
        }
        assert_eq!(Reason::from_code(Reason::ALL.len() as u8), None);
    }
}
