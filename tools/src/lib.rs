//! The PC side of the Robo Cylinder gateway: what its binaries share. The simulated controllers
//! (`sim`, behind `rc-sim` and `rc-gateway-host --sim`, and the world the tests in `tests/` run
//! the gateway against), the gateway on a PC (`host`, behind `rc-gateway-host`), frames for
//! people (`rcframe`, behind `rcframe` and `rc-commission`) and the pseudo-terminal they open.
pub mod host;
pub mod pty;
pub mod rcframe;
pub mod sim;
