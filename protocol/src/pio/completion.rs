//! Completion tracking: what a move or home the PIO returned waits for before the outputs
//! follow the axis' status again (PEND and the completed position number).

use crate::engine::AxisState;
use crate::time::Instant;
use crate::{PositionNo, Pulses, StatusReport};

/// What a returned move or home waits for before the outputs follow the status again.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Target {
    Point(PositionNo),
    Home,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Phase {
    /// The status showed the axis moving when the command was returned: wait for it to stop.
    Before,
    /// Waiting for the status to show the command running.
    Ready,
    /// The status showed it running: wait for it to complete.
    Started,
}

/// How a wait for a move or home ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum End {
    /// The axis reached the point (or home).
    Reached,
    /// The axis stopped elsewhere: the move was cancelled.
    Short,
    /// An alarm or a rejected command: the outputs follow the status.
    Other,
}

/// Where a point of pattern 5 is, for its reed switch LSn: the row's position and band as
/// the controller holds them (pulses).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Band {
    /// The point's position (PCMD).
    pub position: Pulses,
    /// Its positioning band (INP), pulses.
    pub band: u32,
}

impl Band {
    /// Whether `position` is within the band of the point (both ends included, as PFIN).
    pub fn holds(&self, position: Pulses) -> bool {
        position.0.abs_diff(self.position.0) <= self.band
    }
}

/// A returned move or home, from its submission until it is seen to end.
#[derive(Clone, Copy, Debug)]
pub(super) struct Await {
    /// What it waits for.
    pub(super) target: Target,
    since: Instant,
    phase: Phase,
    rejections: u32,
}

impl Await {
    pub(super) fn new(
        target: Target,
        now: Instant,
        axis: &AxisState,
        report: &StatusReport,
    ) -> Await {
        Await {
            target,
            since: now,
            phase: if report.outputs.pfin() {
                Phase::Ready
            } else {
                Phase::Before
            },
            rejections: axis.counters.rejections,
        }
    }

    /// Advance on the axis' status; how the wait ended, if it has.
    pub(super) fn update(&mut self, axis: &AxisState, report: &StatusReport) -> Option<End> {
        if axis.counters.rejections != self.rejections {
            return Some(End::Other);
        }
        if axis.report_at.is_none_or(|at| at <= self.since) {
            return None;
        }
        let out = report.outputs;
        if out.alarm_active() {
            return Some(End::Other);
        }
        let (complete, running) = match self.target {
            Target::Point(point) => {
                if out.pfin() && out.pm() == point.get() {
                    return Some(End::Reached);
                }
                (out.pfin(), !out.pfin())
            }
            Target::Home => (out.pfin() && out.zfin(), !out.pfin() || !out.zfin()),
        };
        match self.phase {
            Phase::Before if out.pfin() => self.phase = Phase::Ready,
            Phase::Ready if running => self.phase = Phase::Started,
            // A move that ran and stopped without showing its point was cut short.
            Phase::Started if complete => {
                return Some(match self.target {
                    Target::Point(_) => End::Short,
                    Target::Home => End::Reached,
                })
            }
            _ => {}
        }
        None
    }
}
