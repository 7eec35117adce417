//! The protocol node the gateway task drives, and the settings it starts with.
//!
//! Every decision is `protocol::node::Node`'s; its documentation holds the hardware contract
//! this firmware keeps (who stamps time, flush before a rate change and before turnaround,
//! ingress before egress).

pub use protocol::node::{Action, Node};
pub use protocol::time::Instant;

use protocol::plc::{GatewayConfig, IDENTITY};
use protocol::{Axis, AxisSet};

/// The board's name in the device identification (FC2B/0E object 05).
const MODEL_NAME: &str = crate::board::MODEL_NAME;

/// The settings of a gateway nobody has set up yet: axis 0 on the bus with the §6-1
/// establishment at 115.2 kbit/s, RTIM 3 ms; the discrete I/O on axis 0; the PLC line at
/// 115.2 kbit/s 8N1, gateway unit 63; PLC watchdog 1 s. The PLC (or the commissioning tool)
/// enables more axes in AXISCFG and applies them with APPLY.
pub const fn default_config() -> GatewayConfig {
    let mut config = GatewayConfig::new(AxisSet::first(1));
    config.pio_axis = Axis::new(0);
    config.identity = protocol::modbus::Identity {
        model_name: MODEL_NAME,
        ..IDENTITY
    };
    // QEMU's UART moves bytes without wire time: a command "leaves" at once, so an answer can
    // complete sooner after the hand-over than a real line allows, and the emulator's virtual
    // clock is only kept near real time. The earliest-answer bound is a property of a wire
    // (`protocol::engine::Config::wire_timing`); on the board it stays on.
    // And its host can stall QEMU for a few hundred ms with a controller's answer already sent
    // (rc-sim keeps real time): the response time-outs get that much slack, so that a stall of
    // the emulator is not taken for a silent axis. Its PLC line is a socket whose bytes the task
    // may read in bursts further apart than t3.5: a frame ends after 20 ms of silence there.
    #[cfg(feature = "emulator")]
    {
        config.bus.wire_timing = false;
        config.bus.reply_slack = protocol::time::Duration::from_millis(250);
        config.plc_frame_gap = Some(protocol::time::Duration::from_millis(20));
    }
    config
}
