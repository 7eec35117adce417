//! The emulator's time driver (QEMU's `b-l475e-iot01a` models no TIM peripheral, which
//! embassy-stm32's time drivers need): `systick_time`'s SysTick driver, which emu-net's build runs
//! too, at the L475's core clock.
//!
//! The same interrupt runs the emulator's model of the independent watchdog (QEMU has no IWDG):
//! [`watchdog_start`], [`watchdog_pet`].

use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::peripheral::{SCB, SYST};
use cortex_m_rt::exception;
use systick_time::SysTickTime;

systick_time::time_driver_impl!(
    static DRIVER: SysTickTime<{ crate::board::SYSCLK_HZ }> = SysTickTime::new()
);

/// Starts the 1 ms interrupt (SysTick counts [`crate::board::SYSCLK_HZ`] core cycles).
pub fn init(syst: SYST) {
    DRIVER.start(syst);
}

#[exception]
fn SysTick() {
    let ms = DRIVER.tick();
    watchdog_check(ms as u32);
}

/// The model of the IWDG: the milliseconds it allows between two pets (0: not started), and the
/// millisecond of the last pet. Like the IWDG, once started it cannot be stopped.
static WATCHDOG_LIMIT_MS: AtomicU32 = AtomicU32::new(0);
static WATCHDOG_PET_MS: AtomicU32 = AtomicU32::new(0);

/// Starts the watchdog model: it resets the chip `timeout_us` after the last pet.
pub fn watchdog_start(timeout_us: u32) {
    watchdog_pet();
    WATCHDOG_LIMIT_MS.store(timeout_us / 1000, Ordering::Relaxed);
}

/// Restarts the watchdog model's count, as `IndependentWatchdog::pet` does the IWDG's.
pub fn watchdog_pet() {
    WATCHDOG_PET_MS.store(DRIVER.ms() as u32, Ordering::Relaxed);
}

/// On every SysTick: past the limit, what the IWDG does (a reset), with a line for the harness.
/// QEMU resets the machine as the board would; the reset cause is not kept (QEMU models no reset
/// flags, and the loader clears RAM), so RESETCAUSE does not say "watchdog" here as it does on the
/// board.
fn watchdog_check(now_ms: u32) {
    let limit = WATCHDOG_LIMIT_MS.load(Ordering::Relaxed);
    let since = now_ms.wrapping_sub(WATCHDOG_PET_MS.load(Ordering::Relaxed));
    if limit != 0 && since > limit {
        error!("watchdog: no progress for {} ms, reset", since);
        SCB::sys_reset();
    }
}
