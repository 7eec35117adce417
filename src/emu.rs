//! The emulator build's hooks, all of them here: what the firmware does differently in QEMU
//! (`--features emulator`, QEMU's `b-l475e-iot01a`: `scripts/emu-build.sh`), and what the test
//! harness (`tests/pyshared/emu.py`) reads and writes in it through qtest.
//!
//! The product code calls every hook in both builds, without a `cfg` of its own. On the board
//! (feature `hw`, module `hw` below) each hook is an empty `#[inline(always)]` function, each
//! piece of state a zero-size type, and the one hook that awaits a macro that leaves no `await`
//! behind ([`wait_wire_time`]), so that the boards' code is what it would be without the calls
//! (checked with `scripts/size-report.sh` and by comparing the disassembly). In the emulator
//! (module `qemu`):
//!
//! | Hook | Where | What it does in QEMU |
//! |---|---|---|
//! | [`start_time`], [`watchdog_start`], [`watchdog_pet`] | start-up, `board::Watchdog` | the SysTick time driver (QEMU models no TIM) and a model of the IWDG on its interrupt (QEMU has no IWDG) |
//! | [`loosen_timing`] | start-up, on the node's defaults | no wire timing on the bus, reply slack, a 20 ms frame gap on the PLC line |
//! | [`Pace`] | `serial::Rs485` | a send lasts its wire time (QEMU's UART moves the bytes at once) |
//! | [`PulseTimer`], [`count_stop_wake`] | the I/O task | what the firmware saw of an input pulse; the stop input's interrupt wakes |
//! | [`serve_gateway_requests`] | the gateway task | a panic or a stall, on the harness' request |
//! | [`LoadMeter`], [`serve_fault_requests`] | the executor loop | the CPU load; a stack overflow, an NMI or an unbound interrupt on request |
//! | [`report_panic`], [`halt_for_harness`], [`hold_for_harness`] | the panic and fault handlers | the panic's place; halt, or hold the reset, until the harness has read the pins |

#[cfg(feature = "hw")]
pub use hw::*;
#[cfg(feature = "emulator")]
pub use qemu::*;

/// On the board: every hook does nothing (module `qemu` below says what each does in the
/// emulator).
#[cfg(feature = "hw")]
mod hw {
    use core::panic::PanicInfo;

    use protocol::pio::PioInputs;
    use protocol::plc::{GatewayConfig, Parity};

    /// The emulator's time driver: on the board, embassy-stm32's TIM driver, which starts itself.
    #[inline(always)]
    pub fn start_time() {}

    /// The emulator's model of the IWDG: the board's own runs.
    #[inline(always)]
    pub fn watchdog_start(_timeout_us: u32) {}

    /// The emulator's model of the IWDG.
    #[inline(always)]
    pub fn watchdog_pet() {}

    /// The emulator's timing: a wire has its own.
    #[inline(always)]
    pub fn loosen_timing(_config: &mut GatewayConfig) {}

    /// A send's wire time, which the board's UART takes by itself.
    pub struct Pace;

    impl Pace {
        #[inline(always)]
        pub const fn new() -> Pace {
            Pace
        }

        #[inline(always)]
        pub fn start(&mut self, _n: usize, _baud: u32, _parity: Parity) {}
    }

    /// The wait for a send's wire time ([`Pace`]): on the board nothing, not even an `await`.
    // A macro, not a function: the await of a future that is ready at once still adds a state to
    // the caller's future (measured: 24 bytes more of the F103's flash in `Rs485::settle`).
    macro_rules! wait_wire_time {
        ($pace:expr) => {};
    }
    pub(crate) use wait_wire_time;

    /// The span of an input's pulse, for the harness.
    pub struct PulseTimer;

    impl PulseTimer {
        #[inline(always)]
        pub const fn new() -> PulseTimer {
            PulseTimer
        }

        #[inline(always)]
        pub fn sample(&mut self, _now: embassy_time::Instant, _inputs: PioInputs) {}
    }

    /// The stop input's interrupt woke the I/O task: counted for the harness.
    #[inline(always)]
    pub fn count_stop_wake() {}

    /// The harness' requests to the gateway task.
    #[inline(always)]
    pub fn serve_gateway_requests() {}

    /// The CPU load, for `scripts/cpu-load.sh`.
    pub struct LoadMeter;

    impl LoadMeter {
        #[inline(always)]
        pub fn start() -> LoadMeter {
            LoadMeter
        }

        #[inline(always)]
        pub fn asleep(&mut self) {}

        #[inline(always)]
        pub fn awake(&mut self) {}
    }

    /// The harness' fault requests.
    #[inline(always)]
    pub fn serve_fault_requests() {}

    /// The panic's place: not on the board (`rt::panic` says why).
    #[inline(always)]
    pub fn report_panic(_info: &PanicInfo) {}

    /// Returns at once: the board does not wait for a harness.
    #[inline(always)]
    pub fn halt_for_harness() {}

    /// Returns at once: the board does not wait for a harness.
    #[inline(always)]
    pub fn hold_for_harness() {}
}

/// In QEMU.
#[cfg(feature = "emulator")]
mod qemu {
    use core::hint::black_box;
    use core::panic::PanicInfo;
    use core::sync::atomic::{AtomicBool, AtomicU32, AtomicU8, Ordering};

    use cortex_m::peripheral::{SCB, SYST};
    use cortex_m_rt::exception;
    use embassy_time::{Duration, Instant};
    use protocol::pio::PioInputs;
    use protocol::plc::{GatewayConfig, Parity};
    use systick_time::SysTickTime;

    // --- Time and the watchdog model ---------------------------------------------------------

    // embassy-time's driver: QEMU's `b-l475e-iot01a` models no TIM peripheral, which
    // embassy-stm32's time drivers need. The SysTick driver `emu-net`'s build runs too, at the
    // L475's core clock.
    systick_time::time_driver_impl!(
        static TIME: SysTickTime<{ crate::board::l475::SYSCLK_HZ }> = SysTickTime::new()
    );

    /// Starts the time driver's 1 ms interrupt (SysTick counts the L475's core cycles).
    pub fn start_time() {
        if let Some(core) = cortex_m::Peripherals::take() {
            TIME.start(core.SYST);
        }
    }

    /// Every millisecond: the expired timers woken, then the watchdog model.
    #[exception]
    fn SysTick() {
        let ms = TIME.tick();
        watchdog_check(ms as u32);
    }

    /// The model of the IWDG (QEMU has none), on the SysTick interrupt: the milliseconds it allows
    /// between two pets (0: not started), and the millisecond of the last pet. Like the IWDG, once
    /// started it cannot be stopped.
    static WATCHDOG_LIMIT_MS: AtomicU32 = AtomicU32::new(0);
    static WATCHDOG_PET_MS: AtomicU32 = AtomicU32::new(0);

    /// Starts the watchdog model: it resets the chip `timeout_us` after the last pet.
    pub fn watchdog_start(timeout_us: u32) {
        watchdog_pet();
        WATCHDOG_LIMIT_MS.store(timeout_us / 1000, Ordering::Relaxed);
    }

    /// Restarts the watchdog model's count, as `IndependentWatchdog::pet` does the IWDG's.
    pub fn watchdog_pet() {
        WATCHDOG_PET_MS.store(TIME.ms() as u32, Ordering::Relaxed);
    }

    /// On every SysTick: past the limit, what the IWDG does (a reset), with a line for the
    /// harness. QEMU resets the machine as the board would; the reset cause is not kept (QEMU
    /// models no reset flags, and the loader clears RAM), so RESETCAUSE does not say "watchdog"
    /// here as it does on the board.
    fn watchdog_check(now_ms: u32) {
        let limit = WATCHDOG_LIMIT_MS.load(Ordering::Relaxed);
        let since = now_ms.wrapping_sub(WATCHDOG_PET_MS.load(Ordering::Relaxed));
        if limit != 0 && since > limit {
            error!("watchdog: no progress for {} ms, reset", since);
            SCB::sys_reset();
        }
    }

    // --- The node's timing ---------------------------------------------------------------------

    /// QEMU's UART moves bytes without wire time: a command "leaves" at once, so an answer can
    /// complete sooner after the hand-over than a real line allows, and the emulator's virtual
    /// clock is only kept near real time. The earliest-answer bound is a property of a wire
    /// (`protocol::engine::Config::wire_timing`); on the board it stays on.
    /// And its host can stall QEMU for a few hundred ms with a controller's answer already sent
    /// (rc-sim keeps real time): the response time-outs get that much slack, so that a stall of
    /// the emulator is not taken for a silent axis. Its PLC line is a socket whose bytes the task
    /// may read in bursts further apart than t3.5: a frame ends after 20 ms of silence there.
    pub fn loosen_timing(config: &mut GatewayConfig) {
        config.bus.wire_timing = false;
        config.bus.reply_slack = protocol::time::Duration::from_millis(250);
        config.plc_frame_gap = Some(protocol::time::Duration::from_millis(20));
    }

    // --- The lines' wire time ------------------------------------------------------------------

    /// Until when the bytes an RS485 line started last are on the wire. Every line of the
    /// emulator build (the L475's two) is paced: a send lasts as long as its bytes would take on
    /// the wire, as on the board (QEMU's UART moves them at once), so that the emulator tests see
    /// a long PLC reply at a low rate as the board's gateway task does, and the gateway task
    /// waits for each bus command as on the board (16.7 ms at 9.6 kbit/s), which the input
    /// samples must survive.
    pub struct Pace {
        until: Option<Instant>,
    }

    impl Pace {
        /// Nothing on the wire.
        pub const fn new() -> Pace {
            Pace { until: None }
        }

        /// `n` bytes handed to the UART now, at `baud` with `parity`.
        pub fn start(&mut self, n: usize, baud: u32, parity: Parity) {
            self.until = Some(Instant::now() + char_time(baud, parity) * n as u32);
        }

        /// Until when the bytes started last are on the wire, unless they were waited for.
        pub fn until(&self) -> Option<Instant> {
            self.until
        }

        /// The bytes started last have left the wire.
        pub fn passed(&mut self) {
            self.until = None;
        }
    }

    /// Waits until the bytes a line started last ([`Pace`]) have left the wire: at once if they
    /// have, or if nothing was started since the last wait. Cancelling the wait is safe: the next
    /// one waits again. (A macro because the board's twin must leave no `await` behind.)
    macro_rules! wait_wire_time {
        ($pace:expr) => {
            if let Some(until) = $pace.until() {
                ::embassy_time::Timer::at(until).await;
                $pace.passed();
            }
        };
    }
    pub(crate) use wait_wire_time;

    /// The time one character takes: a start bit, 8 data bits, the parity bit if any, a stop
    /// bit; rounded up to the microsecond.
    fn char_time(baud: u32, parity: Parity) -> Duration {
        let bits: u64 = if matches!(parity, Parity::None) {
            10
        } else {
            11
        };
        Duration::from_micros((bits * 1_000_000).div_ceil(u64::from(baud.max(1))))
    }

    // --- The I/O task --------------------------------------------------------------------------

    /// How many times the stop input's interrupt woke the I/O task, read by the emulator tests
    /// (through QEMU's qtest, by its symbol) to prove the interrupt path.
    #[used]
    static EMU_STOP_WAKES: AtomicU32 = AtomicU32::new(0);

    /// The span between the first and the last sample that read an input of [`EMU_PULSE_MASK`]
    /// ON in its latest pulse, µs, read by the emulator tests (qtest, by its symbol): what the
    /// firmware saw of a pulse the harness timed on the host, whose own timing QEMU does not
    /// keep under load.
    #[used]
    static EMU_CSTR_SPAN_US: AtomicU32 = AtomicU32::new(0);

    /// The inputs whose pulses [`EMU_CSTR_SPAN_US`] times (bit n = INn; CSTR until a test writes
    /// another mask, such as an ST input's).
    #[used]
    static EMU_PULSE_MASK: AtomicU32 = AtomicU32::new(PioInputs::CSTR.bits() as u32);

    /// The stop input's interrupt woke the I/O task.
    pub fn count_stop_wake() {
        EMU_STOP_WAKES.fetch_add(1, Ordering::Relaxed);
    }

    /// Times the pulses of [`EMU_PULSE_MASK`]'s inputs for [`EMU_CSTR_SPAN_US`].
    pub struct PulseTimer {
        /// When the pulse under way was first sampled ON, the low 32 bits of its µs.
        first_on: Option<u32>,
    }

    impl PulseTimer {
        /// No pulse under way.
        pub const fn new() -> PulseTimer {
            PulseTimer { first_on: None }
        }

        /// The inputs, as sampled at `now`.
        pub fn sample(&mut self, now: Instant, inputs: PioInputs) {
            let us = now.as_micros() as u32;
            let mask = EMU_PULSE_MASK.load(Ordering::Relaxed);
            let on = u32::from(inputs.bits()) & mask != 0;
            self.first_on = on.then(|| self.first_on.unwrap_or(us));
            if let Some(first) = self.first_on {
                EMU_CSTR_SPAN_US.store(us.wrapping_sub(first), Ordering::Relaxed);
            }
        }
    }

    // --- The gateway task ----------------------------------------------------------------------

    /// The harness writes `true` here (QEMU's qtest, found by its symbol) to make the gateway
    /// task panic, so that the fail-safe is proven on the real ELF. `#[used]`: nothing in the
    /// program stores to it, which would otherwise let the compiler drop the check.
    #[used]
    static EMU_PANIC: AtomicBool = AtomicBool::new(false);

    /// The harness writes `true` here to make the gateway task stop making progress (it spins
    /// without yielding), so that the watchdog model ([`watchdog_start`]) is shown to reset a
    /// stuck firmware.
    #[used]
    static EMU_STALL: AtomicBool = AtomicBool::new(false);

    /// On every pass of the gateway task's loop: [`EMU_PANIC`], [`EMU_STALL`]. The panic names the
    /// gateway task's line (`#[track_caller]`).
    #[track_caller]
    pub fn serve_gateway_requests() {
        if EMU_PANIC.load(Ordering::Relaxed) {
            panic!("requested by the emulator harness");
        }
        while EMU_STALL.load(Ordering::Relaxed) {
            core::hint::spin_loop();
        }
    }

    // --- The runtime ---------------------------------------------------------------------------

    /// µs spent outside WFI since start (wraps after 71 minutes: read by difference).
    #[used]
    static EMU_BUSY_US: AtomicU32 = AtomicU32::new(0);
    /// The time of the last `asleep`, µs since start (the window the busy time is taken over).
    #[used]
    static EMU_CLOCK_US: AtomicU32 = AtomicU32::new(0);

    fn now_us() -> u32 {
        // Wraps with the statics: the harness reads differences.
        Instant::now().as_micros() as u32
    }

    /// How much of the time the CPU is not asleep in WFI, for `scripts/cpu-load.sh`, which runs
    /// QEMU with `-icount` (guest time then follows the instructions executed) and reads
    /// [`EMU_BUSY_US`] and [`EMU_CLOCK_US`] through qtest. The interrupt handlers that a wake runs
    /// count as busy: they run right after `awake`, before the next `asleep`.
    pub struct LoadMeter {
        woke: u32,
    }

    impl LoadMeter {
        pub fn start() -> LoadMeter {
            LoadMeter { woke: now_us() }
        }

        pub fn asleep(&mut self) {
            let now = now_us();
            EMU_BUSY_US.fetch_add(now.wrapping_sub(self.woke), Ordering::Relaxed);
            EMU_CLOCK_US.store(now, Ordering::Relaxed);
        }

        pub fn awake(&mut self) {
            self.woke = now_us();
        }
    }

    pub use requests::{hold_for_harness, serve_fault_requests};

    /// Faults on request, to prove the handlers on the real ELF (tests/emu): a stack overflow
    /// (`test_stack_overflow_faults_and_leaves_outputs_safe` in tests/emu/test_firmware.py), an NMI
    /// and an interrupt without a handler (tests/emu/test_faults.py). The firmware's only `unsafe`
    /// outside `rt`.
    #[allow(unsafe_code)]
    mod requests {
        use super::*;
        use embassy_stm32::interrupt::{self, InterruptExt};

        /// Set by the harness through qtest, by its symbol (`request_stack_overflow` in
        /// tests/pyshared/emu.py). `#[used]` and an atomic, like [`EMU_PANIC`]: nothing in the
        /// program stores to it, which would otherwise let the compiler drop the check.
        #[used]
        static EMU_OVERFLOW: AtomicBool = AtomicBool::new(false);

        /// Set by the harness (`request_fault`): [`NMI`] or [`UNBOUND_IRQ`].
        #[used]
        static EMU_FAULT_REQUEST: AtomicU8 = AtomicU8::new(0);
        const NMI: u8 = 1;
        const UNBOUND_IRQ: u8 = 2;
        /// Set by the harness once it has read the pins after a fault that resets
        /// (`release_fault`).
        #[used]
        static EMU_FAULT_SEEN: AtomicBool = AtomicBool::new(false);

        /// Checked after every poll of the executor (every wake).
        pub fn serve_fault_requests() {
            if EMU_OVERFLOW.load(Ordering::Relaxed) {
                black_box(recurse(0));
            }
            match EMU_FAULT_REQUEST.swap(0, Ordering::Relaxed) {
                // SCB ICSR NMIPENDSET: the NMI, taken at once.
                // SAFETY: a write to a system control register, whose only effect is the NMI.
                NMI => unsafe { (*SCB::PTR).icsr.write(1 << 31) },
                // SWPMI1: no peripheral this firmware uses, so no handler is bound to it (its
                // vector is cortex-m-rt's `DefaultHandler`). Enabled, then pended in the NVIC.
                UNBOUND_IRQ => {
                    // SAFETY: unmasking an interrupt only runs its handler, which is the point.
                    unsafe { interrupt::SWPMI1.enable() };
                    interrupt::SWPMI1.pend();
                }
                _ => {}
            }
        }

        /// Before a fault's reset: holds it until the harness has read the pins
        /// ([`EMU_FAULT_SEEN`]), at most 10 s, counted in SysTick wraps (1 ms each, the time
        /// driver's), which go on with its interrupt held off by the fault's handler.
        pub fn hold_for_harness() {
            // SAFETY: a read of SysTick's control register (it clears COUNTFLAG, which the time
            // driver does not use; the reset follows anyway).
            let wrapped = || unsafe { (*SYST::PTR).csr.read() } & 1 << 16 != 0;
            let mut ms = 0u32;
            while !EMU_FAULT_SEEN.load(Ordering::Relaxed) && ms < 10_000 {
                if wrapped() {
                    ms += 1;
                }
            }
        }

        /// Recursion without bound, 512 bytes of stack a level: the array is handed to
        /// `black_box` (so it is really in the frame) and read after the call (so the call is not
        /// a tail call).
        #[inline(never)]
        fn recurse(depth: u32) -> u32 {
            let mut frame = [0u8; 512];
            black_box(&mut frame);
            if black_box(depth) == u32::MAX {
                return 0;
            }
            recurse(depth + 1).wrapping_add(u32::from(frame[depth as usize % frame.len()]))
        }
    }

    /// The panic's place (file and line), for the harness: the emulator's flash is not counted.
    #[inline(always)]
    pub fn report_panic(info: &PanicInfo) {
        match info.location() {
            Some(at) => error!("panic at {}:{}", at.file(), at.line()),
            None => error!("panic"),
        }
    }

    /// After a panic or a HardFault: stays halted with interrupts masked, so that the harness can
    /// read the pins (tests/emu/test_firmware.py). Never returns (typed `()` as on the board,
    /// whose twin returns at once, so that the caller's code after it reads the same in both).
    #[inline(always)]
    pub fn halt_for_harness() {
        cortex_m::interrupt::disable();
        loop {
            cortex_m::asm::wfi();
        }
    }
}
