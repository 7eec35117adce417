//! `rc-gateway` firmware: lets a PLC drive IAI Robo Cylinder actuators over an RS485 bus.
//!
//! Target: STM32L475VG (Cortex-M4F), as on the B-L475E-IOT01A board that QEMU's `b-l475e-iot01a`
//! machine models. Runtime: embassy (async executor, HAL, timers); logging: defmt over RTT.
//!
//! All protocol logic (Robo Cylinder frames, the bus-master state machine, the PLC-side interface)
//! lives in the host-testable `protocol` crate. This binary only initialises the hardware and moves
//! bytes between the peripherals and those state machines; it holds no protocol decisions itself.
//!
//! For now this is the skeleton that the bus-master work will fill in: it brings the chip up, logs
//! the firmware version, and blinks a heartbeat LED so a board (or an emulator trace) shows that the
//! executor and the time driver are running.

#![no_std]
#![no_main]
#![deny(unsafe_code)]

use defmt::{error, info};
use embassy_executor::Spawner;
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_time::Timer;
use {defmt_rtt as _, panic_probe as _};

// Links the protocol crate into the firmware already, before any of its API is used here.
use protocol as _;

/// Firmware version, from `Cargo.toml`.
const VERSION: &str = env!("CARGO_PKG_VERSION");

/// Half period of the heartbeat blink: the LED toggles this often (1 Hz blink).
const HEARTBEAT_HALF_PERIOD_MS: u64 = 500;

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    // Default clock config: the 4 MHz MSI the chip resets to. No external crystal is needed.
    let p = embassy_stm32::init(Default::default());
    info!("rc-gateway {=str} starting", VERSION);

    // B-L475E-IOT01A: LED2 (green) is on PB14, active high.
    let led = Output::new(p.PB14, Level::Low, Speed::Low);
    // Creating the task fails only if its single instance already runs: log it, keep going
    // (the heartbeat is a diagnostic, not a reason to stop the gateway).
    match heartbeat(led) {
        Ok(token) => spawner.spawn(token),
        Err(e) => error!("heartbeat task not started: {}", e),
    }

    info!("init done");
    // Returning ends only this task; the executor keeps running the spawned ones.
}

/// Toggles the heartbeat LED forever.
#[embassy_executor::task]
async fn heartbeat(mut led: Output<'static>) {
    loop {
        led.toggle();
        Timer::after_millis(HEARTBEAT_HALF_PERIOD_MS).await;
    }
}
