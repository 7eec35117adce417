//! The runtime: the executor loop (embassy's raw executor, polled in thread mode, WFI between
//! polls: embassy's own thread executor sleeps with WFE, which busy-waits under QEMU), the time
//! driver's SysTick interrupt, the LAN9118's interrupt, and the panic and fault handlers (reported
//! over semihosting).

use core::panic::PanicInfo;
use core::sync::atomic::{AtomicBool, Ordering};

use cortex_m::interrupt::InterruptNumber;
use cortex_m::peripheral::SYST;
use cortex_m_rt::{exception, ExceptionFrame};
use embassy_executor::{raw, Spawner};
use static_cell::StaticCell;
use systick_time::SysTickTime;

/// Set by a waker (from a task or an interrupt): the executor has work.
static WORK: AtomicBool = AtomicBool::new(false);
static EXECUTOR: StaticCell<raw::Executor> = StaticCell::new();

/// Called by embassy when a task is woken.
#[unsafe(no_mangle)]
fn __pender(_context: *mut ()) {
    WORK.store(true, Ordering::Release);
}

/// The AN386's system clock, which SysTick counts (QEMU's hw/arm/mps2.c: `SYSCLK_FRQ`).
const SYSCLK_HZ: u32 = 25_000_000;

// embassy-time's driver: the SysTick driver the firmware's emulator build runs too.
systick_time::time_driver_impl!(static TIME: SysTickTime<SYSCLK_HZ> = SysTickTime::new());

/// Starts embassy-time's clock: the SysTick interrupt, every millisecond.
pub fn start_time(syst: SYST) {
    TIME.start(syst);
}

#[exception]
fn SysTick() {
    TIME.tick();
}

/// Runs `init` to spawn the tasks, then the executor, forever.
pub fn run(init: impl FnOnce(Spawner)) -> ! {
    let executor: &'static raw::Executor = EXECUTOR.init(raw::Executor::new(core::ptr::null_mut()));
    init(executor.spawner());
    loop {
        WORK.store(false, Ordering::Release);
        // SAFETY: `poll` is called only here, in thread mode, never re-entrantly; the executor is
        // 'static and every task was spawned through its own spawner.
        unsafe { executor.poll() };
        // Sleep unless something was woken meanwhile: with interrupts masked a wake between the
        // check and WFI leaves its interrupt pending, and WFI returns at once.
        cortex_m::interrupt::free(|_| {
            if !WORK.load(Ordering::Acquire) {
                cortex_m::asm::wfi();
            }
        });
    }
}

/// An external interrupt of the AN386, by its number (there is no PAC for the MPS2).
#[derive(Clone, Copy)]
pub struct Irq(pub u16);

// SAFETY: the number is one of the AN386's 32 external interrupts (hw/arm/mps2.c: num-irq 32).
unsafe impl InterruptNumber for Irq {
    fn number(self) -> u16 {
        self.0
    }
}

/// The LAN9118's interrupt line (hw/arm/mps2.c: `lan9118_init(..., 13)` for the AN385/AN386).
pub const ETH_IRQ: Irq = Irq(13);

/// Every external interrupt lands here (cortex-m-rt without a device crate); the only one
/// enabled is the LAN9118's.
#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    if irqn == ETH_IRQ.0 as i16 {
        lan9118::on_interrupt(&crate::ETH_STATE);
    }
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    crate::log!("HardFault at pc {:#x}", frame.pc());
    halt()
}

#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    match info.location() {
        Some(at) => crate::log!("panic at {}:{}", at.file(), at.line()),
        None => crate::log!("panic"),
    }
    halt()
}

/// Ends the emulator with a failure status (semihosting exit).
fn halt() -> ! {
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}
