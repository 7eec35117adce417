//! Why the gateway refuses what a PLC asks, in its own words: each face (the Modbus slave, the
//! discrete inputs) shows a refusal its own way. The Modbus face maps it to an exception in one
//! place (`model::exception`); the PIO shows a refused strobe by its outputs.

/// What a request asked that the gateway will not do; nothing of the request was carried out,
/// except where a variant says the axis' CMST records it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Refused {
    /// No such register or coil here, or not in this table (Modbus 02).
    NoSuchAddress,
    /// A value out of its range, a register that cannot be written, a block of the wrong
    /// length (Modbus 03).
    OutOfRange,
    /// The axis does not answer: anything but a stop is refused, so that nothing runs late when
    /// it appears (Modbus 04).
    Offline,
    /// The job queue is full; CMST shows it (reason 9) when it refused a command (Modbus 04).
    QueueFull,
    /// Not now: the command channel or a synchronized start is busy, the axis is not at rest for
    /// a relative move, the queue has no room for every command of the write (Modbus 04).
    Busy,
    /// The data is not there yet: no status from the axis, a position-table row being fetched
    /// (Modbus 04: ask again shortly).
    NotReady,
    /// STP, EMG or the stop input holds the axis: no motion starts. CMST shows it (failed,
    /// reason 10); to a Modbus master the write itself succeeds, as IAI's controllers take a
    /// start they then do not carry out.
    Stopped,
}

impl From<crate::units::UnitError> for Refused {
    /// A value the controller's units cannot express is out of range (03).
    fn from(_: crate::units::UnitError) -> Refused {
        Refused::OutOfRange
    }
}
