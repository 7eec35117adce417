//! The modules of the `rcframe` binary (see `src/bin/rcframe.rs`).

pub mod decode;
pub mod describe;
pub mod encode;
pub mod units;
