//! The gateway task: the only user of the protocol [`Node`] (built in place at start-up and lent
//! to this task for good: [`rt::run`](crate::rt::run)) and the owner of the two lines around it
//! (the pins are the I/O task's).
//!
//! One loop, no locks (every node call is synchronous and short):
//! wait for bus bytes, PLC bytes, an input sample from the I/O task ([`io`](crate::io)) or the
//! node's own deadline; feed what came and everything else already waiting (ingress before
//! egress); then carry out the node's actions until it has none; tell the I/O task what the
//! outputs and LEDs show; feed the watchdog.
//!
//! With Ethernet (feature `net`), the socket tasks' events ([`crate::net::PORT`]) are one more
//! thing to wait for; `rc_net`'s two calls, the same as the emulator's network build makes, hand
//! them to the node before egress and again after it (`Port::pump`) and carry out its TCP
//! actions (`Port::act`): its replies go into the sockets' send pipes, never waiting on a client.
//!
//! No await in the loop lasts longer than a bus frame (16.7 ms at 9.6 kbit/s), a rate change or
//! a flash write: a PLC reply is handed to its UART and left to it (255 bytes take 2.3 s at
//! 1.2 kbit/s with parity, longer than the watchdog's timeout), and its line is settled (the
//! driver released once the last stop bit has left) at every await that follows. So the stop
//! input, the bus and the watchdog are served while a long reply is on the wire.

use core::pin::pin;
#[cfg(feature = "net")]
use core::{future::Future, pin::Pin};

#[cfg(feature = "net")]
use embassy_futures::select::{select, Either};
use embassy_futures::select::{select4, Either4};
use embassy_time::Timer;

use crate::board::Board;
use crate::emu;
use crate::io::{self, Sample, SAMPLED};
#[cfg(feature = "net")]
use crate::net::PORT;
use crate::node::{Action, Instant, Node};
use crate::serial::Rs485;
use crate::settings::SavedSettings;
use protocol::line::LineAction;
use protocol::plc::SettingsRequest;

/// The loop passes at least this often, whatever happens on the lines: it feeds the watchdog
/// and blinks the run LED (through the I/O task).
const HEARTBEAT: protocol::time::Duration = protocol::time::Duration::from_millis(100);

/// [`io::INDICATORS_PERIOD`] as the node counts time.
const INDICATORS_PERIOD: protocol::time::Duration =
    protocol::time::Duration(io::INDICATORS_PERIOD.as_micros());

/// Now, as the protocol counts time (µs since boot).
fn now() -> Instant {
    Instant(embassy_time::Instant::now().as_micros())
}

/// Sleeps until the node's deadline (forever if it has none).
async fn deadline(at: Option<Instant>) {
    match at {
        Some(Instant(us)) => Timer::at(embassy_time::Instant::from_micros(us)).await,
        None => core::future::pending().await,
    }
}

/// Reads the bus, but not before `hold`: until then the frame that has started is still coming
/// in ([`Node::bus_frame_due`]), and its bytes wait in the UART's buffer. A wake per frame
/// instead of one per byte (32 per transaction, with the echo): measured by `scripts/cpu-load.sh`.
async fn bus_read(bus: &mut Rs485, buf: &mut [u8], hold: Option<Instant>) -> usize {
    if let Some(Instant(us)) = hold {
        Timer::at(embassy_time::Instant::from_micros(us)).await;
    }
    bus.read(buf).await
}

/// Reads the PLC line once the reply on it, if any, has left: the PLC sends its next request
/// only after it, and the receiver is off while the driver is on.
async fn plc_read(plc: &mut Rs485, buf: &mut [u8]) -> usize {
    plc.settle().await;
    plc.read(buf).await
}

/// How often [`fed`] feeds the watchdog, and for how long at most: the longest PLC reply on the
/// wire, 256 bytes of 11 bits at 1.2 kbit/s (2.35 s), rounded up.
#[cfg(feature = "net")]
const FEEDS: u32 = 25;
#[cfg(feature = "net")]
const _: () = assert!(
    FEEDS as u64 * HEARTBEAT.0 >= 256 * 11 * 1_000_000 / 1200
        && FEEDS as u64 * HEARTBEAT.0 < 3_000_000
);

/// Waits for `work` (the PLC line to finish the reply on the wire) feeding the watchdog every
/// [`HEARTBEAT`] meanwhile, for as long as the longest reply lasts at most ([`FEEDS`]; a UART
/// stuck past it still ends in a reset). With Modbus TCP a SAVE, FACTORY, RESTART or line change
/// can come over the network while an RTU reply of any length is on the wire (2.3 s at
/// 1.2 kbit/s, against the watchdog's shortest 0.67 s): without the feeding the board reset, and
/// the save was lost. Over RTU the reply is the one to the write that asked, 8 bytes (73 ms at
/// 1.2 kbit/s), so the other boards wait without it.
#[cfg(feature = "net")]
async fn fed(watchdog: &mut crate::board::Watchdog, work: Pin<&mut dyn Future<Output = ()>>) {
    let feed = async {
        for _ in 0..FEEDS {
            Timer::after(embassy_time::Duration::from_micros(HEARTBEAT.0)).await;
            watchdog.pet();
        }
        core::future::pending::<()>().await
    };
    select(work, feed).await;
}

/// Runs the gateway forever.
#[embassy_executor::task]
pub async fn run(
    board: &'static mut Board,
    settings: &'static mut SavedSettings,
    boot: Sample,
    node: &'static mut Node,
) -> ! {
    // What one read takes out of a UART's ring buffer: a bus frame is 16 bytes (read once it is
    // whole), and a long PLC request comes in a few reads (the loop below reads until empty).
    let mut bus_buf = [0u8; 32];
    let mut plc_buf = [0u8; 32];
    // The UARTs start at the node's settings.
    board.bus.set_baud(node.bus_baud().bits_per_second()).await;
    let plc = node.plc_line();
    board
        .plc
        .set_line(plc.baud.bits_per_second(), plc.parity)
        .await;
    // The harness waits for this line: both UARTs receive at their settings from now on.
    info!("ready");
    // The DFU partition, if the board has one (feature `update`): until the node is told, an
    // image is refused (02).
    #[cfg(feature = "update")]
    let mut dfu = crate::dfu::Dfu::new();
    #[cfg(all(feature = "update", feature = "hw"))]
    let partition = settings.flash().is_some();
    #[cfg(all(feature = "update", feature = "emulator"))]
    let partition = true;
    #[cfg(feature = "update")]
    if partition {
        node.set_update_target(crate::dfu::Dfu::target());
        node.set_boot_state(dfu.start_up(settings));
    }
    let mut stop = boot.stop;
    node.set_stop_input(now(), stop);
    node.sample_inputs(now(), boot.inputs);
    let mut indicators_at = Instant::ZERO;
    // The clock as the last pass left it: the heartbeat and the indicators' period count from
    // there, so that a pass reads the clock only where the node needs it (each reading costs a
    // critical section; `scripts/cpu-load.sh` counts them).
    let mut clock = now();

    loop {
        let hold = node.bus_frame_due();
        // With a DFU job under way the wait is only a look at the lines: its next step follows
        // (unless the bus is not quiet: then the job waits, and the loop with it), or, while the
        // flash erases a sector by itself, a short sleep before the next look.
        #[cfg(feature = "update")]
        let heartbeat = if dfu.busy() && node.quiet_for_flash() {
            dfu.step_in()
        } else {
            HEARTBEAT
        };
        #[cfg(not(feature = "update"))]
        let heartbeat = HEARTBEAT;
        let lines = select4(
            bus_read(&mut board.bus, &mut bus_buf, hold),
            plc_read(&mut board.plc, &mut plc_buf),
            SAMPLED.wait(),
            deadline(protocol::time::earliest(
                node.poll_at(),
                Some(clock + heartbeat),
            )),
        );
        #[cfg(not(feature = "net"))]
        let event = lines.await;
        // A network event counts as the deadline's wake: it is handed to the node with the
        // others queued, after the ingress below (`rc_net::Port::pump`).
        #[cfg(feature = "net")]
        let event = match select(lines, PORT.ready()).await {
            Either::First(event) => event,
            Either::Second(()) => Either4::Fourth(()),
        };
        // The task was waiting on both lines until now: what either holds came just now.
        clock = now();
        match event {
            Either4::First(n) => node.bus_received(clock, bytes(&bus_buf, n)),
            Either4::Second(n) => node.plc_received(clock, bytes(&plc_buf, n)),
            Either4::Third(()) => samples(node, &mut stop, clock),
            Either4::Fourth(()) => {}
        }
        // The emulator harness' panic and stall (nothing on the board).
        emu::serve_gateway_requests();
        // The node's actions one at a time, the lines read before each: what has arrived goes
        // in before anything goes out, and a PLC request whose bytes came in while the task sent
        // on the bus is taken whole, not cut where the task stopped reading
        // (`Node::plc_received_between`); nor does the node see its end at a silence that was
        // the send.
        loop {
            loop {
                let n = board.bus.read_ready(&mut bus_buf);
                let m = board.plc.read_ready(&mut plc_buf);
                if n == 0 && m == 0 {
                    break;
                }
                let at = now();
                if n > 0 {
                    node.bus_received(at, bytes(&bus_buf, n));
                }
                if m > 0 {
                    node.plc_received_between(clock, at, bytes(&plc_buf, m));
                }
            }
            // The lines' buffers were empty at this time (`clock` in the reads above).
            clock = now();
            // With Ethernet, what the sockets hold goes in too; while they gave the node
            // something, it is polled again (a request that got no reply leaves room that no
            // reply refills).
            #[cfg(feature = "net")]
            let gave = PORT.pump(node, clock);
            let Some(action) = node.poll(clock) else {
                #[cfg(feature = "net")]
                if gave {
                    continue;
                }
                break;
            };
            let Board {
                bus, plc, watchdog, ..
            } = &mut *board;
            match action {
                // COMM_CHANGE goes out as a frame does: one send (and one await) for both.
                Action::Bus(_) | Action::Line(LineAction::CommChange) => {
                    let bytes = match action {
                        Action::Bus(frame) => frame,
                        _ => protocol::frame::COMM_CHANGE,
                    };
                    plc.settle_then(pin!(bus.send(&bytes))).await;
                }
                // Left to the UART: see the module documentation.
                Action::Reply(reply) => plc.start_send(reply).await,
                Action::Line(LineAction::SetBaud(baud)) => {
                    plc.settle_then(pin!(bus.set_baud(baud.bits_per_second())))
                        .await
                }
                Action::Line(LineAction::BreakStart) => {
                    plc.settle_then(pin!(bus.break_start())).await
                }
                Action::Line(LineAction::BreakEnd) => bus.break_end(),
                // After the reply to the write that asked for it has left.
                #[cfg(not(feature = "net"))]
                Action::PlcLine(line) => {
                    plc.set_line(line.baud.bits_per_second(), line.parity).await
                }
                // Asked over TCP, the reply on the PLC line may be any, up to 2.3 s long.
                #[cfg(feature = "net")]
                Action::PlcLine(line) => {
                    fed(
                        watchdog,
                        pin!(plc.set_line(line.baud.bits_per_second(), line.parity)),
                    )
                    .await
                }
                Action::Settings(request) => {
                    // The reply to the write that asked for it leaves first: on the F103 an
                    // erase stops the CPU, and with it the interrupt that feeds the UART, for
                    // 20-40 ms; a restart would cut it.
                    #[cfg(not(feature = "net"))]
                    plc.settle().await;
                    #[cfg(feature = "net")]
                    fed(watchdog, pin!(plc.settle())).await;
                    // A whole watchdog period for the erase, not what the wait for the reply
                    // left of it (the F429 feeds it again before each 16 KiB sector, 0.5 s
                    // at most: `board::f429::SettingsSectors`).
                    watchdog.pet();
                    match request {
                        SettingsRequest::Save => {
                            let saved = settings.save(&node.settings_record());
                            node.stored(saved);
                        }
                        SettingsRequest::FactoryReset | SettingsRequest::Restart => {
                            if matches!(request, SettingsRequest::FactoryReset) {
                                settings.factory_reset();
                            }
                            cortex_m::peripheral::SCB::sys_reset();
                        }
                    }
                }
                #[cfg(feature = "net")]
                Action::Tcp(tcp) => PORT.act(tcp, node, clock),
                // A chunk written here; an erase or a check taken here and carried out in
                // steps below, one per pass.
                #[cfg(feature = "update")]
                Action::Update(job) => {
                    if let Some(outcome) = dfu.start(&job, settings) {
                        crate::dfu::report(node, outcome);
                    }
                }
            }
        }

        // One bounded step of the DFU job under way (a page erased, a chunk written, 2 KiB
        // read back: `dfu`), once the node has nothing due: the lines, the stop input and the
        // watchdog are served between two steps. Only while the bus is quiet (nothing moves or
        // is owed a stop): a stop never waits behind a step. Its result goes to the node when
        // it is whole.
        #[cfg(feature = "update")]
        if dfu.busy() && node.quiet_for_flash() {
            if let Some(outcome) = dfu.step(settings) {
                crate::dfu::report(node, outcome);
            }
        }
        // A new firmware on trial confirmed once it has shown it works (and the bus is quiet).
        #[cfg(feature = "update")]
        if dfu.unconfirmed() {
            dfu.confirm(node, settings);
        }

        // The I/O task shows them when it next wakes (1 ms with a PIO axis, else up to 20 ms:
        // the outputs are all OFF then). Every sample when the node wants them periodically
        // (a PIO axis: its logic debounces and times by samples), only changes otherwise.
        io::show_outputs(node.outputs(), node.sample_period().is_some());
        if clock >= indicators_at {
            io::show_indicators(node.indicators());
            indicators_at = clock + INDICATORS_PERIOD;
        }
        board.watchdog.pet();
    }
}

/// Hands the node what the I/O task has sampled since the last call, at the times it was sampled:
/// each run of one level ([`io::Run`]) as its first and its last sample. The debouncer decides as
/// on every sample (a level counts once its samples span the debounce time); what a level starts
/// is stamped with the run's last sample: not earlier than every sample would have, and not
/// later than this task could act on it anyway.
fn samples(node: &mut Node, stop: &mut bool, now: Instant) {
    while let Some(run) = io::take() {
        let (first, last) = run.at(now.0);
        let (first, last) = (Instant(first), Instant(last));
        if run.sample.stop != *stop {
            *stop = run.sample.stop;
            node.set_stop_input(first, *stop);
        }
        node.sample_inputs(first, run.sample.inputs);
        if last != first {
            node.sample_inputs(last, run.sample.inputs);
        }
    }
}

/// The first `n` bytes of `buf` (all of it if `n` is larger, which a UART never reports).
fn bytes(buf: &[u8], n: usize) -> &[u8] {
    buf.get(..n).unwrap_or(buf)
}
