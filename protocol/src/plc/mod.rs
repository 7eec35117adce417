//! What the PLC sees: the Modbus register map of the gateway and the logic behind it.
//!
//! [`Gateway`] owns the bus-master [`Engine`](crate::engine::Engine) and implements the Modbus
//! [`DataModel`](crate::modbus::DataModel): register reads are answered from the engine's picture
//! of the axes, writes become engine jobs. A write is validated completely before anything
//! happens, so an invalid request never reaches the RS485 bus (it gets a Modbus exception).
//!
//! - Command bits act on rising edges, as PIO strobes do; SON and STP are levels.
//! - A broadcast (unit 0) writes DRG1, POSR or the coils of every axis, e.g. a STOP for all.
//! - Every axis shows the fate of its last command in CMST/CMER (taken, done, failed + reason).
//! - Fail-safe: if the PLC has been silent for longer than the watchdog time (default
//!   [`DEFAULT_WATCHDOG_MS`]), or the stop input drops, every axis gets a stop before anything
//!   else, and the event is latched in FAILSAFE until the PLC clears it.

mod config;
mod gateway;
pub mod map;
mod registers;
pub mod table;

pub use config::{
    AxisConfig, GatewayConfig, WatchdogAction, DEFAULT_GATEWAY_UNIT, DEFAULT_WATCHDOG_MS,
};
pub use gateway::{CommandState, Gateway, Reason};
