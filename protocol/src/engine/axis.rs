//! What the engine knows about each axis, and what it has counted.

use crate::time::Instant;
use crate::{AlarmCode, Pulses, Rtim, StatusReport};

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
    /// Rejected commands (status bit 7 or memory Func-Num 8-F); the last code is in
    /// [`AxisState::last_error`].
    pub rejections: u32,
}

impl Counters {
    const ZERO: Counters = Counters {
        frames_sent: 0,
        replies: 0,
        timeouts: 0,
        bcc_errors: 0,
        bad_replies: 0,
        retries: 0,
        rejections: 0,
    };
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
    /// An axis not heard from yet, believed to answer after `rtim`.
    pub(crate) const fn new(rtim: Rtim) -> AxisState {
        AxisState {
            link: Link::Unknown,
            report: None,
            report_at: None,
            position: None,
            position_at: None,
            rtim,
            last_error: None,
            counters: Counters::ZERO,
        }
    }

    /// Whether the last status shows the axis moving: servo on and positioning not complete.
    // Not inlined: its nine uses took 100 B more of the F103's flash.
    #[inline(never)]
    pub fn moving(&self) -> bool {
        self.report
            .is_some_and(|r| r.status.servo() && !r.outputs.pfin() && !r.outputs.alarm_active())
    }
}
