//! What the PLC sees: the Modbus register map of the gateway and the logic behind it.
//!
//! [`Gateway`] owns the bus-master [`Engine`](crate::engine::Engine); seen through
//! [`Gateway::registers`] it is the Modbus [`DataModel`](crate::modbus::DataModel): register
//! reads are answered from the engine's picture of the axes, writes become engine jobs. A write
//! is validated completely before anything happens, so an invalid request never reaches the
//! RS485 bus (it gets a Modbus exception).
//!
//! - Command bits act on rising edges, as PIO strobes do; SON and STP are levels.
//! - A broadcast (unit 0) writes DRG1, POSR or the coils of every axis, e.g. a STOP for all.
//! - Every axis shows the fate of its last command in CMST/CMER (taken, done, failed + reason).
//! - Fail-safe: if the PLC has been silent for longer than the watchdog time (default
//!   [`DEFAULT_WATCHDOG_MS`]), or the stop input drops, every axis gets a stop before anything
//!   else, and the event is latched in FAILSAFE until the PLC clears it.
//!
//! | Module | What it holds |
//! |---|---|
//! | [`write`](mod@write) | What a PLC's write means: typed writes, each register's range and conversion once |
//! | `command` | What the PLC sees of a command: [`CommandState`], [`Reason`], an axis' PLC-side state |
//! | `gateway` | [`Gateway`]: commands and their fate, events, the held SON |
//! | `model` | [`Registers`]: which unit, which addresses exist |
//! | `axis_unit`, `gateway_unit` | The registers of an axis unit and of the gateway unit |
//! | `failsafe`, `sync`, `channel`, `points`, `persist` | The parts with state of their own |
//! | [`settings`] | What survives a power cycle, as stored bytes |
//! | [`map`], `registers`, [`table`] | The register map as data; status words; table rows |
//! | `config`, `boot` | [`GatewayConfig`]; [`Boot`], what the firmware says about the start |
//! | `refused` | [`Refused`]: why a request is refused, before any face says it its way |
//! | `update` | A firmware image over the PLC link into the DFU partition (feature `update`) |

mod axis_unit;
mod boot;
mod channel;
mod command;
mod config;
mod failsafe;
mod gateway;
mod gateway_unit;
pub mod map;
mod model;
mod persist;
mod points;
mod refused;
mod registers;
pub mod settings;
mod sync;
pub mod table;
mod teach;
#[cfg(feature = "update")]
pub mod update;
pub mod write;

pub use boot::{Boot, ConfigSource, ResetCause};
pub use command::{CommandState, Reason};
pub use config::{
    AxisBase, AxisConfig, GatewayConfig, GatewaySettings, InchStep, JogSpeed, Parity, PlcBaud,
    PlcLine, UnitId, WatchdogAction, WatchdogTime, DEFAULT_AXIS_BASE, DEFAULT_GATEWAY_UNIT,
    DEFAULT_PIO_INCH, DEFAULT_PIO_JOG, DEFAULT_WATCHDOG_MS, IDENTITY, MAX_AXIS_BASE, MAX_PIO_INCH,
    PIO_ACCEL, PLC_BAUDS,
};
pub use failsafe::{CAUSE_STOP_INPUT, CAUSE_WATCHDOG};
pub use gateway::Gateway;
#[cfg(feature = "tcp")]
pub use model::TcpView;
pub use model::{diagnostic, Registers};
pub use persist::SettingsRequest;
pub use points::CACHED_ROWS;
pub use refused::Refused;
pub use write::{admit, Conflict, Pending};
