//! The Robo Cylinder codec: what the bytes on the RS485 bus mean, without time or state. A
//! frame ([`frame`]) found in a byte stream ([`deframer`]) is a command ([`command`]) or a reply
//! ([`reply`]) whose fields are status bits ([`status`]), alarm codes ([`alarm`]) and addresses
//! of the controller's memory map ([`memory`]); [`line`](mod@line) is the bus itself (break,
//! rates, the communication-change broadcast). The crate's root re-exports each module, so
//! `protocol::command` and `protocol::rc::command` are one.

pub mod alarm;
pub mod command;
pub mod deframer;
mod field;
pub mod frame;
pub mod line;
pub mod memory;
pub mod reply;
pub mod status;
