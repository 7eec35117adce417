//! An RS485 line: a buffered UART with a driver enable, by hardware (the UART's DE output, USART
//! v3/v4 chips such as the L4) or by a GPIO set before a write and cleared once the last stop bit
//! has left (F1), and the operations the protocol asks of the line (send, wait for transmission
//! complete, rate and framing change, break).
//!
//! A send has two halves: [`Rs485::start_send`] puts the bytes into the UART's ring, which its
//! interrupt empties onto the wire, and [`Rs485::settle`] waits until the last stop bit has left
//! and releases the driver. The gateway task starts a PLC reply and goes on with the bus, the
//! stop input and the watchdog while it is on the wire (a 255-byte reply lasts 2.3 s at
//! 1.2 kbit/s with parity), settling the line at every await ([`Rs485::settle_then`]).

use core::future::Future;
use core::pin::Pin;

use embassy_futures::select::select;
use embassy_stm32::gpio::Output;
use embassy_stm32::usart::BufferedUart;
use embedded_io_async::{Read, ReadReady, Write};
use protocol::plc::Parity;

use crate::board::{line_config, UartRegs};
use crate::emu;
use crate::pins::LineBreak;

/// One RS485 line. Receiving continues in the UART's ring buffer while the task awaits a send.
pub struct Rs485 {
    uart: BufferedUart<'static>,
    /// The UART's registers, for the transmission-complete check the driver's own can miss.
    regs: UartRegs,
    /// How this line holds a break, if it is the bus.
    line_break: Option<LineBreak>,
    in_break: bool,
    /// The driver enable, if software drives it (no hardware DE on the chip).
    de: Option<Output<'static>>,
    /// The rate and parity in force (what a refused change falls back to).
    baud: u32,
    parity: Parity,
    /// Bytes have been started and not yet settled.
    sending: bool,
    /// The emulator's wire time (QEMU moves the bytes at once; nothing on the board).
    pace: emu::Pace,
}

impl Rs485 {
    /// Wraps a UART running at `baud` and `parity` ([`line_config`]): built with `new_with_de`
    /// (hardware DE, `de` is `None`), or without a DE pin, which `de` then is (driven low: the
    /// transmitter off).
    pub fn new(
        uart: BufferedUart<'static>,
        regs: UartRegs,
        (baud, parity): (u32, Parity),
        line_break: Option<LineBreak>,
        de: Option<Output<'static>>,
    ) -> Rs485 {
        Rs485 {
            uart,
            regs,
            line_break,
            in_break: false,
            de,
            baud,
            parity,
            sending: false,
            pace: emu::Pace::new(),
        }
    }

    /// Waits for received bytes; how many were copied. Framing, parity, noise and overrun
    /// errors do not come back here (embassy-stm32 0.6.0 logs them in its interrupt, at `warn`,
    /// and keeps the byte or drops it): the protocol sees the damaged frame or the gap and
    /// recovers by itself.
    pub async fn read(&mut self, buf: &mut [u8]) -> usize {
        self.uart.read(buf).await.unwrap_or(0)
    }

    /// The received bytes already buffered, without waiting (0 when none, and while a send on
    /// this line has not settled: the other end answers only after it, so what is there is read
    /// once the line has settled, and a reply is never started behind an unsettled one).
    /// (Not `async`: with bytes buffered, the blocking read returns them at once; no state
    /// machine of its own, nor one per call in the gateway task.)
    pub fn read_ready(&mut self, buf: &mut [u8]) -> usize {
        if self.sending {
            return 0;
        }
        match self.uart.read_ready() {
            Ok(true) => embedded_io::Read::read(&mut self.uart, buf).unwrap_or(0),
            _ => 0,
        }
    }

    /// Transmits `bytes` and returns once the last stop bit has left (transmission complete), so
    /// that the line may turn around or change rate.
    pub async fn send(&mut self, bytes: &[u8]) {
        self.start_send(bytes).await;
        self.settle().await;
    }

    /// Drives the line and hands `bytes` to the UART, which sends them while the caller goes on;
    /// [`Rs485::settle`] waits for the end. Only on a settled line: a frame handed over while the
    /// last one is still on the wire is dropped (logged), not waited for.
    pub async fn start_send(&mut self, bytes: &[u8]) {
        if self.sending {
            // Cannot happen: the bus settles every frame, and nothing is read from the PLC line
            // (so no request comes to be answered) until its reply has settled. Waiting here
            // could hold the gateway task for a whole reply (2.3 s at 1.2 kbit/s); a master
            // whose reply is dropped asks again.
            warn!("uart: frame dropped, the line is still sending");
            return;
        }
        if self.in_break {
            // The node never sends during a break; if it did, the frame would be lost on a line
            // held low, so end the break first.
            warn!("uart: send during a break, break ended");
            self.break_end();
        }
        if let Some(de) = self.de.as_mut() {
            de.set_high();
        }
        self.sending = true;
        self.pace.start(bytes.len(), self.baud, self.parity);
        // One write: a frame always fits the empty ring (a PLC ADU is 256 bytes at most, a bus
        // frame 16), and the driver's `write` takes all of it or waits for room without
        // registering a waker; a longer one it refuses.
        if self.uart.write(bytes).await.is_err() {
            warn!("uart: transmit error");
        }
    }

    /// Waits until everything started has left the line, then releases the driver. At once when
    /// nothing was started; cancelling it is safe (the next call waits again).
    pub async fn settle(&mut self) {
        if !self.sending {
            return;
        }
        let _ = self.uart.flush().await;
        // embassy-stm32 0.6.0 can report completion early: its interrupt enables the
        // transmission-complete interrupt when the slice it takes from the TX ring has one byte
        // left, which is also the byte before the ring wraps; served late, after that byte has
        // left, it takes TC for the end of the whole transmission, and then goes on with the
        // bytes after the wrap. Its interrupt enables say whether it has (`UartRegs`); until
        // they do (rarely, and never longer than the rest of the frame), the other tasks run
        // between looks.
        while !self.regs.transmission_complete() {
            embassy_futures::yield_now().await;
        }
        // The emulator's wire time, once the UART is done (nothing on the board).
        emu::wait_wire_time!(self.pace);
        // Transmission complete: the line may turn around (unless a break holds it).
        if let Some(de) = self.de.as_mut().filter(|_| !self.in_break) {
            de.set_low();
        }
        self.sending = false;
    }

    /// Runs `work` while settling this line: a send that ends meanwhile releases its driver at
    /// once, whatever `work` waits for (a PLC reply ending while the task sends on the bus).
    /// (Not generic: one copy for every kind of work.)
    pub async fn settle_then(&mut self, work: Pin<&mut dyn Future<Output = ()>>) {
        let settle = async {
            self.settle().await;
            core::future::pending::<()>().await
        };
        select(work, settle).await;
    }

    /// Changes the rate (both directions) after any transmission in progress has completed.
    /// (Not `async`: the caller awaits `set_line`'s future itself, without a state machine of
    /// this wrapper's around it.)
    pub fn set_baud(&mut self, bits_per_second: u32) -> impl Future<Output = ()> + '_ {
        let parity = self.parity;
        self.set_line(bits_per_second, parity)
    }

    /// Changes rate and framing after any transmission in progress has completed. A change the
    /// UART refuses (a divider its clock cannot make) leaves the line as it was: the driver has
    /// disabled the UART and its interrupt by then, and the old settings enable them again.
    pub async fn set_line(&mut self, baud: u32, parity: Parity) {
        self.flush().await;
        for (baud, parity) in [(baud, parity), (self.baud, self.parity)] {
            if self.uart.set_config(&line_config(baud, parity)).is_ok() {
                self.baud = baud;
                self.parity = parity;
                return;
            }
            error!("uart: rate {} refused", baud);
        }
    }

    /// Waits until everything written has left the line. (Not `async`, as `set_baud`.)
    pub fn flush(&mut self) -> impl Future<Output = ()> + '_ {
        self.sending = true;
        self.settle()
    }

    /// Starts holding the line low (driver enabled), after any transmission has completed.
    pub async fn break_start(&mut self) {
        self.flush().await;
        match &self.line_break {
            Some(line_break) => {
                if let Some(de) = self.de.as_mut() {
                    de.set_high();
                }
                line_break.hold();
                self.in_break = true;
            }
            None => warn!("uart: this line cannot hold a break"),
        }
    }

    /// Ends the break: the line idles high again and the driver is released.
    pub fn break_end(&mut self) {
        if let Some(line_break) = &self.line_break {
            line_break.release();
        }
        if let Some(de) = self.de.as_mut() {
            de.set_low();
        }
        self.in_break = false;
    }
}
