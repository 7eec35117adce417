//! How the engine runs the bus.

use crate::axes::AxisSet;
use crate::line::Baud;
use crate::time::Duration;
use crate::Rtim;

/// The most resends after a time-out, Nrt (complete edition §5 (2): 0-3).
pub const MAX_RETRIES: u8 = 3;

/// How the engine runs the bus.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// The axes on the bus.
    pub axes: AxisSet,
    /// The line rate to establish and use.
    pub baud: Baud,
    /// The RTIM to establish (the controllers' minimum response delay).
    pub rtim: Rtim,
    /// Resends after a time-out, Nrt (complete edition §5 (2): 0-[`MAX_RETRIES`]; larger values
    /// count as [`MAX_RETRIES`]).
    pub retries: u8,
    /// Run the communication establishment procedure (§6-1) first. Without it, the engine
    /// assumes every axis already runs at `baud` with `rtim`.
    pub establish: bool,
    /// The transceiver's receiver is always on: swallow the gateway's own transmissions.
    pub echo: bool,
    /// The bytes cross a real wire, so that their times obey the line rate: the command takes
    /// its 16 character times to leave, the controller waits RTIM, and its answer takes 16
    /// character times to arrive. Then nothing can complete an answer sooner than that after the
    /// command was handed over ([`Output::Transmit`](super::Output::Transmit)), and a frame
    /// that ends earlier is a stale one (a late answer to an earlier command, or noise): it is
    /// not accepted. True for a UART (the firmware) and for the simulated bus in virtual time.
    ///
    /// False where byte times do not come from a wire: a pseudo-terminal, a socket, some USB
    /// adapters that acknowledge a write at once. There a controller's answer can arrive as
    /// soon as RTIM after the command, and the bound would throw every valid answer away: every
    /// valid, matching answer is accepted whenever it arrives while its command waits.
    pub wire_timing: bool,
    /// Added to every response time-out (complete edition §5 Trt). Zero on a wire, where §5's
    /// figure holds. More where the bytes may wait outside the wire: an emulator on a loaded
    /// host can stall for a few hundred ms with an answer already sent, and a USB adapter's
    /// latency timer holds received bytes for up to 16 ms.
    pub reply_slack: Duration,
    /// Position reads (R4 PNOW) per polling cycle for moving axes.
    pub position_reads_per_cycle: u8,
    /// How often an offline axis is probed, at most: the first probe follows after
    /// [`FIRST_PROBE`](super::FIRST_PROBE) and the interval doubles with each unanswered probe
    /// up to this, so that an axis lost to a burst of noise is back quickly and a dead one costs
    /// little.
    pub probe_interval: Duration,
    /// How long a job waits for a state (in position, homed) before it fails.
    pub motion_timeout: Duration,
    /// How often an offline axis is also tried at the power-up line settings (9.6 kbit/s,
    /// RTIM 255 ms) and, if it answers there, reconfigured like §6-1 for that axis alone
    /// (only with [`Config::establish`]: a controller that was power-cycled or replaced comes
    /// back at its stored settings).
    pub rejoin_interval: Duration,
    /// Start rejoin tries while an axis moves or runs a job too. Off by default: a try holds the
    /// bus for up to 300 ms (one transaction at 9.6 kbit/s and RTIM 255 ms), in which no moving
    /// axis is supervised and no stop can go out; so a lost axis is tried at its power-up
    /// settings only in a quiet moment (it is still probed at the bus' settings meanwhile).
    pub rejoin_while_moving: bool,
}

impl Config {
    /// The defaults: no axis, 115.2 kbit/s, RTIM 3 ms, 2 resends, establishment on, wire timing.
    pub const DEFAULT: Config = Config {
        axes: AxisSet::EMPTY,
        baud: Baud::B115200,
        rtim: Rtim::MIN,
        retries: 2,
        establish: true,
        echo: false,
        wire_timing: true,
        reply_slack: Duration::from_millis(0),
        position_reads_per_cycle: 4,
        probe_interval: Duration::from_millis(500),
        motion_timeout: Duration::from_millis(60_000),
        rejoin_interval: Duration::from_millis(5_000),
        rejoin_while_moving: false,
    };
}

impl Default for Config {
    fn default() -> Config {
        Config::DEFAULT
    }
}
