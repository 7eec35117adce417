//! `rc-gateway` firmware: lets a PLC drive IAI Robo Cylinder actuators over an RS485 bus.
//!
//! Target: STM32L475VG (Cortex-M4F), as on the B-L475E-IOT01A board that QEMU's `b-l475e-iot01a`
//! machine models. Runtime: embassy (async executor, HAL, timers).
//!
//! All protocol logic lives in the host-tested `protocol` crate; this binary only moves bytes,
//! pin levels and time between the peripherals and the protocol's node, and carries out what the
//! node asks. Modules:
//!
//! | Module | What it answers |
//! |---|---|
//! | [`board`] | Which pin and peripheral is which signal (the only board-specific module) |
//! | [`pins`] | GPIO below the HAL: the fail-safe pin states, the bus break |
//! | [`serial`] | An RS485 line: send-then-flush, rate change, break |
//! | [`discrete`] | PIO inputs and outputs as pins; LEDs |
//! | [`node`] | The protocol node and the settings it starts with |
//! | [`gateway`] | The one task that owns the node |
//! | `net` | Modbus TCP over Ethernet: the network stack and its socket tasks (feature `net`) |
//! | [`io`] | The task that samples the inputs and drives the outputs and LEDs |
//! | [`settings`] | The settings at start-up and on SAVE, factory reset, reset cause |
//! | `dfu` | The DFU partition a firmware image sent over the PLC link goes to (feature `update`: the L475) |
//! | [`rt`] | Executor loop, panic and HardFault handlers (the `unsafe`, but the emulator's fault requests) |
//! | [`emu`] | The emulator build's hooks (time driver, watchdog model, pacing, the harness' requests): no-ops on the board |
//!
//! Two builds (Cargo features): `hw` (default) for the board, `emulator` for QEMU
//! (`scripts/emu-build.sh`). They differ in the time driver, the log channel and the watchdog:
//! the product code calls the emulator's hooks ([`emu`]) in both, and they do nothing on the board.

#![no_std]
#![no_main]
#![deny(unsafe_code)]

#[cfg(all(feature = "hw", feature = "emulator"))]
compile_error!("the features `hw` and `emulator` exclude each other: build the emulator with `--no-default-features --features emulator`");
#[cfg(not(any(feature = "hw", feature = "emulator")))]
compile_error!("choose a build: feature `hw` (the default) or `emulator`");
#[cfg(any(
    all(feature = "board-l475", feature = "board-f103"),
    all(feature = "board-l475", feature = "board-f429"),
    all(feature = "board-f103", feature = "board-f429"),
))]
compile_error!("choose one board: `board-l475` (the default), or `board-f103` / `board-f429` with `--no-default-features --features hw,board-f103` (or `hw,board-f429`)");
#[cfg(not(any(feature = "board-l475", feature = "board-f103", feature = "board-f429")))]
compile_error!("choose a board: feature `board-l475`, `board-f103` or `board-f429`");
#[cfg(all(feature = "board-f429", feature = "emulator"))]
compile_error!("the emulator build is the L475's: QEMU has no STM32 with Ethernet (the network side is proven on `mps2-an386`: emu-net/)");

#[macro_use]
mod log;
mod board;
#[cfg(feature = "update")]
mod dfu;
mod discrete;
mod emu;
mod gateway;
mod io;
#[cfg(feature = "net")]
mod net;
mod node;
mod pins;
#[allow(unsafe_code)]
mod rt;
mod serial;
mod settings;

#[cfg(feature = "hw")]
use defmt_rtt as _;
use embassy_executor::Spawner;
use small_mem as _;
use static_cell::StaticCell;

/// Firmware version, from `Cargo.toml`.
const VERSION: &str = env!("CARGO_PKG_VERSION");

#[cortex_m_rt::entry]
fn main() -> ! {
    rt::run(start, spawn)
}

/// What the tasks work with, for as long as the firmware runs (in [`rt::run`]'s frame).
struct Started {
    /// Built with the stored settings, in place (see `protocol::node::Node::new`): built last
    /// in [`start`]'s struct literal, so that nothing is written into this struct between the
    /// node's construction and its move here (checked: `start`'s frame holds no node).
    node: node::Node,
    /// `None` if the board could not be set up.
    parts: Option<&'static mut Parts>,
}

/// The board's side of [`Started`], in a `static`: its size is the board's (the settings store
/// is not in the emulator build), and the size report counts statics per board, the stack from
/// the emulator.
static PARTS: StaticCell<Parts> = StaticCell::new();

/// The board's side of [`Started`].
struct Parts {
    board: board::Board,
    pins: io::Pins,
    settings: settings::SavedSettings,
    /// The pins at power-up.
    boot: io::Sample,
    /// The network settings, as loaded: the stack starts at this address.
    #[cfg(feature = "net")]
    net: protocol::net::NetConfig,
}

/// Brings the chip up, loads the settings (a factory reset first if the inputs held at power-up
/// ask for one) and builds the node with them.
#[inline(never)]
fn start() -> Started {
    let mut config = node::default_config();
    // The emulator's timing: no wire timing on the bus, reply slack, the PLC line's frame gap
    // (nothing on the board).
    emu::loosen_timing(&mut config);
    let mut parts = bring_up(config.settings.plc);
    let mut booted = protocol::plc::Boot::DEFAULT;
    if let Some(Parts {
        board,
        settings,
        boot,
        pins,
        ..
    }) = parts.as_deref_mut()
    {
        // Before the settings: a stored pattern this board lacks ports for is not taken.
        config.pio_ports = protocol::pio::Ports {
            inputs: pins.inputs.ports(),
            outputs: pins.outputs.ports(),
        };
        settings.load(boot.inputs, &mut config);
        booted = settings.boot;
        // A load that erased (a factory reset, a torn page) had its last pet before its last
        // erase: the gateway task's first heartbeat counts from here, not from there.
        board.watchdog.pet();
    }
    #[cfg(feature = "net")]
    if let Some(parts) = parts.as_deref_mut() {
        parts.net = config.settings.net;
    }
    Started {
        parts,
        node: node::Node::new(config, &node::IDENTITY, booted),
    }
}

/// The chip, the board with its PLC line at `plc` and the settings store. Not inlined: its
/// temporaries are gone before the settings are loaded and the node is built (the deepest stack
/// at start-up: the settings store's, on the boards).
#[inline(never)]
fn bring_up(plc: protocol::plc::PlcLine) -> Option<&'static mut Parts> {
    // The IWDG first: nothing below (clocks, PHY) may hang the chip before it runs.
    #[cfg(feature = "hw")]
    board::start_watchdog();
    let p = embassy_stm32::init(board::clock_config());
    emu::start_time();
    info!("rc-gateway {} starting", VERSION);

    match board::board(p, plc) {
        Ok((mut board, pins)) => {
            let boot = io::Sample::of(&pins.inputs);
            let settings = settings::SavedSettings::new(board.settings_flash.take());
            Some(PARTS.init(Parts {
                board,
                pins,
                settings,
                boot,
                #[cfg(feature = "net")]
                net: protocol::net::NetConfig::DEFAULT,
            }))
        }
        Err(_) => {
            // Only a baud rate the kernel clock cannot make: a build error, not a field fault.
            error!("UART configuration refused");
            None
        }
    }
}

/// Spawns the I/O task and the gateway task, which drives the node, and with Ethernet the
/// network stack's tasks.
fn spawn(spawner: Spawner, started: &'static mut Started) {
    let Started { node, parts } = started;
    let Some(Parts {
        board,
        pins,
        settings,
        boot,
        #[cfg(feature = "net")]
        net,
    }) = parts
    else {
        return;
    };
    #[cfg(feature = "net")]
    if let Some(ethernet) = board.ethernet.take() {
        net::spawn(spawner, ethernet, net);
    }
    match io::run(pins) {
        Ok(token) => spawner.spawn(token),
        Err(_) => error!("I/O task not started"),
    }
    match gateway::run(board, settings, *boot, node) {
        Ok(token) => spawner.spawn(token),
        Err(_) => error!("gateway task not started"),
    }
}
