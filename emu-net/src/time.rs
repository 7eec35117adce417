//! An embassy time driver on the Cortex-M SysTick, at the AN386's 25 MHz core clock (QEMU's
//! hw/arm/mps2.c: `SYSCLK_FRQ`).
//!
//! SysTick interrupts every millisecond; `now()` adds the counter's progress inside the current
//! millisecond, so time has microsecond resolution (embassy-time's 1 MHz tick). Expired timers
//! are woken from the interrupt, at most 1 ms late.

use core::cell::{Cell, RefCell};
use core::task::Waker;

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{SCB, SYST};
use cortex_m_rt::exception;
use critical_section::Mutex;
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

/// The AN386's system clock, which SysTick counts.
pub const SYSCLK_HZ: u32 = 25_000_000;
const TICKS_PER_MS: u64 = embassy_time_driver::TICK_HZ / 1000;
const CYCLES_PER_MS: u32 = SYSCLK_HZ / 1000;
const CYCLES_PER_TICK: u32 = CYCLES_PER_MS / TICKS_PER_MS as u32;
const _: () = assert!(CYCLES_PER_TICK * TICKS_PER_MS as u32 == CYCLES_PER_MS);

struct SysTickTime {
    /// Milliseconds counted by the interrupt.
    ms: Mutex<Cell<u64>>,
    queue: Mutex<RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static TIME: SysTickTime = SysTickTime {
    ms: Mutex::new(Cell::new(0)),
    queue: Mutex::new(RefCell::new(Queue::new())),
});

/// Starts the 1 ms interrupt.
pub fn init(mut syst: SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(CYCLES_PER_MS - 1);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
}

impl Driver for SysTickTime {
    fn now(&self) -> u64 {
        critical_section::with(|cs| {
            let mut ms = self.ms.borrow(cs).get();
            let mut current = SYST::get_current();
            // Wrapped, but the (masked) interrupt has not counted it yet.
            if SCB::is_pendst_pending() {
                ms += 1;
                current = SYST::get_current();
            }
            let within = (CYCLES_PER_MS - 1).saturating_sub(current) / CYCLES_PER_TICK;
            ms * TICKS_PER_MS + u64::from(within)
        })
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| self.queue.borrow_ref_mut(cs).schedule_wake(at, waker));
    }
}

#[exception]
fn SysTick() {
    critical_section::with(|cs| {
        let ms = TIME.ms.borrow(cs).get() + 1;
        TIME.ms.borrow(cs).set(ms);
        TIME.queue
            .borrow_ref_mut(cs)
            .next_expiration(ms * TICKS_PER_MS);
    });
}
