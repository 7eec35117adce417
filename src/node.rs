//! The contract between the gateway task and the protocol state machine it owns.
//!
//! The task ([`crate::gateway`]) moves bytes, pin levels and time into a [`Node`] and carries out
//! the [`Action`]s it returns; every decision is the node's. The planned `protocol::node::Node` has
//! exactly these methods (as inherent methods), so wiring it in is: implement [`Node`] for it by
//! delegation (or replace this module's items with `pub use`s of the protocol's), and change
//! [`ActiveNode`] and [`new_node`]. Until then the bring-up stand-in ([`crate::bringup`]) runs on
//! the same task, so the hardware layer and the emulator harness are exercised end to end.

pub use protocol::engine::Instant;
pub use protocol::line::Baud;
pub use protocol::pio::{PioInputs, PioOutputs};

/// Something the node asks of the lines (what `protocol::line::LineAction` will be).
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum LineAction {
    /// Switch the bus UART to this rate (after the last byte has left: the task flushes first).
    SetBaud(Baud),
    /// Start holding the bus low (a break, complete edition §6-1), driver enabled.
    BreakStart,
    /// Release the bus: back to idle (mark), driver disabled.
    BreakEnd,
    /// Transmit `protocol::frame::COMM_CHANGE` on the bus (nobody answers it).
    CommChange,
}

/// What the node wants done now.
pub enum Action<'a> {
    /// Transmit this frame on the RS485 bus, then wait until it has left (turnaround).
    Bus([u8; 16]),
    /// A line operation on the bus.
    Line(LineAction),
    /// Transmit this Modbus reply to the PLC, then wait until it has left.
    Reply(&'a [u8]),
}

/// The sans-IO protocol object the gateway task drives. Time is passed in, never read.
pub trait Node {
    /// Bytes the bus UART received; `now` is when they were read.
    fn bus_received(&mut self, now: Instant, bytes: &[u8]);
    /// Bytes the PLC UART received.
    fn plc_received(&mut self, now: Instant, bytes: &[u8]);
    /// The discrete inputs, sampled every millisecond (bit n = PCON pattern 0 port INn).
    fn sample_inputs(&mut self, now: Instant, inputs: PioInputs);
    /// The safety stop input changed (`active` = the stop is requested: the input is OFF).
    fn set_stop_input(&mut self, now: Instant, active: bool);
    /// The next thing to do; the task calls this until it returns `None`.
    fn poll(&mut self, now: Instant) -> Option<Action<'_>>;
    /// When `poll` has something to do without new input (`None`: only input wakes it).
    fn poll_at(&self) -> Option<Instant>;
    /// The discrete outputs to drive (bit n = PCON pattern 0 port OUTn).
    fn outputs(&self) -> PioOutputs;
    /// (bus link good, alarm) for the LEDs.
    fn indicators(&self) -> (bool, bool);
}

/// The node the firmware runs.
pub type ActiveNode = crate::bringup::BringUp;

/// A new [`ActiveNode`], to be placed in a `static` by the caller (it is large; never on a stack).
pub const fn new_node() -> ActiveNode {
    crate::bringup::BringUp::new()
}
