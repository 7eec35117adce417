//! Host-side tools and test harnesses for the Robo Cylinder gateway.
pub mod harness;
pub mod host;
pub mod node_harness;
pub mod pty;
pub mod rcframe;
pub mod regmap;
pub mod sim;
