use core::cell::{Cell, RefCell};
use core::task::Waker;

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{SCB, SYST};
use critical_section::Mutex;
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

/// The time driver for a core clocked at `SYSCLK_HZ` (the cycles SysTick counts), in a `static`
/// declared with [`time_driver_impl!`](crate::time_driver_impl).
pub struct SysTickTime<const SYSCLK_HZ: u32> {
    /// Milliseconds counted by the interrupt.
    ms: Mutex<Cell<u64>>,
    queue: Mutex<RefCell<Queue>>,
}

impl<const SYSCLK_HZ: u32> SysTickTime<SYSCLK_HZ> {
    const TICKS_PER_MS: u64 = embassy_time_driver::TICK_HZ / 1000;
    /// Core cycles in a millisecond (SysTick's period).
    const CYCLES_PER_MS: u32 = SYSCLK_HZ / 1000;
    /// Core cycles in a tick: a whole number, or the driver does not build.
    const CYCLES_PER_TICK: u32 = {
        let cycles = Self::CYCLES_PER_MS / Self::TICKS_PER_MS as u32;
        assert!(
            cycles * Self::TICKS_PER_MS as u32 == Self::CYCLES_PER_MS,
            "a tick is not a whole number of core cycles"
        );
        cycles
    };

    /// The driver at 0 ms, not yet counting ([`SysTickTime::start`]).
    #[allow(clippy::new_without_default)]
    pub const fn new() -> Self {
        SysTickTime {
            ms: Mutex::new(Cell::new(0)),
            queue: Mutex::new(RefCell::new(Queue::new())),
        }
    }

    /// Starts the 1 ms interrupt: SysTick counts `SYSCLK_HZ` core cycles.
    pub fn start(&self, mut syst: SYST) {
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(Self::CYCLES_PER_MS - 1);
        syst.clear_current();
        syst.enable_interrupt();
        syst.enable_counter();
    }

    /// Counts a millisecond and wakes the timers it expired: the SysTick handler's work. The
    /// milliseconds since [`SysTickTime::start`], this one counted.
    pub fn tick(&self) -> u64 {
        critical_section::with(|cs| {
            let ms = self.ms.borrow(cs).get() + 1;
            self.ms.borrow(cs).set(ms);
            self.queue
                .borrow_ref_mut(cs)
                .next_expiration(ms * Self::TICKS_PER_MS);
            ms
        })
    }

    /// The milliseconds the interrupt has counted.
    pub fn ms(&self) -> u64 {
        critical_section::with(|cs| self.ms.borrow(cs).get())
    }
}

impl<const SYSCLK_HZ: u32> Driver for SysTickTime<SYSCLK_HZ> {
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
            let within = (Self::CYCLES_PER_MS - 1).saturating_sub(current) / Self::CYCLES_PER_TICK;
            ms * Self::TICKS_PER_MS + u64::from(within)
        })
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| {
            self.queue.borrow_ref_mut(cs).schedule_wake(at, waker);
        });
    }
}
