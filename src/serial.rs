//! An RS485 line: a buffered UART with a driver enable, by hardware (the UART's DE output, USART
//! v3/v4 chips such as the L4) or by a GPIO set before a write and cleared once the last stop bit
//! has left (F1), and the operations the protocol asks of the bus (send then wait for
//! transmission complete, rate change, break).

use embassy_stm32::gpio::Output;
use embassy_stm32::usart::BufferedUart;
use embedded_io_async::{Read, ReadReady, Write};

use crate::pins::LineBreak;

/// One RS485 line. Receiving continues in the UART's ring buffer while the task awaits a send.
pub struct Rs485 {
    uart: BufferedUart<'static>,
    /// Size of the TX ring: a write never exceeds it (the driver refuses longer writes).
    tx_capacity: usize,
    /// How this line holds a break, if it is the bus.
    line_break: Option<LineBreak>,
    in_break: bool,
    /// The driver enable, if software drives it (no hardware DE on the chip).
    de: Option<Output<'static>>,
}

impl Rs485 {
    /// Wraps a UART: built with `new_with_de` (hardware DE, `de` is `None`), or without a DE
    /// pin, which `de` then is (driven low: the transmitter off).
    pub fn new(
        uart: BufferedUart<'static>,
        tx_capacity: usize,
        line_break: Option<LineBreak>,
        de: Option<Output<'static>>,
    ) -> Rs485 {
        Rs485 {
            uart,
            tx_capacity,
            line_break,
            in_break: false,
            de,
        }
    }

    /// Waits for received bytes; how many were copied (0 after a receive error, which is logged:
    /// the protocol sees the gap or the damaged frame and recovers by itself).
    pub async fn read(&mut self, buf: &mut [u8]) -> usize {
        match self.uart.read(buf).await {
            Ok(n) => n,
            Err(_) => {
                warn!("uart: receive error");
                0
            }
        }
    }

    /// The received bytes already buffered, without waiting (0 when none).
    pub async fn read_ready(&mut self, buf: &mut [u8]) -> usize {
        match self.uart.read_ready() {
            Ok(true) => self.read(buf).await,
            _ => 0,
        }
    }

    /// Transmits `bytes` and returns once the last stop bit has left (transmission complete), so
    /// that the line may turn around or change rate. Cancelling it is safe (bytes already queued
    /// are sent, the driver enable is dropped by hardware).
    pub async fn send(&mut self, bytes: &[u8]) {
        if self.in_break {
            // The node never sends during a break; if it did, the frame would be lost on a line
            // held low, so end the break first.
            warn!("uart: send during a break, break ended");
            self.break_end().await;
        }
        if let Some(de) = self.de.as_mut() {
            de.set_high();
        }
        for chunk in bytes.chunks(self.tx_capacity.max(1)) {
            // Flush after each chunk: the driver's `write` waits for free space without
            // registering a waker, so never write more than the empty ring holds.
            if self.uart.write_all(chunk).await.is_err() || self.uart.flush().await.is_err() {
                warn!("uart: transmit error");
                break;
            }
        }
        // `flush` returned: transmission complete, the line may turn around.
        if let Some(de) = self.de.as_mut() {
            de.set_low();
        }
    }

    /// Changes the rate (both directions) after any transmission in progress has completed.
    pub async fn set_baud(&mut self, bits_per_second: u32) {
        if self.uart.flush().await.is_err() || self.uart.set_baudrate(bits_per_second).is_err() {
            error!("uart: rate {} refused", bits_per_second);
        }
    }

    /// Changes rate and framing after any transmission in progress has completed.
    pub async fn set_config(&mut self, config: &embassy_stm32::usart::Config) {
        if self.uart.flush().await.is_err() || self.uart.set_config(config).is_err() {
            error!("uart: configuration refused");
        }
    }

    /// Waits until everything written has left the line.
    pub async fn flush(&mut self) {
        let _ = self.uart.flush().await;
    }

    /// Starts holding the line low (driver enabled), after any transmission has completed.
    pub async fn break_start(&mut self) {
        let _ = self.uart.flush().await;
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
    pub async fn break_end(&mut self) {
        if let Some(line_break) = &self.line_break {
            line_break.release();
        }
        if let Some(de) = self.de.as_mut() {
            de.set_low();
        }
        self.in_break = false;
    }
}
