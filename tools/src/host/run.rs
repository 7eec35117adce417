//! The loop: reading both lines, driving the node, carrying out its line actions, sleeping,
//! and reading control lines.

use std::io::{self, Write};
use std::os::fd::{AsFd, BorrowedFd};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration as StdDuration;

use protocol::frame::COMM_CHANGE;
use protocol::line::{LineAction, BREAK_MS};
use protocol::node::{Action, TcpAction};
use protocol::plc::update::{UpdateError, UpdateJob};
use protocol::time::Instant;
use protocol::Request;
use serde_json::json;

use super::port::Input;
use super::{
    control, port, BusSide, Ended, Host, Restart, BUS_EVENT_GRAIN_US, MAX_LOGGED_BURST,
    MAX_OUTPUTS_PER_PASS, MAX_READS_PER_PASS,
};

impl Host {
    /// Run until `stop` is raised (checked at least every
    /// [`Options::max_sleep`](super::Options::max_sleep)), a `quit` line, or the end of standard
    /// input (with control lines). Fails on an I/O error of a line.
    pub fn run(&mut self, stop: &AtomicBool) -> io::Result<Ended> {
        let mut buf = [0u8; 4096];
        self.log.note(self.now(), "started");
        loop {
            if stop.load(Ordering::Relaxed) {
                return Ok(Ended::Stopped);
            }
            let now = self.now();
            self.read_plc(now, &mut buf)?;
            self.read_bus(now, &mut buf)?;
            let until = self.drive(now)?;
            if let Some(ended) = self.read_control(now, &mut buf)? {
                return Ok(ended);
            }
            if let Some(plc) = &mut self.plc {
                plc.flush()?;
            }
            if let BusSide::Device { port, .. } = &mut self.bus {
                port.flush()?;
            }
            // A restart asked for in this pass comes first: the reply to RESTART is not the
            // proof a trial needs (the firmware resets right after it).
            if let Some(why) = self.restart_due.take() {
                self.restart(now, why)?;
                continue;
            }
            self.confirm_trial(now)?;
            self.sleep(until)?;
        }
    }

    fn read_plc(&mut self, now: u64, buf: &mut [u8]) -> io::Result<()> {
        let node_now = now.saturating_sub(self.epoch);
        if let Some(tcp) = &mut self.tcp {
            tcp.pump(node_now, &mut self.node)?;
        }
        for _ in 0..MAX_READS_PER_PASS {
            let Some(plc) = &mut self.plc else {
                break;
            };
            let n = match plc.read(buf)? {
                Input::Bytes(n) => n,
                Input::Nothing => break,
            };
            // A frame that ended (t3.5) before these bytes is handled before they start the
            // next one.
            self.drive(now)?;
            let bytes = buf.get(..n).unwrap_or(&[]);
            self.node.plc_received(self.node_time(now), bytes);
            if self.burst.len() + bytes.len() <= MAX_LOGGED_BURST {
                self.burst.extend_from_slice(bytes);
            }
        }
        Ok(())
    }

    fn read_bus(&mut self, now: u64, buf: &mut [u8]) -> io::Result<()> {
        match &mut self.bus {
            BusSide::Sim(bus) => {
                for (at, byte) in bus.advance(now) {
                    let at = at.max(self.last_bus_rx);
                    self.last_bus_rx = at;
                    self.log.bus_received(at, byte);
                    self.node
                        .bus_received(Instant(at.saturating_sub(self.epoch)), &[byte]);
                }
            }
            BusSide::Device { port, .. } => {
                for _ in 0..MAX_READS_PER_PASS {
                    let n = match port.read(buf)? {
                        Input::Bytes(n) => n,
                        Input::Nothing => break,
                    };
                    let bytes = buf.get(..n).unwrap_or(&[]);
                    for &byte in bytes {
                        self.log.bus_received(now, byte);
                    }
                    self.node
                        .bus_received(Instant(now.saturating_sub(self.epoch)), bytes);
                }
            }
        }
        Ok(())
    }

    /// Poll the node until it is idle; its deadline.
    fn drive(&mut self, now: u64) -> io::Result<Option<u64>> {
        for _ in 0..MAX_OUTPUTS_PER_PASS {
            match self.node.poll(self.node_time(now)) {
                Some(Action::Bus(bytes)) => {
                    if let Ok(request) = protocol::Frame::new_checked(&bytes)
                        .and_then(|frame| Request::parse(&frame))
                    {
                        if let Some(counts) = self.sent.get_mut(usize::from(request.axis.get())) {
                            *counts.entry(request.command.mnemonic()).or_default() += 1;
                        }
                    }
                    if let Ok(frame) = protocol::Frame::new_checked(&bytes) {
                        self.log.bus_sent(now, &frame);
                    }
                    match &mut self.bus {
                        BusSide::Sim(bus) => {
                            bus.host_send(now, &bytes);
                        }
                        BusSide::Device { port } => port.send(&bytes)?,
                    }
                }
                Some(Action::Reply(bytes)) => {
                    if let Some(plc) = &mut self.plc {
                        plc.send(bytes)?;
                    }
                    self.log.modbus_request(now, &self.burst, "reply");
                    self.log.modbus_reply(now, bytes);
                    self.burst.clear();
                }
                Some(Action::Line(action)) => self.line(now, action)?,
                Some(Action::PlcLine(line)) => {
                    if let Some(plc) = &mut self.plc {
                        plc.drain()?;
                        plc.set_rate(line.baud.bits_per_second())?;
                    }
                    self.log.note(now, &format!("PLC line: {line:?}"));
                }
                Some(Action::Tcp(TcpAction::Reply(socket))) => {
                    let bytes = self.node.tcp_reply().to_vec();
                    self.log.modbus_reply(now, &bytes);
                    if let Some(tcp) = &mut self.tcp {
                        tcp.reply(
                            now.saturating_sub(self.epoch),
                            socket,
                            &bytes,
                            &mut self.node,
                        );
                    }
                }
                Some(Action::Tcp(TcpAction::Close(socket))) => {
                    self.log.note(now, &format!("TCP: socket {socket} closed"));
                    if let Some(tcp) = &mut self.tcp {
                        tcp.close(socket, &mut self.node);
                    }
                }
                Some(Action::Settings(store)) => {
                    self.log.note(now, &format!("store: {store:?}"));
                    match store {
                        // A PC has no settings flash: a save is kept for the run (and counted);
                        // a restart starts with it.
                        protocol::plc::SettingsRequest::Save => {
                            self.saves += 1;
                            self.saved = Some(self.node.settings_record());
                            self.node.stored(Ok(self.saves));
                        }
                        // After this pass, once the reply has left.
                        protocol::plc::SettingsRequest::Restart => {
                            self.restart_due = Some(Restart::Reset);
                            return Ok(Some(now));
                        }
                        protocol::plc::SettingsRequest::FactoryReset => {
                            self.restart_due = Some(Restart::Factory);
                            return Ok(Some(now));
                        }
                    }
                }
                Some(Action::Update(job)) => {
                    // Only with a board (`Node::set_update_target`) is the node asked.
                    let result = match &mut self.board {
                        Some(board) => board.carry_out(&job),
                        None => Err(UpdateError::NoPartition),
                    };
                    let what = match job {
                        UpdateJob::Erase { len } => format!("erase {len} B"),
                        UpdateJob::Write { offset, bytes } => {
                            format!("write {} B at {offset}", bytes.len())
                        }
                        UpdateJob::Finish { len, crc32 } => {
                            format!("finish {len} B, CRC-32 {crc32:08x}")
                        }
                    };
                    self.log.note(now, &format!("update: {what}: {result:?}"));
                    if let Ok(Some(version)) = result {
                        self.node.set_image_version(version);
                    }
                    self.node.update_done(result.map(|_| ()));
                }
                None => {
                    if self.node.receiver_counters() != self.seen_receiver {
                        // A burst ended without a reply (a broadcast, another unit, noise).
                        self.seen_receiver = self.node.receiver_counters();
                        if !self.burst.is_empty() {
                            self.log.modbus_request(now, &self.burst, "no reply");
                            self.burst.clear();
                        }
                    }
                    return Ok(self.node.poll_at().map(|t| t.0.saturating_add(self.epoch)));
                }
            }
        }
        // More to do: come back at once.
        Ok(Some(now))
    }

    /// A firmware on trial that has shown it works (`Node::trial_passed`) is confirmed to the
    /// bootloader (embassy-boot's `mark_booted`), as the firmware does.
    fn confirm_trial(&mut self, now: u64) -> io::Result<()> {
        let Some(board) = &mut self.board else {
            return Ok(());
        };
        if board.unconfirmed() && self.node.trial_passed() {
            let state = board.confirm()?;
            self.node.set_boot_state(state);
            self.log
                .note(now, &format!("boot: confirmed ({})", state.name()));
        }
        Ok(())
    }

    /// A restart, as the board's reset: the reply to RESTART has left; the TCP connections are
    /// dropped (the serial line stays: it is a wire), the bootloader runs (`prepare_boot`: a
    /// marked image swapped in, an unconfirmed trial swapped back), and a new node starts with
    /// the settings saved during the run (none after a factory reset), its uptime from 0.
    pub(super) fn restart(&mut self, now: u64, why: Restart) -> io::Result<()> {
        if let Some(plc) = &mut self.plc {
            plc.flush()?;
            plc.drain()?;
        }
        if let Some(tcp) = &mut self.tcp {
            tcp.drop_all();
        }
        if why == Restart::Factory {
            self.saved = None;
        }
        let node = super::Host::start_node(
            &self.options,
            self.saved.as_ref().map(|r| r.as_slice()),
            self.saves,
            Some(protocol::plc::ResetCause::Software),
            self.board.as_mut(),
        )?;
        self.node = node;
        self.epoch = self.now();
        self.seen_receiver = protocol::modbus::ReceiverCounters::default();
        self.burst.clear();
        let config = self.node.gateway().config();
        let (plc_bps, bus_baud) = (config.settings.plc.baud.bits_per_second(), config.bus.baud);
        if let Some(plc) = &mut self.plc {
            plc.set_rate(plc_bps)?;
        }
        if let BusSide::Sim(bus) = &mut self.bus {
            bus.set_host_baud(bus_baud);
        }
        let version = self.board.as_ref().and_then(|b| b.active_version());
        self.log.note(
            now,
            &format!(
                "restarted ({why:?}): running {}, {}",
                version.map_or_else(
                    || protocol::plc::IDENTITY.revision.to_string(),
                    |v| format!("{}.{}.{}", v.major, v.minor, v.patch)
                ),
                self.boot_state().map_or("no bootloader", |b| b.name())
            ),
        );
        Ok(())
    }

    fn line(&mut self, now: u64, action: LineAction) -> io::Result<()> {
        self.log.note(now, &format!("line: {action:?}"));
        match (&mut self.bus, action) {
            (BusSide::Sim(bus), LineAction::SetBaud(baud)) => bus.set_host_baud(baud),
            (BusSide::Sim(bus), LineAction::BreakStart) => {
                // The node ends the break BREAK_MS later; the simulated line takes it whole.
                bus.host_break(now, u64::from(BREAK_MS) * 1_000);
            }
            (BusSide::Sim(_), LineAction::BreakEnd) => {}
            (BusSide::Sim(bus), LineAction::CommChange) => {
                bus.host_send(now, &COMM_CHANGE);
            }
            (BusSide::Device { port }, LineAction::SetBaud(baud)) => {
                port.drain()?;
                port.set_rate(baud.bits_per_second())?;
            }
            (BusSide::Device { port }, LineAction::BreakStart) => {
                port.drain()?;
                port.set_break(true)?;
            }
            (BusSide::Device { port }, LineAction::BreakEnd) => port.set_break(false)?,
            (BusSide::Device { port }, LineAction::CommChange) => port.send(&COMM_CHANGE)?,
        }
        Ok(())
    }

    fn sleep(&self, until: Option<u64>) -> io::Result<()> {
        let now = self.now();
        let max_us = u64::try_from(self.max_sleep.as_micros()).unwrap_or(u64::MAX);
        let mut wake = now.saturating_add(max_us);
        if let Some(t) = until {
            wake = wake.min(t);
        }
        let mut fds: Vec<(BorrowedFd<'_>, bool)> = Vec::new();
        if let Some(plc) = &self.plc {
            fds.push((plc.fd(), plc.output_pending()));
        }
        if let Some(tcp) = &self.tcp {
            fds.extend(tcp.fds());
        }
        match &self.bus {
            BusSide::Sim(bus) => {
                if let Some(t) = bus.next_event() {
                    wake = wake.min(t.max(now + BUS_EVENT_GRAIN_US));
                }
            }
            BusSide::Device { port } => {
                fds.push((port.fd(), port.output_pending()));
            }
        }
        if wake <= now {
            return Ok(());
        }
        let stdin = io::stdin();
        if self.control.is_some() {
            fds.push((stdin.as_fd(), false));
        }
        port::wait(&fds, StdDuration::from_micros(wake - now))
    }

    fn read_control(&mut self, now: u64, buf: &mut [u8]) -> io::Result<Option<Ended>> {
        let Some(mut pending) = self.control.take() else {
            return Ok(None);
        };
        let result = self.read_control_lines(now, buf, &mut pending);
        self.control = Some(pending);
        result
    }

    fn read_control_lines(
        &mut self,
        now: u64,
        buf: &mut [u8],
        pending: &mut Vec<u8>,
    ) -> io::Result<Option<Ended>> {
        let stdin = io::stdin();
        if !port::readable(stdin.as_fd())? {
            return Ok(None);
        }
        // Readable: one read returns what is there without blocking (or 0 at the end).
        let n = match nix::unistd::read(stdin.as_fd(), buf) {
            Ok(n) => n,
            Err(nix::errno::Errno::EINTR | nix::errno::Errno::EAGAIN) => return Ok(None),
            Err(e) => return Err(e.into()),
        };
        if n == 0 {
            self.log.note(now, "standard input closed");
            return Ok(Some(Ended::InputClosed));
        }
        pending.extend_from_slice(buf.get(..n).unwrap_or(&[]));
        while let Some(end) = pending.iter().position(|&b| b == b'\n') {
            let line: Vec<u8> = pending.drain(..=end).collect();
            let line = String::from_utf8_lossy(&line);
            let Some(command) = control::parse(&line) else {
                continue;
            };
            let (answer, ended) = match command {
                Ok(command) => self.control(now, command),
                Err(error) => (json!({"ok": false, "error": error}), None),
            };
            let mut out = io::stdout().lock();
            writeln!(out, "{answer}")?;
            out.flush()?;
            if ended.is_some() {
                return Ok(ended);
            }
        }
        Ok(None)
    }
}
