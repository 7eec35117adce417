//! A Robo Cylinder controller simulator in virtual time.
//!
//! Up to 16 simulated controllers ([`Controller`]) on one simulated RS485 line ([`Bus`]),
//! speaking IAI's 16-byte ASCII protocol as the vendor documents describe it: the brief edition
//! ("ROBO CYLINDER Serial Communications Protocol") and the complete edition ("Robo Cylinder RCP
//! Serial Communication protocol", 2002); section numbers refer to the complete edition unless
//! stated. Frames are encoded and decoded with the [`protocol`] crate, never by hand.
//!
//! Every time is a `u64` count of microseconds of virtual time; nothing reads a clock or sleeps.
//! A test (or a bus master under test) sends with [`Bus::host_send`], asks [`Bus::next_event`]
//! when something will happen and runs the bus with [`Bus::advance`], which returns the bytes
//! the host received. [`host::ScriptedHost`] wraps that loop for scripted exchanges, and
//! [`realtime::RealTime`] runs it against the wall clock for a real master (the only part that
//! reads a clock).
//!
//! | Module | What it models |
//! |---|---|
//! | [`wire`] | Byte and frame times at a baud rate |
//! | [`motion`] | Trapezoidal moves from VCMD/ACMD |
//! | [`memory`] | Non-volatile, edit and execution areas (§7) |
//! | [`controller`] | One axis: line settings, drive state, status bytes |
//! | `commands` | What each command does, and its rejections (§4-4, §8-1-5) |
//! | `line` | A controller's line: bytes in, replies out, breaks, baud changes, power |
//! | [`bus`] | The half-duplex line: timing, collisions, breaks, baud mismatches |
//! | [`fault`] | Seeded fault injection |
//! | [`stats`] | Counters of everything that happened, injected faults included |
//! | [`host`] | A scripted host for tests |
//! | [`realtime`] | The bus against the wall clock, for a real master behind a PTY or TCP socket |
//! | [`rng`] | The deterministic generator |

mod commands;
mod line;

pub mod bus;
pub mod controller;
pub mod fault;
pub mod host;
pub mod memory;
pub mod motion;
pub mod realtime;
pub mod rng;
pub mod stats;
pub mod wire;

pub use bus::{Bus, BusConfig, Source};
pub use controller::{BadBccPolicy, Controller, ControllerConfig, ControllerStats};
pub use fault::Faults;
pub use host::{Answer, ScriptedHost};
pub use stats::BusStats;
