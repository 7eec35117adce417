//! The bus-master engine driving the simulated bus, in virtual time.
//!
//! This is the loop the firmware runs (poll, transmit, receive, wait), with the simulator in
//! place of the UART and a number in place of the clock. Bytes are handed to the engine at
//! their exact arrival times, so time-outs, host gaps and cycle times are those the wire gives.

use protocol::engine::{Engine, Event, Output};
use protocol::frame::COMM_CHANGE;
use protocol::line::Baud;
use protocol::line::{LineAction, BREAK_MS};
use protocol::time::Instant;
use rc_tools::sim::Bus;

/// What the harness drives: the engine itself, or something that owns one. (The whole
/// gateway has its own harness, [`NodeHarness`](crate::node_harness::NodeHarness).)
pub trait BusMaster {
    /// What to do at `now`.
    fn poll(&mut self, now: Instant) -> Output;
    /// Bytes from the line.
    fn receive(&mut self, now: Instant, bytes: &[u8]);
    /// The engine's events, for masters that pass them on.
    fn next_event(&mut self) -> Option<Event>;
    /// The rate the master starts at.
    fn line_baud(&self) -> Baud;
}

impl BusMaster for Engine {
    fn poll(&mut self, now: Instant) -> Output {
        Engine::poll(self, now)
    }
    fn receive(&mut self, now: Instant, bytes: &[u8]) {
        Engine::receive(self, now, bytes);
    }
    fn next_event(&mut self) -> Option<Event> {
        Engine::next_event(self)
    }
    fn line_baud(&self) -> Baud {
        Engine::line_baud(self)
    }
}

/// Bus master + simulated bus + virtual clock.
pub struct Harness<M: BusMaster = Engine> {
    /// The bus master under test (an [`Engine`], or a gateway that owns one).
    pub engine: M,
    /// The simulated line and controllers.
    pub bus: Bus,
    /// Virtual time, microseconds.
    pub now: u64,
    /// Every event the engine produced, with its time.
    pub events: Vec<(u64, Event)>,
    /// Every frame the engine transmitted, with its time.
    pub sent: Vec<(u64, protocol::Request)>,
}

impl<M: BusMaster> Harness<M> {
    /// The engine starts with the bus at time 0; the bus' host side starts at the engine's rate.
    pub fn new(engine: M, mut bus: Bus) -> Harness<M> {
        bus.set_host_baud(engine.line_baud());
        Harness {
            engine,
            bus,
            now: 0,
            events: Vec::new(),
            sent: Vec::new(),
        }
    }

    /// Run one step of the loop: act on the engine's output, or advance time to the next thing
    /// that happens (a byte arrives, or the engine's deadline) but not beyond `limit`.
    pub fn step(&mut self, limit: u64) {
        let output = self.engine.poll(Instant(self.now));
        match output {
            Output::Transmit(frame) => {
                if let Ok(request) = protocol::Request::parse(&frame) {
                    self.sent.push((self.now, request));
                }
                self.bus.host_send(self.now, &frame.to_bytes());
            }
            Output::Line(LineAction::SetBaud(baud)) => self.bus.set_host_baud(baud),
            Output::Line(LineAction::BreakStart) => {
                // The engine ends the break BREAK_MS later; the simulated line takes the
                // whole break at once.
                self.bus
                    .host_break(self.now, u64::from(BREAK_MS).saturating_mul(1000));
            }
            Output::Line(LineAction::BreakEnd) => {}
            Output::Line(LineAction::CommChange) => {
                self.bus.host_send(self.now, &COMM_CHANGE);
            }
            Output::Idle(until) => {
                let wake = [until.map(|t| t.0), self.bus.next_event(), Some(limit)]
                    .into_iter()
                    .flatten()
                    .min()
                    .unwrap_or(limit)
                    .max(self.now);
                for (at, byte) in self.bus.advance(wake) {
                    self.engine.receive(Instant(at), &[byte]);
                }
                self.now = wake;
            }
        }
        self.collect_events();
    }

    fn collect_events(&mut self) {
        while let Some(event) = self.engine.next_event() {
            self.events.push((self.now, event));
        }
    }

    /// Run until virtual time `until`.
    pub fn run_until(&mut self, until: u64) {
        let mut guard = 0u64;
        while self.now < until {
            self.step(until);
            guard += 1;
            if guard > 50_000_000 {
                break;
            }
        }
    }

    /// Run until `found` returns true for a new event (or `timeout` µs pass); the event.
    pub fn run_until_event(
        &mut self,
        timeout: u64,
        mut found: impl FnMut(&Event) -> bool,
    ) -> Option<(u64, Event)> {
        let until = self.now.saturating_add(timeout);
        let mut seen = self.events.len();
        while self.now < until {
            self.step(until);
            if let Some(hit) = self.events[seen..].iter().find(|(_, e)| found(e)) {
                return Some(*hit);
            }
            seen = self.events.len();
        }
        None
    }
}
