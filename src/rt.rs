//! The runtime glue that needs `unsafe`, all of it here but the emulator's fault requests
//! ([`emu`](crate::emu)): the executor loop, the panic handler, the HardFault handler and the
//! handler of every other exception and interrupt (`DefaultHandler`: NMI, and any interrupt no
//! driver binds).
//!
//! The stack: flip-link (`.cargo/config.toml`) links the firmware with the stack at the bottom of
//! RAM, from `_stack_start` (right below `.data`) down to the start of RAM, and the statics above
//! it. An overflow therefore runs off the start of RAM, which faults (a bus fault, escalated to a
//! HardFault), instead of silently overwriting the statics. The core cannot stack the exception
//! frame there either, so the HardFault entry below moves to a stack of its own before any Rust
//! code runs.
//!
//! The executor is embassy's raw executor polled from thread mode, sleeping with WFI between
//! polls. (embassy's thread executor sleeps with WFE; under QEMU that busy-waits and starves the
//! SysTick time driver. WFI is as good on silicon, so both builds use this loop.)

use core::panic::PanicInfo;
use core::sync::atomic::{AtomicBool, Ordering};

use embassy_executor::{raw, Spawner};
use static_cell::StaticCell;

use crate::{emu, pins};

/// Set by a waker (from a task or an interrupt): the executor has work.
static WORK: AtomicBool = AtomicBool::new(false);
static EXECUTOR: StaticCell<raw::Executor> = StaticCell::new();

/// Called by embassy when a task of the executor is woken.
#[unsafe(no_mangle)]
fn __pender(_context: *mut ()) {
    WORK.store(true, Ordering::Release);
}

/// Builds the one large value the tasks share with `make`, runs `init` to spawn the tasks,
/// then the executor, forever.
///
/// The value (the protocol node, 11 KB) lives in this function's frame, built there in place
/// (`make`'s result is written straight into it), and is lent to the tasks for good.
// Rust has no placement into a `static`: a `StaticCell` would build it on the stack first and
// copy it (measured: 23 KB of stack at start-up), and a `static` with a const initializer costs
// its image in flash (11.4 KB of `.data`, a fifth of the F103's flash budget), though the node
// is nearly all zeros. Here it costs its size in RAM, as in `.bss`, counted in the measured
// stack.
pub fn run<T: 'static>(make: impl FnOnce() -> T, init: impl FnOnce(Spawner, &'static mut T)) -> ! {
    let executor: &'static raw::Executor = EXECUTOR.init(raw::Executor::new(core::ptr::null_mut()));
    let mut value = make();
    // SAFETY: `run` never returns and the firmware never unwinds (panics abort on these
    // targets, and the handler halts), so this frame and `value` in it outlive every task.
    // `value` is not named again: the reference handed out is the only way to it.
    let value: &'static mut T = unsafe { &mut *core::ptr::addr_of_mut!(value) };
    start(executor.spawner(), value, init);
    let mut load = emu::LoadMeter::start();
    loop {
        WORK.store(false, Ordering::Release);
        // SAFETY: `poll` is called only here, in thread mode, never re-entrantly; the executor is
        // 'static and every task was spawned on it through its own spawner.
        unsafe { executor.poll() };
        emu::serve_fault_requests();
        // Sleep unless something was woken meanwhile. Interrupts are masked for the check, so a
        // wake between the check and WFI leaves the interrupt pending, and WFI returns at once.
        cortex_m::interrupt::free(|_| {
            if !WORK.load(Ordering::Acquire) {
                load.asleep();
                cortex_m::asm::wfi();
                load.awake();
            }
        });
    }
}

/// `init`, in a frame of its own: the peripherals and the board it builds are moved into the
/// tasks and gone when it returns, instead of staying under every poll of the loop below.
// Measured: 832 bytes of stack under the whole firmware.
#[inline(never)]
fn start<T: 'static>(
    spawner: Spawner,
    value: &'static mut T,
    init: impl FnOnce(Spawner, &'static mut T),
) {
    init(spawner, value)
}

/// Outputs safe first, then the message, then stop (see [`halt`]).
#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    pins::force_safe();
    // On the board, no location: the file names of every place that can panic (the `Location`s
    // the handler would read) cost 6.9 KB of flash (measured on the F103 build), and a debug
    // probe shows where it stopped anyway (`probe-rs run` prints the backtrace at the `udf` of
    // `halt`). The message is never formatted: that would pull `core::fmt` in. The emulator,
    // whose flash is not counted, names the place for the harness (`emu::report_panic`).
    #[cfg(feature = "hw")]
    error!("panic (the probe's backtrace shows where)");
    emu::report_panic(info);
    halt()
}

// The HardFault entry, the symbol the vector table names (cortex-m-rt's `HardFault_` is only
// the default its link.x `PROVIDE`s). No Rust and no stack before `msr msp`: after a stack
// overflow the stack pointer lies below RAM (flip-link's layout), the core could not stack the
// exception frame, and the first push there would fault inside the HardFault handler, which locks
// the core up. So: r0 = the stack pointer of the code that faulted (the process stack if
// EXC_RETURN's bit 2 says so; the firmware runs everything on the main stack), then the main
// stack back to its top, `_stack_start` (right below `.data`), then the Rust handler. Whatever
// the faulting code kept at the top of the stack is overwritten: the handler never returns.
core::arch::global_asm!(
    ".section .text.HardFault,\"ax\",%progbits",
    ".global HardFault",
    ".type HardFault,%function",
    ".p2align 2",
    ".thumb_func",
    "HardFault:",
    "mrs r0, msp",
    "tst lr, #4",
    "it ne",
    "mrsne r0, psp",
    "movw r1, :lower16:_stack_start",
    "movt r1, :upper16:_stack_start",
    "msr msp, r1",
    "b {handler}",
    ".size HardFault, . - HardFault",
    handler = sym hard_fault,
);

unsafe extern "C" {
    /// The top of the stack (cortex-m-rt; with flip-link, right below `.data`): only its address.
    static _stack_start: u32;
    /// The bottom of the stack (cortex-m-rt; with flip-link, the start of RAM): only its address.
    static _stack_end: u32;
}

/// A bus fault, an undefined instruction, a stack overflow...: outputs safe, report where, then
/// reset (board) or halt (emulator). Runs on the stack `HardFault` gave it; `sp`: the stack pointer
/// of the code that faulted, where the core stacked the exception frame if it could.
extern "C" fn hard_fault(sp: u32) -> ! {
    fail_safe(|| {
        let bottom = core::ptr::addr_of!(_stack_end) as u32;
        let top = core::ptr::addr_of!(_stack_start) as u32;
        // The frame (r0-r3, r12, lr, pc, xpsr) is there only if it lies inside the stack; after
        // an overflow it does not (the stack pointer is below RAM), and reading it would fault
        // again. (This handler's own few dozen bytes at the top of the stack could overwrite a
        // frame only from a fault before `main`: past it, the run loop's frame holds the node.)
        if sp >= bottom && sp <= top.saturating_sub(32) {
            // SAFETY: eight words inside the stack region, 4-aligned (the core keeps SP so).
            let pc = unsafe { core::ptr::read_volatile((sp as *const u32).add(6)) };
            error!("HardFault at pc {:#x}, sp {:#x}", pc, sp);
        } else {
            error!("HardFault, sp {:#x} outside the stack: stack overflow", sp);
        }
    });
    // The emulator: halt, as after a panic, so that the harness can read the pins
    // (tests/emu/test_firmware.py). The board: start again.
    emu::halt_for_harness();
    reset()
}

/// NMI (exception 2) as cortex-m-rt numbers it for [`DefaultHandler`] (the exception's number
/// less 16, so that interrupts count from 0).
#[cfg(all(feature = "hw", feature = "board-l475"))]
const NMI: i16 = 2 - 16;

/// Every exception and interrupt without a handler of its own, which cortex-m-rt's vector table
/// points here (its own default spins, the outputs as they were, until the watchdog fires): NMI
/// (the clock security system on the F103 and F429, a flash ECC double error or an SRAM parity
/// error on the L475), any interrupt enabled with no driver bound to it, SVCall, PendSV, SysTick
/// on the boards (their time driver is a TIM), and the configurable faults (not enabled: they
/// escalate to HardFault). The same as a HardFault: outputs OFF and both drivers released first,
/// then a reset; in the emulator too (after the harness has read the pins), which halts only
/// after a HardFault or a panic.
///
/// One exception returns, on the L475: an ECC double error in a settings page (a record torn by
/// a power cut during a save) or in the DFU partition (a chunk's write torn), which fails the
/// read that hit it instead (`l475::DcacheOff`).
#[cortex_m_rt::exception]
unsafe fn DefaultHandler(irqn: i16) {
    #[cfg(all(feature = "hw", feature = "board-l475"))]
    if irqn == NMI && crate::board::l475::settings_ecc_error() {
        return;
    }
    fail_safe(|| error!("exception {} has no handler: reset", irqn + 16));
    reset()
}

/// What every fault does first: every output OFF, the alarm LED on, both RS485 drivers released
/// (`pins::force_safe`), then `report`. On the board not when the fault interrupted a critical
/// section (PRIMASK set: only an NMI or a HardFault can), which may have been defmt's, midway
/// through a log frame: a second frame would panic there ("taken reentrantly"), and a panic in
/// an NMI locks the core up until the watchdog. `#[inline(always)]`: one copy per handler, no
/// closure call.
#[inline(always)]
fn fail_safe(report: impl FnOnce()) {
    pins::force_safe();
    #[cfg(feature = "hw")]
    if cortex_m::register::primask::read().is_active() {
        return;
    }
    report();
}

/// After a fault: a system reset. The outputs stay OFF through it: every pin is an input from
/// reset until start-up drives it OFF, and the carrier's pull-downs hold the output stages and
/// the drivers' DE low meanwhile. The emulator waits first until the harness has read the pins
/// (bounded: `emu::hold_for_harness`).
fn reset() -> ! {
    emu::hold_for_harness();
    cortex_m::peripheral::SCB::sys_reset()
}

/// After a panic. On the board: an undefined instruction, which a debug probe (`probe-rs run`)
/// stops at, showing the log above; without a probe it is a HardFault, which resets the chip
/// (outputs stay OFF through the reset). In the emulator (after a panic or a HardFault): stay
/// halted with interrupts masked, so that the harness can read the pins
/// (`emu::halt_for_harness`, which never returns there).
fn halt() -> ! {
    emu::halt_for_harness();
    cortex_m::asm::udf()
}
