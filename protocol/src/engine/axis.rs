//! What the engine knows about each axis, and what it has counted.

use super::time::Instant;
use crate::{AlarmCode, Pulses, Rtim, StatusReport, RTIM_AFTER_BREAK};

/// Whether the axis answers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Link {
    /// Not heard from yet.
    Unknown,
    /// Answered its last poll.
    Online,
    /// Did not answer a poll and its retries; probed at a reduced rate.
    Offline,
}

/// How many distinct rejection codes an axis keeps separate counts for; further codes are
/// counted in [`Counters::rejections`] only.
pub const REJECTION_CODES: usize = 6;

/// Counters of one axis (wrapping; they are diagnostics, read by difference).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Counters {
    /// Frames sent to this axis (retries included).
    pub frames_sent: u32,
    /// Valid responses that answered the command sent.
    pub replies: u32,
    /// Commands that got no valid response in time.
    pub timeouts: u32,
    /// Responses with a bad BCC while this axis was addressed.
    pub bcc_errors: u32,
    /// Other malformed or mismatched responses while this axis was addressed.
    pub bad_replies: u32,
    /// Commands resent after a time-out.
    pub retries: u32,
    /// Rejected commands (status bit 7 or memory Func-Num 8-F), all codes.
    pub rejections: u32,
    /// Rejections by warning code: the first [`REJECTION_CODES`] codes seen, with counts.
    pub rejections_by_code: [(AlarmCode, u32); REJECTION_CODES],
}

impl Counters {
    pub(crate) fn count_rejection(&mut self, code: AlarmCode) {
        self.rejections = self.rejections.wrapping_add(1);
        let slot = self
            .rejections_by_code
            .iter_mut()
            .find(|(c, n)| *c == code || *n == 0);
        if let Some(slot) = slot {
            *slot = (code, slot.1.wrapping_add(1));
        }
    }

    /// Rejections counted for `code` (0 if not among the kept codes).
    pub fn rejections_of(&self, code: AlarmCode) -> u32 {
        self.rejections_by_code
            .iter()
            .find(|(c, n)| *c == code && *n > 0)
            .map_or(0, |(_, n)| *n)
    }
}

/// Why the last transaction with an axis failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LinkError {
    /// No valid response (none within Trt, or only corrupted ones), after every allowed retry.
    Timeout,
    /// The controller rejected the command with this warning code.
    Rejected(AlarmCode),
}

/// The engine's picture of one axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisState {
    /// Whether it is configured (polled).
    pub enabled: bool,
    /// Whether it answers.
    pub link: Link,
    /// The last status response (any direct-format reply updates it).
    pub report: Option<StatusReport>,
    /// When `report` was received.
    pub report_at: Option<Instant>,
    /// The last position read (R4 PNOW).
    pub position: Option<Pulses>,
    /// When `position` was received.
    pub position_at: Option<Instant>,
    /// The RTIM the engine believes the axis uses, for its time-outs.
    pub rtim: Rtim,
    /// The last failure.
    pub last_error: Option<LinkError>,
    /// Counters.
    pub counters: Counters,
}

impl AxisState {
    pub(crate) const fn new() -> AxisState {
        AxisState {
            enabled: false,
            link: Link::Unknown,
            report: None,
            report_at: None,
            position: None,
            position_at: None,
            rtim: RTIM_AFTER_BREAK,
            last_error: None,
            counters: Counters {
                frames_sent: 0,
                replies: 0,
                timeouts: 0,
                bcc_errors: 0,
                bad_replies: 0,
                retries: 0,
                rejections: 0,
                rejections_by_code: [(AlarmCode(0), 0); REJECTION_CODES],
            },
        }
    }

    /// Whether the last status shows the axis moving: servo on and positioning not complete.
    pub fn moving(&self) -> bool {
        self.report
            .is_some_and(|r| r.status.servo() && !r.outputs.pfin() && !r.outputs.alarm_active())
    }
}
