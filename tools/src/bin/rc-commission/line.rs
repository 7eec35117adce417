//! The bus on a serial port, driven by the gateway's own bus master (`protocol::engine::Engine`):
//! the same time-outs, retries, establishment and jobs as the firmware, with std I/O.

use std::io::{self, Read, Write};
use std::time::{Duration, Instant};

/// Added to every response time-out, for what a USB adapter and the PC add to the wire's time.
const REPLY_SLACK: protocol::time::Duration = protocol::time::Duration::from_millis(50);

use protocol::engine::{Config, Engine, Event, Job, JobOutput, Link, Output};
use protocol::frame::COMM_CHANGE;
use protocol::line::{Baud, LineAction};
use protocol::{Axis, AxisSet, Rtim};
use serialport::SerialPort;

/// How long one read waits at most, so that the engine's deadlines are kept.
const MAX_WAIT: Duration = Duration::from_millis(2);

pub struct Line {
    port: Box<dyn SerialPort>,
    pub engine: Engine,
    start: Instant,
    events: Vec<Event>,
}

impl Line {
    /// Open `path` at `baud`; the engine serves `axes`. With `establish`, it first runs the §6-1
    /// procedure (break, then every axis moved to `baud` and RTIM 3 ms); without, it assumes the
    /// controllers already run at `baud` with `rtim`.
    pub fn open(
        path: &str,
        baud: Baud,
        axes: AxisSet,
        rtim: Rtim,
        establish: bool,
        retries: u8,
    ) -> Result<Line, String> {
        let port = serialport::new(path, baud.bits_per_second())
            .timeout(MAX_WAIT)
            .open()
            .map_err(|e| {
                // serialport words ENOTTY as "Not a typewriter": say what it means here.
                if e.description == nix::errno::Errno::ENOTTY.desc() {
                    format!("{path}: not a serial port ({e})")
                } else {
                    format!("{path}: {e}")
                }
            })?;
        let config = Config {
            axes,
            baud,
            rtim: if establish { Rtim::MIN } else { rtim },
            retries,
            establish,
            // A USB adapter or a pseudo-terminal takes a write at once: no wire time to check
            // answers against (engine::Config::wire_timing).
            wire_timing: false,
            // A USB adapter's latency timer holds received bytes for up to 16 ms, and a PC
            // schedules this process when it can: an answer that waits outside the wire is
            // still the axis' answer (engine::Config::reply_slack). Under load the commission
            // tests lost answers to a 0 ms slack and reported axes missing.
            reply_slack: REPLY_SLACK,
            ..Config::default()
        };
        Ok(Line {
            port,
            engine: Engine::new(config),
            start: Instant::now(),
            events: Vec::new(),
        })
    }

    fn now(&self) -> protocol::time::Instant {
        let us = u64::try_from(self.start.elapsed().as_micros()).unwrap_or(u64::MAX);
        protocol::time::Instant(us)
    }

    /// Run the engine for at most `limit`, until `done` holds (checked after every step).
    pub fn run_until(
        &mut self,
        limit: Duration,
        mut done: impl FnMut(&mut Line) -> bool,
    ) -> Result<bool, String> {
        let deadline = Instant::now() + limit;
        loop {
            self.step().map_err(|e| format!("serial port: {e}"))?;
            if done(self) {
                return Ok(true);
            }
            if Instant::now() >= deadline {
                return Ok(false);
            }
        }
    }

    fn step(&mut self) -> io::Result<()> {
        loop {
            let now = self.now();
            match self.engine.poll(now) {
                Output::Transmit(frame) => {
                    self.port.write_all(&frame.to_bytes())?;
                    self.port.flush()?;
                }
                Output::Line(action) => self.line(action)?,
                Output::Idle(_) => break,
            }
        }
        let mut buf = [0u8; 256];
        match self.port.read(&mut buf) {
            Ok(n) => {
                let now = self.now();
                self.engine.receive(now, buf.get(..n).unwrap_or(&[]));
            }
            Err(e) if e.kind() == io::ErrorKind::TimedOut => {}
            Err(e) => return Err(e),
        }
        while let Some(event) = self.engine.next_event() {
            self.events.push(event);
        }
        Ok(())
    }

    fn line(&mut self, action: LineAction) -> io::Result<()> {
        match action {
            LineAction::SetBaud(baud) => {
                self.port.flush()?;
                self.port.set_baud_rate(baud.bits_per_second())?;
            }
            LineAction::BreakStart => {
                self.port.flush()?;
                self.port.set_break()?;
            }
            LineAction::BreakEnd => self.port.clear_break()?,
            LineAction::CommChange => {
                self.port.write_all(&COMM_CHANGE)?;
                self.port.flush()?;
            }
        }
        Ok(())
    }

    /// Whether the bus has been established (or needed no establishment) and every axis of
    /// `axes` has either answered or been given up.
    pub fn settled(&self, axes: &[Axis]) -> bool {
        axes.iter()
            .all(|&a| matches!(self.engine.axis(a).link, Link::Online | Link::Offline))
    }

    /// Run `job` to its end (at most `limit`).
    pub fn job(&mut self, job: Job, limit: Duration) -> Result<JobOutput, String> {
        let id = self
            .engine
            .submit(job)
            .map_err(|e| format!("axis {}: refused: {e:?}", job.axis.get()))?;
        let mut result = None;
        let mut seen = self.events.len();
        self.run_until(limit, |line| {
            for event in line.events.get(seen..).unwrap_or(&[]) {
                if let Event::JobDone {
                    id: done,
                    result: r,
                    ..
                } = event
                {
                    if *done == id {
                        result = Some(*r);
                    }
                }
            }
            seen = line.events.len();
            result.is_some()
        })?;
        match result {
            Some(Ok(output)) => Ok(output),
            Some(Err(error)) => Err(format!("axis {}: {}", job.axis.get(), describe(error))),
            None => Err(format!("axis {}: no end within {limit:?}", job.axis.get())),
        }
    }

    /// What the engine has reported so far.
    pub fn events(&self) -> &[Event] {
        &self.events
    }

    /// The line's rate now.
    pub fn baud(&self) -> Baud {
        self.engine.line_baud()
    }
}

/// A job error in words a maintenance engineer can act on.
pub fn describe(error: protocol::engine::JobError) -> String {
    use protocol::engine::JobError::*;
    match error {
        Timeout | Offline => {
            "no reply (check the wiring, termination, the axis number and the baud rate)".into()
        }
        OutcomeUnknown => "no reply to a relative move: it may or may not have moved".into(),
        Rejected(code) => format!("rejected: {:02X} {}", code.0, code.text()),
        Alarm(code) => format!("alarm {:02X} {}", code.0, code.text()),
        Unexpected => "an answer that does not confirm the command".into(),
        Cancelled => "cancelled by a stop".into(),
        VerifyFailed => "the read-back differs from what was written".into(),
        WaitTimeout => "the move or homing did not complete in time".into(),
    }
}
