//! What the engine hands back: what to do on the line ([`Output`]), what happened ([`Event`]),
//! why a job was refused ([`SubmitError`]) and what the bus as a whole has counted.

use super::job::{JobError, JobId, JobOutput};
use crate::line::LineAction;
use crate::time::Instant;
use crate::{Axis, Frame, StatusReport};

/// What the caller does next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Output {
    /// Send this frame now.
    Transmit(Frame),
    /// Do this to the line now.
    Line(LineAction),
    /// Nothing to send until this time (or until bytes arrive); `None`: until something changes.
    Idle(Option<Instant>),
}

/// Something that happened, for the PLC side and for logs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// The axis answered after being unknown or offline.
    Online(Axis),
    /// The axis stopped answering.
    Offline(Axis),
    /// The axis' status changed.
    Status {
        /// The axis.
        axis: Axis,
        /// Its new status.
        report: StatusReport,
    },
    /// A job finished.
    JobDone {
        /// The job.
        id: JobId,
        /// Its axis.
        axis: Axis,
        /// How it ended.
        result: Result<JobOutput, JobError>,
    },
    /// The communication establishment procedure finished.
    Established,
}

/// Why a job was not accepted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SubmitError {
    /// [`QUEUE_LEN`](super::QUEUE_LEN) jobs are waiting already, or
    /// [`WAITING_PER_AXIS`](super::WAITING_PER_AXIS) for this axis.
    QueueFull,
    /// The axis is not in [`Config::axes`](super::Config::axes).
    AxisDisabled,
}

/// Counters that belong to the bus rather than to one axis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BusCounters {
    /// Valid frames or bad candidates that arrived while no command was waiting for an answer.
    pub unsolicited: u32,
    /// Events dropped because nobody read them.
    pub events_lost: u32,
    /// Jobs refused because the queue was full.
    pub queue_full: u32,
    /// Times the establishment procedure ran.
    pub establishments: u32,
    /// Times an axis came to owe a stop: its stop got no answer ([`Engine::stop_owed`](super::Engine::stop_owed));
    /// more stops it does not answer while it owes one are not counted again.
    pub stops_owed: u32,
}

impl BusCounters {
    pub(crate) const ZERO: BusCounters = BusCounters {
        unsolicited: 0,
        events_lost: 0,
        queue_full: 0,
        establishments: 0,
        stops_owed: 0,
    };
}
