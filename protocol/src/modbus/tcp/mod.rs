//! Modbus TCP, beside RTU: the same [`Slave`](super::Slave), register map, units and
//! exceptions, another framing (feature `tcp`).
//!
//! Source: "MODBUS Messaging on TCP/IP Implementation Guide V1.0b" (*TCP Guide*).
//!
//! | Module | What it answers |
//! |---|---|
//! | [`mbap`] | What a frame is (MBAP header, PDU) and where frames end in a byte stream |
//! | [`server`] | Which connections are served: allow-list, limit, idle time, turns |
//!
//! What differs from the serial line, and where it is handled:
//! - **Unit ids** (TCP Guide §4.4.2): 0xFF, and 0, address the device at the IP address
//!   itself, which is the gateway unit here; every other id is a unit as on RTU (the gateway's
//!   own id, the axes'). There is no broadcast on TCP.
//! - **A unit nobody serves** gets exception 0x0A, gateway path unavailable (Application
//!   Protocol §7): on a connection of its own a client would otherwise wait for its time-out.
//! - **FC08 Diagnostics** is serial-line only (Application Protocol §6.8): exception 01.
//!
//! [`Slave::handle_tcp`](super::Slave::handle_tcp) answers one frame.

pub mod mbap;
pub mod server;

pub use crate::net::{Ipv4, Policy};
pub use mbap::{MbapError, Stream, TcpAdu, MAX_TCP_ADU_LEN, MBAP_LEN};
pub use server::{Server, SocketHandle, TcpCounters, MAX_CONNECTIONS, SOCKETS};

/// The Modbus TCP port (TCP Guide §4.1, registered with IANA).
pub const MODBUS_TCP_PORT: u16 = 502;

/// The unit id of the device at the IP address itself (TCP Guide §4.4.2); 0 is taken the
/// same way.
pub const DIRECT_UNIT: u8 = 0xFF;
