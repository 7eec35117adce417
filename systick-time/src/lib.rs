//! An embassy time driver on the Cortex-M SysTick, shared by the two emulator builds: the
//! firmware's (`--features emulator`, QEMU's `b-l475e-iot01a`, which models no TIM peripheral for
//! embassy-stm32's time drivers) and `emu-net`'s (QEMU's `mps2-an386`, which has no HAL at all).
//!
//! SysTick interrupts every millisecond; [`Driver::now`] adds the counter's progress within the
//! current millisecond, so time has the resolution of embassy-time's tick (1 MHz in both builds).
//! Expired timers are woken from the interrupt, at most 1 ms late, which the emulator tests
//! (generous time-outs, never wire timing) do not notice.
//!
//! The core clock is a const parameter, so that the cycles per millisecond and per tick are
//! constants (`now()` runs on every timer poll, and `scripts/cpu-load.sh` counts its
//! instructions). Each build declares the driver and its SysTick handler itself, because the
//! handler may do more than count (the firmware's watchdog model):
//!
//! ```ignore
//! systick_time::time_driver_impl!(static TIME: SysTickTime<SYSCLK_HZ> = SysTickTime::new());
//!
//! #[cortex_m_rt::exception]
//! fn SysTick() {
//!     TIME.tick();
//! }
//! ```
//! and starts it once with [`SysTickTime::start`].

#![no_std]

#[cfg(target_os = "none")]
mod driver;

#[cfg(target_os = "none")]
pub use driver::SysTickTime;
#[cfg(target_os = "none")]
pub use embassy_time_driver::time_driver_impl;
