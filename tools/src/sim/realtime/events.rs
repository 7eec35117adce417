//! The event log (`rc-sim --events FILE`): what a benchmark measures the master by, one event a
//! line, times in µs of the host's monotonic clock (`CLOCK_MONOTONIC`, the clock of
//! `std::time::Instant` on Linux), so that a master's own timestamps compare with them:
//!
//! ```text
//! REQ <t> <axis> <code>            a command reached the controllers (t: when the master's bytes were read)
//! REP <t> <axis> <code> <pfin>     a reply reached the master (pfin 1: PFIN on, a status reply)
//! MOVE <t> <axis> <inband>         a move (or a home) started at t; it is in its band from inband on
//! ```
//!
//! `<code>` is the command's [`Code`](protocol::Code) as `Debug` prints it (`Status`,
//! `ReadMemory`, `Stop`...). A move's `inband` is the simulator's own figure: the moment the
//! controller turns PFIN on, which no status poll can see sooner.

use std::io::{self, Write};

use protocol::frame::Packet;
use protocol::status::Outputs;
use protocol::{Axis, Deframer, Reply, Request};

use super::super::bus::Bus;

/// Microseconds of `CLOCK_MONOTONIC` now.
pub fn monotonic_us() -> u64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC).map_or(0, |t| {
        let us = i128::from(t.tv_sec()) * 1_000_000 + i128::from(t.tv_nsec()) / 1_000;
        u64::try_from(us).unwrap_or(0)
    })
}

/// Writes the event log; see the [module documentation](self).
pub(super) struct EventLog {
    out: io::BufWriter<Box<dyn Write + Send>>,
    /// `CLOCK_MONOTONIC` µs minus the bus's virtual µs (set when a run starts).
    offset: i128,
    from_master: Deframer,
    to_master: Deframer,
    /// Each axis' last move start logged.
    moves: [Option<u64>; 16],
}

impl std::fmt::Debug for EventLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EventLog").finish_non_exhaustive()
    }
}

impl EventLog {
    pub(super) fn new(out: Box<dyn Write + Send>) -> EventLog {
        EventLog {
            out: io::BufWriter::new(out),
            offset: 0,
            from_master: Deframer::default(),
            to_master: Deframer::default(),
            moves: [None; 16],
        }
    }

    /// Virtual time `virtual_now` is `CLOCK_MONOTONIC` µs `monotonic_now`.
    pub(super) fn sync(&mut self, virtual_now: u64, monotonic_now: u64) {
        self.offset = i128::from(monotonic_now) - i128::from(virtual_now);
    }

    fn at(&self, virtual_us: u64) -> u64 {
        u64::try_from(i128::from(virtual_us) + self.offset).unwrap_or(0)
    }

    pub(super) fn host(&mut self, now: u64, bytes: &[u8]) -> io::Result<()> {
        for &byte in bytes {
            if let Ok(Packet::Frame(frame)) = self.from_master.push(byte) {
                if let Ok(request) = Request::parse(&frame) {
                    let code = request.command.code();
                    writeln!(
                        self.out,
                        "REQ {} {} {code:?}",
                        self.at(now),
                        request.axis.get()
                    )?;
                }
            }
        }
        Ok(())
    }

    pub(super) fn master(&mut self, received: &[(u64, u8)]) -> io::Result<()> {
        for &(at, byte) in received {
            if let Ok(Packet::Frame(frame)) = self.to_master.push(byte) {
                if let Ok(reply) = Reply::parse(&frame) {
                    let pfin = reply
                        .report()
                        .is_some_and(|r| r.outputs.contains(Outputs::PFIN));
                    writeln!(
                        self.out,
                        "REP {} {} {:?} {}",
                        self.at(at),
                        reply.axis().get(),
                        reply.code(),
                        u8::from(pfin)
                    )?;
                }
            }
        }
        Ok(())
    }

    /// Log the moves started since the last call.
    pub(super) fn moves(&mut self, bus: &Bus) -> io::Result<()> {
        for controller in bus.controllers() {
            let axis: Axis = controller.axis();
            let Some(start) = controller.last_move_start() else {
                continue;
            };
            let Some(seen) = self.moves.get_mut(usize::from(axis.get())) else {
                continue;
            };
            if *seen == Some(start) {
                continue;
            }
            *seen = Some(start);
            let in_band = controller
                .profile()
                .map(|p| p.in_band_at())
                .or(controller.homing_done_at())
                .unwrap_or(start);
            let (start, in_band) = (self.at(start), self.at(in_band));
            writeln!(self.out, "MOVE {start} {} {in_band}", axis.get())?;
        }
        Ok(())
    }

    pub(super) fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }
}
