//! Frames for people: the `rcframe` binary's encode and decode (see `src/bin/rcframe.rs`), and
//! the units and descriptions `rc-commission` shares with it.

pub mod decode;
pub mod describe;
pub mod encode;
pub mod units;
