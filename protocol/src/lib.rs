//! The IAI Robo Cylinder serial protocol, sans-IO.
//!
//! This crate knows what the bytes on the RS485 bus mean; it never touches hardware or reads a
//! clock. It is `no_std`, allocates nothing and never panics on any input.
//!
//! Sources: IAI's "ROBO CYLINDER Serial Communications Protocol" (the *brief edition*) and
//! "Robo Cylinder RCP Serial Communication protocol" (2002, the *complete edition*); section
//! numbers in the documentation refer to them. Where they disagree, the item's documentation
//! says which is followed and why.
//!
//! | Module | What it answers |
//! |---|---|
//! | [`rc`] | The Robo Cylinder codec, each of its modules also at the crate's root: |
//! | [`frame`] | What is a frame: STX, 12 characters, BCC, ETX |
//! | [`deframer`] | Where are the frames in a byte stream |
//! | [`command`] | What the host can say ([`Request`], [`Command`]) |
//! | [`reply`] | What a controller answers ([`Reply`]) and whether it answers the command sent |
//! | [`status`], [`alarm`] | What the status bits and alarm codes mean |
//! | [`units`] | mm, mm/s and G in the controller's units |
//! | [`memory`] | The controller's memory map |
//! | [`engine`] | The bus master: what to send next, time-outs, retries, polling, jobs ([`engine::point_jobs`]: point-table reads and writes as frame sequences) |
//! | [`line`](mod@line) | Break, baud rates, the communication-change broadcast |
//! | [`modbus`] | The gateway's other side: a Modbus slave for the PLC ([`modbus::Slave`]), RTU and (feature `tcp`) TCP |
//! | [`net`] | The network settings: the board's address, who may connect over TCP |
//! | [`pio`] | The PLC's discrete I/O (PCON pattern 0 signals) for one axis, as jobs and outputs |
//! | [`plc`] | What the PLC sees: the Modbus register map, commands, fail-safe |
//! | [`node`] | The one object the firmware drives: the gateway behind its lines and pins |
//! | [`time`], [`axes`] | Time passed in by the caller; per-axis sets and maps |
//!
//! ```
//! use protocol::{Axis, Command, Frame, Reply, Request};
//!
//! // Ask axis 0 for its status (brief edition §5-1 1).
//! let request = Request::new(Axis::new(0).ok_or("axis")?, Command::Status);
//! assert_eq!(&request.emit().to_text(), b"0n000000000082");
//!
//! // The controller answers: servo on, ready, homed; PFIN, ZFIN and *ALM (no alarm) on.
//! let reply = Reply::parse(&Frame::from_text(b"U0n0F0000B0035")?)?;
//! reply.answers(&request).map_err(|_| "mismatch")?;
//! let report = reply.report().ok_or("not a status")?;
//! assert!(report.status.home() && report.outputs.pfin() && !report.outputs.alarm_active());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::unreachable,
        clippy::todo
    )
)]

pub mod axes;
mod bits;
mod div;
pub mod engine;
pub mod error;
mod hex;
pub mod modbus;
pub mod net;
pub mod node;
pub mod pio;
pub mod plc;
pub mod rc;
pub mod time;
mod types;
pub mod units;

pub use rc::{alarm, command, deframer, frame, line, memory, reply, status};

pub use alarm::AlarmCode;
pub use axes::{AxisMap, AxisSet};
pub use command::{Buffered, Code, Command, Request};
pub use deframer::Deframer;
pub use error::{Error, Field};
pub use frame::{Frame, Packet};
/// The `nb` crate, whose `Result` the [`Deframer`] returns.
pub use nb;
pub use reply::{MemoryCode, Mismatch, Reply};
pub use status::{Inputs, Outputs, Status, StatusReport};
pub use types::{
    Acceleration, Address, Axis, DataType, HomeDirection, PositionNo, Pulses, ResetKind, Rtim,
    Transfer, Velocity, RTIM_AFTER_BREAK,
};
