//! The protocol node the gateway task drives, and the settings it starts with.
//!
//! Every decision is `protocol::node::Node`'s; its documentation holds the hardware contract
//! this firmware keeps (who stamps time, flush before a rate change and before turnaround,
//! ingress before egress).

pub use protocol::node::{Action, Node};
pub use protocol::time::Instant;

use protocol::modbus::Identity;
use protocol::plc::GatewayConfig;
use protocol::{Axis, AxisSet};

/// The board's name in the device identification (FC2B/0E object 05).
const MODEL_NAME: &str = crate::board::MODEL_NAME;

/// Who this gateway is: the project's identity with the board's name.
pub static IDENTITY: Identity = Identity {
    model_name: MODEL_NAME,
    ..protocol::plc::IDENTITY
};

/// The settings of a gateway nobody has set up yet: axis 0 on the bus with the §6-1
/// establishment at 115.2 kbit/s, RTIM 3 ms; the discrete I/O on axis 0; the PLC line at
/// 115.2 kbit/s 8N1, gateway unit 63; PLC watchdog 1 s. The PLC (or the commissioning tool)
/// enables more axes in AXISCFG and applies them with APPLY.
pub const fn default_config() -> GatewayConfig {
    let mut config = GatewayConfig::new(AxisSet::first(1));
    config.settings.pio_axis = Axis::new(0);
    config
}
