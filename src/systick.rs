//! An embassy time driver on the Cortex-M SysTick, for the emulator: QEMU's `b-l475e-iot01a`
//! models no TIM peripheral, which embassy-stm32's time drivers need.
//!
//! SysTick interrupts every millisecond; `now()` adds the counter's progress within the current
//! millisecond, so time has microsecond resolution. Timers are checked on each interrupt: they
//! fire at most 1 ms late, which the emulator tests (generous time-outs) do not notice.
//!
//! The same interrupt runs the emulator's model of the independent watchdog (QEMU has no IWDG):
//! [`watchdog_start`], [`watchdog_pet`].

use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicU32, Ordering};
use core::task::Waker;

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{SCB, SYST};
use cortex_m_rt::exception;
use critical_section::Mutex;
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

const TICKS_PER_MS: u64 = embassy_time_driver::TICK_HZ / 1000;
/// Core cycles in a millisecond (SysTick's period) and in a tick, as constants: `now()` runs on
/// every timer poll, and `scripts/cpu-load.sh` counts it.
const CYCLES_PER_MS: u32 = crate::board::SYSCLK_HZ / 1000;
const CYCLES_PER_TICK: u32 = CYCLES_PER_MS / TICKS_PER_MS as u32;
const _: () = assert!(CYCLES_PER_TICK * TICKS_PER_MS as u32 == CYCLES_PER_MS);

struct SysTickDriver {
    /// Milliseconds counted by the interrupt.
    ms: Mutex<Cell<u64>>,
    queue: Mutex<RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: SysTickDriver = SysTickDriver {
    ms: Mutex::new(Cell::new(0)),
    queue: Mutex::new(RefCell::new(Queue::new())),
});

/// Starts the 1 ms interrupt (SysTick counts [`crate::board::SYSCLK_HZ`] core cycles).
pub fn init(mut syst: SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(CYCLES_PER_MS - 1);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
}

impl Driver for SysTickDriver {
    fn now(&self) -> u64 {
        critical_section::with(|cs| {
            let mut ms = self.ms.borrow(cs).get();
            let mut current = SYST::get_current();
            // The counter wrapped but the interrupt has not run yet (it is masked here): count
            // that millisecond, and read the counter again so it belongs to the new one.
            if SCB::is_pendst_pending() {
                ms += 1;
                current = SYST::get_current();
            }
            let within = (CYCLES_PER_MS - 1).saturating_sub(current) / CYCLES_PER_TICK;
            ms * TICKS_PER_MS + u64::from(within)
        })
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| {
            self.queue.borrow_ref_mut(cs).schedule_wake(at, waker);
        });
    }
}

#[exception]
fn SysTick() {
    let ms = critical_section::with(|cs| {
        let ms = DRIVER.ms.borrow(cs).get() + 1;
        DRIVER.ms.borrow(cs).set(ms);
        DRIVER
            .queue
            .borrow_ref_mut(cs)
            .next_expiration(ms * TICKS_PER_MS);
        ms
    });
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
    let ms = critical_section::with(|cs| DRIVER.ms.borrow(cs).get());
    WATCHDOG_PET_MS.store(ms as u32, Ordering::Relaxed);
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
