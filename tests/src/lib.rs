//! Test harnesses for the Robo Cylinder gateway: the engine and the whole Node against the
//! simulator (`rc_tools::sim`) in virtual time, and the register table docs/plc.md shows.
pub mod harness;
pub mod node_harness;
pub mod regmap;
