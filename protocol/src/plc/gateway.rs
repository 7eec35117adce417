//! The gateway: the bus master plus everything the PLC reads and writes.

use super::config::{GatewayConfig, WatchdogAction};
use super::map::*;
use super::registers::{join, split, status_block};
use crate::engine::{
    AxisSet, Duration, Engine, Event, Instant, Job, JobError, JobId, JobKind, JobOutput, Link,
    LinkError, Output, SubmitError,
};
use crate::jobs::PointReadback;
use crate::line::Baud;
use crate::memory::PointField;
use crate::modbus::{BitTable, DataModel, Exception, RegisterTable, SlaveCounters};
use crate::units::{Accel, Complement, Lead, Length, Speed};
use crate::Rtim;
use crate::{Axis, Buffered, Command, HomeDirection, PositionNo};

/// The fate of an axis' last command, as CMST shows it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CommandState {
    /// No command yet.
    #[default]
    Idle = 0,
    /// Accepted, running.
    Taken = 1,
    /// Finished.
    Done = 2,
    /// Failed; CMER says why.
    Failed = 3,
}

/// Why a command failed: the high byte of CMER (the low byte carries the RC code, if any).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Reason {
    /// No failure.
    None = 0,
    /// No valid answer from the axis after the retries.
    Timeout = 1,
    /// An `m` got no answer: it may or may not have moved.
    OutcomeUnknown = 2,
    /// The controller rejected the command (low byte: its warning code).
    Rejected = 3,
    /// The axis went into alarm (low byte: the alarm code).
    Alarm = 4,
    /// The controller answered something else than expected.
    Unexpected = 5,
    /// A stop cancelled it.
    Cancelled = 6,
    /// The read-back differs from what was written.
    VerifyFailed = 7,
    /// The move did not complete within the motion time-out.
    WaitTimeout = 8,
    /// The gateway's job queue was full.
    QueueFull = 9,
    /// Refused: STP/EMG or the stop input is active, no motion may start.
    Paused = 10,
}

impl Reason {
    fn of(error: JobError) -> u16 {
        let (reason, code) = match error {
            JobError::Timeout => (Reason::Timeout, 0),
            JobError::OutcomeUnknown => (Reason::OutcomeUnknown, 0),
            JobError::Rejected(c) => (Reason::Rejected, c.0),
            JobError::Alarm(c) => (Reason::Alarm, c.0),
            JobError::Unexpected => (Reason::Unexpected, 0),
            JobError::Cancelled => (Reason::Cancelled, 0),
            JobError::VerifyFailed => (Reason::VerifyFailed, 0),
            JobError::WaitTimeout => (Reason::WaitTimeout, 0),
        };
        (reason as u16) << 8 | u16::from(code)
    }
}

/// The PLC-side state of one axis.
#[derive(Clone, Copy, Debug, Default)]
struct PlcAxis {
    drg1: u16,
    posr: u16,
    coil_alrs: bool,
    coil_home: bool,
    state: CommandState,
    reason: u16,
    taken: u16,
    job: Option<JobId>,
    /// The running command moves the axis: PEND and PM stay off until it is done, as a PCON
    /// drops PEND when it accepts a start (the last status may predate the move).
    moving: bool,
    /// SON is held ON but the servo is off (an alarm reset turned it off): try again then.
    son_retry: Instant,
}

impl PlcAxis {
    fn son(&self) -> bool {
        self.drg1 & DRG1_SON != 0
    }
    fn paused(&self) -> bool {
        self.drg1 & (DRG1_STP | DRG1_EMG) != 0
    }
}

/// Command channel (ROBONET's five steps): 1 the PLC writes a request while the response is 0,
/// 2 the gateway runs it, 3 writes the response, 4 the PLC clears the request, 5 the gateway
/// clears the response.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
enum Channel {
    #[default]
    Idle,
    /// Reading the point (both requests start so: a write compares first, to spare V5), for
    /// this request.
    Reading(JobId, [u16; REQ_LEN]),
    /// Writing the field, for this request.
    Writing(JobId, [u16; REQ_LEN]),
    /// Response posted; waiting for the PLC to clear the request.
    Answered,
}

/// Command channel request codes.
const REQ_READ_FIELD: u16 = 1;
const REQ_WRITE_FIELD: u16 = 2;
/// In RESP[4]: the write was skipped because the value was already stored (no V5 spent).
const UNCHANGED: u16 = 0xFFFF;
/// Registers of the request block.
const REQ_LEN: usize = 6;
/// Registers of the response block.
const RESP_LEN: usize = 5;

/// The gateway; see the [module documentation](super).
#[derive(Debug)]
pub struct Gateway {
    engine: Engine,
    config: GatewayConfig,
    axes: [PlcAxis; 16],
    now: Instant,
    last_plc: Option<Instant>,
    watchdog_tripped: bool,
    stop_input: bool,
    failsafe: u16,
    failsafe_count: u16,
    sync_mask: u16,
    sync_status: u16,
    sync_pending: AxisSet,
    sync_buffered: AxisSet,
    sync_jobs: [Option<JobId>; 16],
    sync_start: Option<JobId>,
    request: [u16; REQ_LEN],
    response: [u16; RESP_LEN],
    channel: Channel,
    /// BUSBAUD and BUSRTIM as written, taken on APPLY.
    bus_line: (Baud, Rtim),
    /// The Modbus slave's counters, as its owner last reported them.
    plc_counters: SlaveCounters,
    /// Point-table rows as last read from (or verified on) each axis, for 0x1000.
    points: [[Option<PointReadback>; 16]; 16],
    /// A row being fetched for 0x1000, per axis (one at a time), with the row's generation.
    point_reads: [Option<(JobId, PositionNo, u8)>; 16],
    /// Per row: bumped whenever a write to it is submitted, so that a read that started
    /// before the write cannot put the old row back in the cache.
    row_gen: [[u8; 16]; 16],
    /// A row being written through 0x1000, per axis.
    point_writes: [Option<(JobId, PositionNo)>; 16],
}

/// `word` with `bit` set or cleared.
const fn with_bit(word: u16, bit: u16, on: bool) -> u16 {
    if on {
        word | bit
    } else {
        word & !bit
    }
}

fn index(axis: Axis) -> usize {
    usize::from(axis.get())
}

impl Gateway {
    /// A gateway with its bus master.
    pub fn new(config: GatewayConfig) -> Gateway {
        Gateway {
            engine: Engine::new(config.bus),
            config,
            axes: [PlcAxis::default(); 16],
            now: Instant(0),
            last_plc: None,
            watchdog_tripped: false,
            stop_input: false,
            failsafe: 0,
            failsafe_count: 0,
            sync_mask: 0,
            sync_status: 0,
            sync_pending: AxisSet::default(),
            sync_buffered: AxisSet::default(),
            sync_jobs: [None; 16],
            sync_start: None,
            request: [0; REQ_LEN],
            response: [0; RESP_LEN],
            channel: Channel::Idle,
            bus_line: (config.bus.baud, config.bus.rtim),
            plc_counters: SlaveCounters::default(),
            points: [[None; 16]; 16],
            point_reads: [None; 16],
            row_gen: [[0; 16]; 16],
            point_writes: [None; 16],
        }
    }

    /// The Modbus slave's counters, for PLCLINK: the owner of the slave (firmware task, PC
    /// gateway) reports them after each frame.
    pub fn set_plc_counters(&mut self, counters: SlaveCounters) {
        self.plc_counters = counters;
    }

    /// The bus master.
    pub fn engine(&self) -> &Engine {
        &self.engine
    }

    /// The configuration.
    pub fn config(&self) -> &GatewayConfig {
        &self.config
    }

    /// The latched fail-safe bits (FAILSAFE register).
    pub fn failsafe(&self) -> u16 {
        self.failsafe
    }

    /// The state of an axis' last command and its CMER code.
    pub fn command_state(&self, axis: Axis) -> (CommandState, u16) {
        self.axes
            .get(index(axis))
            .map_or((CommandState::Idle, 0), |a| (a.state, a.reason))
    }

    /// Set the time for the Modbus requests about to be handled.
    pub fn set_time(&mut self, now: Instant) {
        self.now = now;
    }

    /// Bytes received on the RS485 bus.
    pub fn receive(&mut self, now: Instant, bytes: &[u8]) {
        self.engine.receive(now, bytes);
        self.handle_events();
    }

    /// The stop input (PIO *STP, wired as a safety input): `active` when it is OFF.
    /// Its activation stops every axis (fail-safe) and no motion starts while it stays active.
    pub fn set_stop_input(&mut self, now: Instant, active: bool) {
        self.now = now;
        if active && !self.stop_input {
            self.trip(2);
        }
        self.stop_input = active;
    }

    /// What to do on the bus at `now`: the watchdog, job bookkeeping, then the engine.
    pub fn poll(&mut self, now: Instant) -> Output {
        self.now = now;
        let limit = self.config.watchdog;
        if let Some(last) = self.last_plc {
            if limit > Duration::ZERO && !self.watchdog_tripped && now.since(last) > limit {
                self.watchdog_tripped = true;
                match self.config.watchdog_action {
                    WatchdogAction::StopAll => self.trip(1),
                    WatchdogAction::LatchOnly => {
                        self.failsafe |= 1;
                        self.failsafe_count = self.failsafe_count.wrapping_add(1);
                    }
                }
            }
        }
        self.handle_events();
        self.hold_servo_on(now);
        let output = self.engine.poll(now);
        self.handle_events();
        match output {
            Output::Idle(until) => Output::Idle(self.watchdog_deadline().min(until).or(until)),
            other => other,
        }
    }

    /// SON is a level, as on a PCON: while the PLC holds it ON, a servo that went off (the alarm
    /// reset turns it off, a servo job failed) is turned on again, every 2 s at most, when
    /// nothing runs on the axis, it is not in alarm and the fail-safe is not latched. SON OFF is only ever acted on as a
    /// change: a controller's servo is on at power-up, and a PLC that never uses SON keeps it.
    fn hold_servo_on(&mut self, now: Instant) {
        for axis in self.config.bus.axes.iter() {
            let Some(plc) = self.axes.get(index(axis)).copied() else {
                continue;
            };
            let state = self.engine.axis(axis);
            let servo_off = state.report.is_some_and(|r| {
                !r.status.servo() && !r.outputs.alarm_active() && state.link == Link::Online
            });
            let failsafe = self.failsafe != 0 || self.watchdog_tripped;
            let idle = plc.job.is_none() && !self.engine.busy(axis);
            if plc.son() && servo_off && idle && !failsafe && now >= plc.son_retry {
                if let Some(p) = self.axes.get_mut(index(axis)) {
                    p.son_retry = now + Duration::from_millis(2000);
                }
                // Not a PLC command: CMST and CMCT keep showing the PLC's own.
                let _ = self.engine.submit(Job {
                    axis,
                    kind: JobKind::Servo(true),
                });
            }
        }
    }

    fn watchdog_deadline(&self) -> Option<Instant> {
        let limit = self.config.watchdog;
        match self.last_plc {
            Some(last) if limit > Duration::ZERO && !self.watchdog_tripped => {
                Some(last + limit + Duration::from_micros(1))
            }
            _ => None,
        }
    }

    /// Latch a fail-safe cause and stop every axis, before anything else.
    fn trip(&mut self, cause: u16) {
        self.failsafe |= cause;
        self.failsafe_count = self.failsafe_count.wrapping_add(1);
        // Every configured axis, offline ones too: one that dropped out for a moment during a
        // move would carry on when it answers again. A dead one only costs a time-out.
        for axis in self.config.bus.axes.iter() {
            // A stop jumps every queue; it cannot be refused for a configured axis.
            let _ = self.engine.submit(Job {
                axis,
                kind: JobKind::Stop,
            });
        }
        if self.sync_status == 1 {
            self.sync_failed();
        }
    }

    fn plc_activity(&mut self) {
        self.last_plc = Some(self.now);
        self.watchdog_tripped = false;
    }

    fn motion_blocked(&self, axis: Axis) -> bool {
        self.stop_input || self.axes.get(index(axis)).is_some_and(PlcAxis::paused)
    }

    /// Submit a command for the PLC (a register write, or the PIO logic's strobe) and record its
    /// fate in CMST/CMER. Motion is refused while STP/EMG or the stop input is active.
    pub fn command(&mut self, axis: Axis, kind: JobKind) -> Result<(), Exception> {
        let moves = matches!(
            kind,
            JobKind::Home(_)
                | JobKind::MoveToPoint(_)
                | JobKind::DirectMove { .. }
                | JobKind::Jog(_)
                | JobKind::MoveAbsolute(_)
                | JobKind::MoveRelative(_)
        );
        if kind == JobKind::Stop {
            // A stop is an interrupt, not a command with an outcome of its own: CMST keeps showing
            // the command it cancels (failed, reason 6).
            let submitted = self
                .engine
                .submit(Job { axis, kind })
                .map(|_| ())
                .map_err(|_| Exception::ServerDeviceFailure);
            // After the stop (which cancels the axis' queued jobs): give the synchronized start
            // up and cancel what it buffered.
            if self.sync_status == 1 && AxisSet(self.sync_mask).contains(axis) {
                self.sync_failed();
            }
            return submitted;
        }
        let blocked = moves && self.motion_blocked(axis);
        let result = if blocked {
            Err(Reason::Paused)
        } else {
            self.engine.submit(Job { axis, kind }).map_err(|e| match e {
                SubmitError::QueueFull | SubmitError::AxisDisabled => Reason::QueueFull,
            })
        };
        let Some(plc) = self.axes.get_mut(index(axis)) else {
            return Err(Exception::ServerDeviceFailure);
        };
        match result {
            Ok(id) => {
                plc.job = Some(id);
                plc.moving = moves;
                plc.state = CommandState::Taken;
                plc.reason = 0;
                plc.taken = plc.taken.wrapping_add(1);
                Ok(())
            }
            Err(reason) => {
                plc.job = None;
                plc.state = CommandState::Failed;
                plc.reason = (reason as u16) << 8;
                match reason {
                    Reason::QueueFull => Err(Exception::ServerDeviceFailure),
                    _ => Ok(()),
                }
            }
        }
    }

    fn handle_events(&mut self) {
        while let Some(event) = self.engine.next_event() {
            match event {
                Event::JobDone { id, axis, result } => self.job_done(id, axis, result),
                // A controller that comes (back) online may have been replaced or edited:
                // its point table is read afresh.
                Event::Online(axis) => {
                    if let Some(rows) = self.points.get_mut(index(axis)) {
                        *rows = [None; 16];
                    }
                }
                _ => {}
            }
        }
    }

    fn job_done(&mut self, id: JobId, axis: Axis, result: Result<JobOutput, JobError>) {
        if let Some(plc) = self.axes.get_mut(index(axis)).filter(|p| p.job == Some(id)) {
            plc.job = None;
            plc.moving = false;
            match result {
                Ok(_) => {
                    plc.state = CommandState::Done;
                    plc.reason = 0;
                }
                Err(e) => {
                    plc.state = CommandState::Failed;
                    plc.reason = Reason::of(e);
                }
            }
        }
        self.sync_done(id, axis, &result);
        self.table_done(id, axis, &result);
        self.channel_done(id, result);
    }

    // -------------------------------------------------------------- position table (0x1000)

    fn cache_row(&mut self, axis: Axis, point: PositionNo, row: Option<PointReadback>) {
        if let Some(slot) = self
            .points
            .get_mut(index(axis))
            .and_then(|rows| rows.get_mut(usize::from(point.get())))
        {
            *slot = row;
        }
    }

    fn cached_row(&self, axis: Axis, row: u16) -> Option<PointReadback> {
        self.points
            .get(index(axis))
            .and_then(|rows| rows.get(usize::from(row)))
            .copied()
            .flatten()
    }

    fn row_generation(&self, axis: Axis, point: PositionNo) -> u8 {
        self.row_gen
            .get(index(axis))
            .and_then(|g| g.get(usize::from(point.get())))
            .copied()
            .unwrap_or(0)
    }

    /// A write to the row is on its way: forget the cached row, and any read in flight.
    fn row_written(&mut self, axis: Axis, point: PositionNo) {
        if let Some(g) = self
            .row_gen
            .get_mut(index(axis))
            .and_then(|g| g.get_mut(usize::from(point.get())))
        {
            *g = g.wrapping_add(1);
        }
        self.cache_row(axis, point, None);
    }

    fn table_done(&mut self, id: JobId, axis: Axis, result: &Result<JobOutput, JobError>) {
        let i = index(axis);
        let row = match result {
            Ok(JobOutput::Point(readback)) => Some(*readback),
            _ => None,
        };
        if let Some((job, point, generation)) = self.point_reads.get(i).copied().flatten() {
            if job == id {
                if let Some(slot) = self.point_reads.get_mut(i) {
                    *slot = None;
                }
                // Only if no write to the row was submitted since the read started.
                if generation == self.row_generation(axis, point) {
                    self.cache_row(axis, point, row);
                }
                return;
            }
        }
        if let Some((job, point)) = self.point_writes.get(i).copied().flatten() {
            if job == id {
                if let Some(slot) = self.point_writes.get_mut(i) {
                    *slot = None;
                }
                // The verified read-back, or nothing if the write failed.
                self.cache_row(axis, point, row);
            }
        }
    }

    /// Rows of `axis` that a read of `count` registers at `address` needs and that are not
    /// cached: fetch the first (one read per axis at a time). Whether all are there.
    fn table_rows_ready(&mut self, axis: Axis, address: u16, count: usize) -> bool {
        let missing = (0..count)
            .filter_map(|i| nth(address, i))
            .filter_map(super::table::locate)
            .map(|(row, _)| row)
            .find(|&row| self.cached_row(axis, row).is_none());
        let Some(row) = missing else {
            return true;
        };
        let busy = self
            .point_reads
            .get(index(axis))
            .is_some_and(Option::is_some);
        // An axis that does not answer is not asked (its frames would take the bus from the
        // live axes at job priority).
        let online = self.engine.axis(axis).link == Link::Online;
        let point = u8::try_from(row).ok().and_then(PositionNo::new);
        if let (false, true, Some(point)) = (busy, online, point) {
            let generation = self.row_generation(axis, point);
            if let Ok(id) = self.engine.submit(Job {
                axis,
                kind: JobKind::ReadPoint(point),
            }) {
                if let Some(slot) = self.point_reads.get_mut(index(axis)) {
                    *slot = Some((id, point, generation));
                }
            }
        }
        false
    }

    /// A whole row written at 0x1000 + 16 n: stored with read-back verify, unless the
    /// controller already holds exactly that (V5 is never spent on unchanged data).
    fn table_write(&mut self, axis: Axis, address: u16, values: &[u16]) -> Result<(), Exception> {
        let Some((row, 0)) = super::table::locate(address) else {
            return Err(Exception::IllegalDataAddress);
        };
        if !(15..=16).contains(&values.len()) {
            return Err(Exception::IllegalDataAddress);
        }
        let config = self
            .config
            .axes
            .get(index(axis))
            .copied()
            .unwrap_or_default();
        let data = super::table::point(values, &config)?;
        let point = u8::try_from(row)
            .ok()
            .and_then(PositionNo::new)
            .ok_or(Exception::IllegalDataAddress)?;
        // Unchanged, as the PLC sees it (the controller's row in the PLC's units): no write, so
        // no V5 (reading a row and writing it back must not wear the memory).
        let mut wanted = [0u16; 16];
        for (slot, &v) in wanted.iter_mut().zip(values) {
            *slot = v;
        }
        if let Some(w) = wanted.get_mut(11) {
            if *w == 0 {
                *w = values.get(10).copied().unwrap_or(0);
            }
        }
        let unchanged = self
            .cached_row(axis, row)
            .is_some_and(|r| super::table::registers(&r, &config) == wanted);
        if unchanged {
            return Ok(());
        }
        // Not a PLC command: CMST keeps showing the axis' last command. The PLC reads the row
        // back to see it stored (verified on the controller).
        let id = self
            .engine
            .submit(Job {
                axis,
                kind: JobKind::WritePoint {
                    point,
                    data,
                    verify: true,
                },
            })
            .map_err(|_| Exception::ServerDeviceFailure)?;
        self.row_written(axis, point);
        if let Some(slot) = self.point_writes.get_mut(index(axis)) {
            *slot = Some((id, point));
        }
        Ok(())
    }

    // -------------------------------------------------------------- synchronized start

    /// Whether a synchronized start of `mask` may begin now.
    fn sync_check(&self, mask: AxisSet) -> Result<(), Exception> {
        if mask.0 == 0 || mask.iter().any(|a| self.motion_blocked(a)) {
            return Err(Exception::IllegalDataValue);
        }
        // Busy: running, an `h` of an earlier attempt still out (its completion must be
        // cancelled, not taken for this attempt's), or no room for one `h` per axis.
        let leftover = self.sync_jobs.iter().any(Option::is_some) || self.sync_start.is_some();
        let room = crate::engine::QUEUE_LEN.saturating_sub(self.engine.queued());
        if self.sync_status == 1 || leftover || mask.iter().count() > room {
            return Err(Exception::ServerDeviceFailure);
        }
        Ok(())
    }

    fn start_sync(&mut self) -> Result<(), Exception> {
        let mask = AxisSet(self.sync_mask);
        self.sync_check(mask)?;
        self.sync_status = 1;
        self.sync_pending = AxisSet::default();
        self.sync_buffered = AxisSet::default();
        self.sync_start = None;
        for axis in mask.iter() {
            let posr = self.axes.get(index(axis)).map_or(0, |p| p.posr);
            let point = PositionNo::new(u8::try_from(posr).unwrap_or(0)).unwrap_or(PositionNo::MIN);
            let Some(buffered) = Buffered::new(&Command::MoveToPoint(point)) else {
                continue;
            };
            let job = Job {
                axis,
                kind: JobKind::Command(Command::Buffer(buffered)),
            };
            match self.engine.submit(job) {
                Ok(id) => {
                    self.sync_pending = self.sync_pending.with(axis);
                    if let Some(slot) = self.sync_jobs.get_mut(index(axis)) {
                        *slot = Some(id);
                    }
                }
                Err(_) => {
                    self.sync_failed();
                    return Err(Exception::ServerDeviceFailure);
                }
            }
        }
        Ok(())
    }

    fn sync_done(&mut self, id: JobId, axis: Axis, result: &Result<JobOutput, JobError>) {
        if self.sync_start == Some(id) {
            self.sync_start = None;
            if result.is_ok() {
                self.sync_status = 2;
                self.sync_buffered = AxisSet::default();
            } else {
                // The `t` may not have reached every axis: cancel what may still be buffered.
                self.sync_failed();
            }
            return;
        }
        let Some(slot) = self
            .sync_jobs
            .get_mut(index(axis))
            .filter(|s| **s == Some(id))
        else {
            return;
        };
        *slot = None;
        self.sync_pending = AxisSet(self.sync_pending.0 & !(1 << axis.get()));
        if result.is_ok() {
            self.sync_buffered = self.sync_buffered.with(axis);
            if self.sync_status != 1 {
                // The start was given up while this `h` ran: cancel it at once.
                self.sync_failed();
                return;
            }
        } else {
            self.sync_failed();
            return;
        }
        if self.sync_pending.0 == 0 && self.sync_status == 1 {
            let mask = AxisSet(self.sync_mask);
            if mask.iter().any(|a| self.motion_blocked(a)) {
                // STP, EMG or the stop input came on while the commands were buffered.
                self.sync_failed();
                return;
            }
            let Some(lead) = mask.iter().next() else {
                return;
            };
            match self.engine.submit(Job {
                axis: lead,
                kind: JobKind::StartBuffered(mask),
            }) {
                Ok(id) => self.sync_start = Some(id),
                Err(_) => self.sync_failed(),
            }
        }
    }

    /// Give up: cancel what was buffered by buffering `n` (complete edition §4-4-10).
    fn sync_failed(&mut self) {
        self.sync_status = 3;
        for axis in self.sync_buffered.iter() {
            if let Some(cancel) = Buffered::new(&Command::Status) {
                let _ = self.engine.submit(Job {
                    axis,
                    kind: JobKind::Command(Command::Buffer(cancel)),
                });
            }
        }
        self.sync_buffered = AxisSet::default();
    }

    // -------------------------------------------------------------- command channel

    /// Check a new request block before anything is stored (step 1 requires the response to
    /// be clear; a request while one runs is refused with exception 04).
    fn channel_check(
        &self,
        request: [u16; REQ_LEN],
    ) -> Result<Option<(Axis, PositionNo)>, Exception> {
        let [code, axis, point, field, _, _] = request;
        if code == 0 {
            return Ok(None);
        }
        if request == self.request && self.channel != Channel::Idle {
            // The same request written again while it runs or is answered: nothing new.
            return Ok(None);
        }
        if self.channel != Channel::Idle || self.response[0] != 0 {
            return Err(Exception::ServerDeviceFailure);
        }
        let axis = u8::try_from(axis)
            .ok()
            .and_then(Axis::new)
            .filter(|&a| self.config.bus.axes.contains(a))
            .ok_or(Exception::IllegalDataValue)?;
        let point = u8::try_from(point)
            .ok()
            .and_then(PositionNo::new)
            .ok_or(Exception::IllegalDataValue)?;
        channel_field(field).ok_or(Exception::IllegalDataValue)?;
        if code != REQ_READ_FIELD && code != REQ_WRITE_FIELD {
            return Err(Exception::IllegalDataValue);
        }
        Ok(Some((axis, point)))
    }

    /// Act on the stored request block.
    fn channel_request(&mut self, start: Option<(Axis, PositionNo)>) -> Result<(), Exception> {
        if self.request[0] == 0 {
            // Step 4 -> 5: the PLC cleared its request, the gateway clears the response.
            if self.channel == Channel::Answered {
                self.response = [0; RESP_LEN];
                self.channel = Channel::Idle;
            }
            return Ok(());
        }
        let Some((axis, point)) = start else {
            return Ok(());
        };
        let id = self
            .engine
            .submit(Job {
                axis,
                kind: JobKind::ReadPoint(point),
            })
            .map_err(|_| Exception::ServerDeviceFailure)?;
        self.channel = Channel::Reading(id, self.request);
        Ok(())
    }

    fn channel_done(&mut self, id: JobId, result: Result<JobOutput, JobError>) {
        let request = match self.channel {
            Channel::Reading(r, request) | Channel::Writing(r, request) if r == id => request,
            _ => return,
        };
        if self.request != request {
            // The PLC cleared (or changed) its request while it ran: drop the result, and never
            // write on behalf of a request that is gone.
            self.channel = Channel::Idle;
            return;
        }
        let [code, axis, point, field, hi, lo] = request;
        let wanted = join(hi, lo);
        let unexpected = (Reason::Unexpected as u16) << 8;
        match (self.channel, result) {
            (Channel::Reading(..), Ok(JobOutput::Point(readback))) => {
                let Some(field) = channel_field(field) else {
                    return self.answer_error(code, unexpected);
                };
                let stored = readback.get(field);
                if code == REQ_READ_FIELD || stored == wanted {
                    let count = if code == REQ_WRITE_FIELD {
                        UNCHANGED
                    } else {
                        0
                    };
                    let [h, l] = split(stored);
                    return self.answer([code, 0, h, l, count]);
                }
                let (Some(axis), Some(point)) = (
                    u8::try_from(axis).ok().and_then(Axis::new),
                    u8::try_from(point).ok().and_then(PositionNo::new),
                ) else {
                    return self.answer_error(code, unexpected);
                };
                let job = Job {
                    axis,
                    kind: JobKind::WriteField {
                        point,
                        field,
                        value: wanted,
                    },
                };
                match self.engine.submit(job) {
                    Ok(w) => {
                        self.row_written(axis, point);
                        self.channel = Channel::Writing(w, request);
                    }
                    Err(_) => self.answer_error(code, (Reason::QueueFull as u16) << 8),
                }
            }
            (Channel::Writing(..), Ok(output)) => {
                let count = match output {
                    JobOutput::Value(v) => u16::try_from(v).unwrap_or(u16::MAX - 1),
                    _ => 0,
                };
                self.answer([code, 0, hi, lo, count]);
            }
            (_, Err(e)) => self.answer_error(code, Reason::of(e)),
            _ => self.answer_error(code, unexpected),
        }
    }

    fn answer(&mut self, response: [u16; RESP_LEN]) {
        self.response = response;
        self.channel = Channel::Answered;
    }

    fn answer_error(&mut self, code: u16, error: u16) {
        self.answer([code | 0x8000, error, 0, 0, 0]);
    }

    // -------------------------------------------------------------- axis registers

    fn axis_read(&self, axis: Axis, table: RegisterTable, address: u16) -> Result<u16, Exception> {
        let state = self.engine.axis(axis);
        let plc = self.axes.get(index(axis)).copied().unwrap_or_default();
        let config = self
            .config
            .axes
            .get(index(axis))
            .copied()
            .unwrap_or_default();
        match address {
            PNOW..=DSSE => {
                let starting = plc.moving && plc.state == CommandState::Taken;
                let block = status_block(state, &config, plc.paused() || self.stop_input, starting)
                    .ok_or(Exception::ServerDeviceFailure)?;
                block
                    .get(usize::from(address - PNOW))
                    .copied()
                    .ok_or(Exception::IllegalDataAddress)
            }
            CMST => Ok(plc.state as u16),
            CMER => Ok(plc.reason),
            LINK => Ok(match state.link {
                Link::Unknown => 0,
                Link::Online => 1,
                Link::Offline => 2,
            }),
            CMCT => Ok(plc.taken),
            DRG1 if table == RegisterTable::Holding => Ok(plc.drg1),
            POSR if table == RegisterTable::Holding => Ok(plc.posr),
            a => match (super::table::locate(a), table) {
                (Some((row, offset)), RegisterTable::Holding) => {
                    let readback = self
                        .cached_row(axis, row)
                        .ok_or(Exception::ServerDeviceFailure)?;
                    super::table::registers(&readback, &config)
                        .get(usize::from(offset))
                        .copied()
                        .ok_or(Exception::IllegalDataAddress)
                }
                _ => Err(Exception::IllegalDataAddress),
            },
        }
    }

    fn write_drg1(&mut self, axis: Axis, value: u16) -> Result<(), Exception> {
        let old = self.axes.get(index(axis)).copied().unwrap_or_default();
        let rising = |bit: u16| value & bit != 0 && old.drg1 & bit == 0;
        // Every command this write causes must fit in the queue, or the write has no effect
        // (exception 04) and the PLC can repeat it; a stop needs no room.
        let needed = usize::from((value & DRG1_SON != 0) != old.son())
            + usize::from(rising(DRG1_ALRS))
            + usize::from(rising(DRG1_HOME))
            + usize::from(rising(DRG1_CSTR));
        if crate::engine::QUEUE_LEN.saturating_sub(self.engine.queued()) < needed {
            return Err(Exception::ServerDeviceFailure);
        }
        if let Some(plc) = self.axes.get_mut(index(axis)) {
            plc.drg1 = value;
        }
        let now_paused = value & (DRG1_STP | DRG1_EMG) != 0;
        if now_paused && !old.paused() {
            self.command(axis, JobKind::Stop)?;
        }
        if (value & DRG1_SON != 0) != old.son() {
            self.command(axis, JobKind::Servo(value & DRG1_SON != 0))?;
        }
        if rising(DRG1_ALRS) {
            self.command(axis, JobKind::AlarmReset)?;
        }
        if rising(DRG1_HOME) {
            let home = self.home_direction(axis);
            self.command(axis, JobKind::Home(home))?;
        }
        if rising(DRG1_CSTR) {
            let point =
                PositionNo::new(u8::try_from(old.posr).unwrap_or(0)).unwrap_or(PositionNo::MIN);
            self.command(axis, JobKind::MoveToPoint(point))?;
        }
        Ok(())
    }

    fn home_direction(&self, axis: Axis) -> HomeDirection {
        self.config
            .axes
            .get(index(axis))
            .map_or(HomeDirection::MotorEnd, |c| c.scale.home)
    }

    /// Validate a direct numeric move (0x9900) into a job.
    fn direct_move(&self, axis: Axis, values: &[u16]) -> Result<JobKind, Exception> {
        let config = self
            .config
            .axes
            .get(index(axis))
            .copied()
            .unwrap_or_default();
        let reg = |i: usize| values.get(i).copied().unwrap_or(0);
        let pcmd = join(reg(0), reg(1)) as i32;
        let inp = join(reg(2), reg(3));
        let vcmd = join(reg(4), reg(5));
        let acmd = reg(6);
        let (ppow, ctlf) = (reg(7), reg(8));
        const CTLF_INC: u16 = 1 << 3;
        if ppow != 0 || ctlf & !CTLF_INC != 0 {
            return Err(Exception::IllegalDataValue);
        }
        let relative = ctlf & CTLF_INC != 0;
        let scale = config.scale;
        let target = if relative {
            // The end of a relative move must be inside the travel too, from where it is now:
            // so only from rest, with nothing queued that would move it first.
            let state = self.engine.axis(axis);
            if self.engine.busy(axis) || state.moving() {
                return Err(Exception::ServerDeviceFailure);
            }
            let here = state
                .position
                .map(|p| scale.position_from_wire(p).0)
                .ok_or(Exception::ServerDeviceFailure)?;
            let end = here.saturating_add(pcmd);
            if end < 0 || end > config.stroke.0 {
                return Err(Exception::IllegalDataValue);
            }
            scale.distance_to_wire(Length(pcmd))
        } else {
            if pcmd < 0 || pcmd > config.stroke.0 {
                return Err(Exception::IllegalDataValue);
            }
            scale.position_to_wire(Length(pcmd))
        }
        .map_err(|_| Exception::IllegalDataValue)?;
        scale
            .band_to_wire(Length(
                i32::try_from(inp).map_err(|_| Exception::IllegalDataValue)?,
            ))
            .map_err(|_| Exception::IllegalDataValue)?;
        if vcmd == 0 {
            return Err(Exception::IllegalDataValue);
        }
        let velocity = scale
            .velocity(Speed(vcmd))
            .map_err(|_| Exception::IllegalDataValue)?;
        let acceleration = scale
            .acceleration(Accel(u32::from(acmd)))
            .map_err(|_| Exception::IllegalDataValue)?;
        Ok(JobKind::DirectMove {
            target,
            relative,
            velocity,
            acceleration,
        })
    }

    fn axis_write(&mut self, axis: Axis, address: u16, values: &[u16]) -> Result<(), Exception> {
        match (address, values) {
            (DRG1, [value]) => {
                if value & !DRG1_SUPPORTED != 0 {
                    return Err(Exception::IllegalDataValue);
                }
                self.write_drg1(axis, *value)
            }
            (POSR, [value]) => {
                if *value > 15 {
                    return Err(Exception::IllegalDataValue);
                }
                if let Some(plc) = self.axes.get_mut(index(axis)) {
                    plc.posr = *value;
                }
                Ok(())
            }
            (DIRECT, _) => {
                let len = u16::try_from(values.len()).unwrap_or(u16::MAX);
                if !(DIRECT_MIN..=DIRECT_MAX).contains(&len) {
                    return Err(Exception::IllegalDataAddress);
                }
                let kind = self.direct_move(axis, values)?;
                self.command(axis, kind)
            }
            (DRG1..=POSR, _) | (PNOW..=CMCT, _) => Err(Exception::IllegalDataValue),
            (a, _) if super::table::locate(a).is_some() => self.table_write(axis, a, values),
            _ => Err(Exception::IllegalDataAddress),
        }
    }

    fn axis_coils(&mut self, axis: Axis, address: u16, values: &[bool]) -> Result<(), Exception> {
        let coils = [COIL_SON, COIL_ALRS, COIL_STP, COIL_HOME, COIL_STOP];
        let addresses = (0..values.len()).map(|i| nth(address, i));
        for a in addresses.clone() {
            if !a.is_some_and(|a| coils.contains(&a)) {
                return Err(Exception::IllegalDataAddress);
            }
        }
        let writes: heapless::Vec<(u16, bool), 5> = addresses
            .zip(values.iter().copied())
            .filter_map(|(a, v)| a.map(|a| (a, v)))
            .collect();
        // Stops first, then the rest in address order.
        for &(a, on) in writes
            .iter()
            .filter(|(a, _)| *a == COIL_STOP || *a == COIL_STP)
        {
            let plc = self.axes.get(index(axis)).copied().unwrap_or_default();
            match a {
                COIL_STOP if on => self.command(axis, JobKind::Stop)?,
                COIL_STP => {
                    self.write_drg1(axis, with_bit(plc.drg1, DRG1_STP, on))?;
                }
                _ => {}
            }
        }
        for &(a, on) in writes.iter() {
            let plc = self.axes.get(index(axis)).copied().unwrap_or_default();
            match a {
                COIL_SON => {
                    self.write_drg1(axis, with_bit(plc.drg1, DRG1_SON, on))?;
                }
                COIL_ALRS => {
                    if on && !plc.coil_alrs {
                        self.command(axis, JobKind::AlarmReset)?;
                    }
                    if let Some(p) = self.axes.get_mut(index(axis)) {
                        p.coil_alrs = on;
                    }
                }
                COIL_HOME => {
                    if on && !plc.coil_home {
                        let home = self.home_direction(axis);
                        self.command(axis, JobKind::Home(home))?;
                    }
                    if let Some(p) = self.axes.get_mut(index(axis)) {
                        p.coil_home = on;
                    }
                }
                _ => {}
            }
        }
        Ok(())
    }

    fn axis_coil(&self, axis: Axis, address: u16) -> Result<bool, Exception> {
        let plc = self.axes.get(index(axis)).copied().unwrap_or_default();
        match address {
            COIL_SON => Ok(plc.son()),
            COIL_ALRS => Ok(plc.coil_alrs),
            COIL_STP => Ok(plc.drg1 & DRG1_STP != 0),
            COIL_HOME => Ok(plc.coil_home),
            COIL_STOP => Ok(false),
            _ => Err(Exception::IllegalDataAddress),
        }
    }

    // -------------------------------------------------------------- gateway registers

    fn gateway_read(&self, address: u16) -> Result<u16, Exception> {
        let (major, minor, patch) = self.config.version;
        let uptime = u32::try_from(self.now.0 / 1_000_000).unwrap_or(u32::MAX);
        match address {
            G_VERSION => Ok(u16::from(major) << 8 | u16::from(minor)),
            0x0001 => Ok(patch),
            G_UPTIME => Ok(split(uptime)[0]),
            0x0003 => Ok(split(uptime)[1]),
            G_FAILSAFE => Ok(self.failsafe),
            G_FAILSAFE_COUNT => Ok(self.failsafe_count),
            G_WATCHDOG => {
                Ok(u16::try_from(self.config.watchdog.as_micros() / 1000).unwrap_or(u16::MAX))
            }
            G_BUS_BAUD => Ok(u16::try_from(self.bus_line.0.bits_per_second() / 100).unwrap_or(0)),
            G_BUS_RTIM => Ok(u16::from(self.bus_line.1.get())),
            G_RETRIES => Ok(u16::from(self.engine.config().retries)),
            G_APPLY => Ok(0),
            G_WD_ACTION => Ok(match self.config.watchdog_action {
                WatchdogAction::StopAll => 0,
                WatchdogAction::LatchOnly => 1,
            }),
            G_PIO_AXIS => Ok(self.config.pio_axis.map_or(0xFFFF, |a| u16::from(a.get()))),
            G_SYNC_MASK => Ok(self.sync_mask),
            G_SYNC_START => Ok(0),
            G_SYNC_STATUS => Ok(self.sync_status),
            a if (G_AXIS_CONFIG..G_AXIS_CONFIG + 16 * G_AXIS_CONFIG_LEN).contains(&a) => {
                let offset = a - G_AXIS_CONFIG;
                let axis = Axis::new(u8::try_from(offset / G_AXIS_CONFIG_LEN).unwrap_or(0))
                    .ok_or(Exception::IllegalDataAddress)?;
                self.axis_config_read(axis, offset % G_AXIS_CONFIG_LEN)
            }
            a if (G_REQUEST..G_REQUEST + REQ_LEN as u16).contains(&a) => self
                .request
                .get(usize::from(a - G_REQUEST))
                .copied()
                .ok_or(Exception::IllegalDataAddress),
            a if (G_RESPONSE..G_RESPONSE + RESP_LEN as u16).contains(&a) => self
                .response
                .get(usize::from(a - G_RESPONSE))
                .copied()
                .ok_or(Exception::IllegalDataAddress),
            a if (G_DIAG..G_DIAG + 16 * G_DIAG_LEN).contains(&a) => {
                let offset = a - G_DIAG;
                let axis = Axis::new(u8::try_from(offset / G_DIAG_LEN).unwrap_or(0))
                    .ok_or(Exception::IllegalDataAddress)?;
                Ok(self.diagnostics(axis, offset % G_DIAG_LEN))
            }
            a if (G_PLC..G_PLC + 14).contains(&a) => {
                let c = self.plc_counters;
                let exceptions = [
                    Exception::IllegalFunction,
                    Exception::IllegalDataAddress,
                    Exception::IllegalDataValue,
                    Exception::ServerDeviceFailure,
                ]
                .into_iter()
                .fold(0u32, |n, e| n.wrapping_add(c.exceptions(e)));
                let values = [
                    c.frames,
                    c.crc_errors,
                    exceptions,
                    c.replies,
                    c.ignored,
                    c.broadcasts,
                    c.malformed,
                ];
                Ok(counter_register(&values, a - G_PLC))
            }
            a if (G_BUS..G_BUS + 8).contains(&a) => {
                let c = self.engine.bus_counters();
                let values = [c.unsolicited, c.events_lost, c.queue_full, c.establishments];
                Ok(counter_register(&values, a - G_BUS))
            }
            _ => Err(Exception::IllegalDataAddress),
        }
    }

    fn diagnostics(&self, axis: Axis, offset: u16) -> u16 {
        let state = self.engine.axis(axis);
        let c = state.counters;
        let words = [
            c.frames_sent,
            c.replies,
            c.timeouts,
            c.bcc_errors,
            c.bad_replies,
            c.retries,
            c.rejections,
        ];
        match offset {
            14 => match state.link {
                Link::Unknown => 0,
                Link::Online => 1,
                Link::Offline => 2,
            },
            15 => match state.last_error {
                None => 0,
                Some(LinkError::Timeout) => 0x0100,
                Some(LinkError::Rejected(code)) => 0x0300 | u16::from(code.0),
            },
            _ => counter_register(&words, offset),
        }
    }

    fn axis_config_read(&self, axis: Axis, field: u16) -> Result<u16, Exception> {
        let c = self
            .config
            .axes
            .get(index(axis))
            .copied()
            .unwrap_or_default();
        let stroke = split(u32::try_from(c.stroke.0).unwrap_or(0));
        Ok(match field {
            0 => u16::from(self.config.bus.axes.contains(axis)),
            1 => c.scale.lead.hundredths(),
            2 => u16::from(c.scale.home.code()),
            3 => c.scale.pulses_per_rev,
            4 => stroke[0],
            5 => stroke[1],
            6 => match c.scale.complement {
                Complement::Ones => 1,
                Complement::Twos => 2,
            },
            _ => 0,
        })
    }

    /// Nothing moving, running or waiting, and no establishment under way: APPLY (a break and
    /// the whole establishment, during which no stop could reach an axis) is only safe then.
    fn bus_idle(&self) -> bool {
        !self.engine.establishing()
            && self.sync_status != 1
            && self
                .config
                .bus
                .axes
                .iter()
                .all(|a| !self.engine.busy(a) && !self.engine.axis(a).moving())
    }

    /// Check one gateway register write without applying it.
    fn gateway_check(&self, address: u16, value: u16) -> Result<(), Exception> {
        let valid = match address {
            G_FAILSAFE => value == 0,
            G_WATCHDOG => value == 0 || (50..=60_000).contains(&value),
            G_BUS_BAUD => Baud::from_bits_per_second(u32::from(value) * 100).is_some(),
            G_BUS_RTIM => u8::try_from(value).ok().and_then(Rtim::new).is_some(),
            G_RETRIES => value <= 3,
            G_APPLY => value == 0 || (value == 1 && self.bus_idle()),
            G_WD_ACTION => value <= 1,
            G_PIO_AXIS => value == 0xFFFF || value <= 15,
            G_SYNC_MASK => value & !self.config.bus.axes.0 == 0,
            G_SYNC_START => value <= 1,
            a if (G_AXIS_CONFIG..G_AXIS_CONFIG + 16 * G_AXIS_CONFIG_LEN).contains(&a) => {
                let offset = a - G_AXIS_CONFIG;
                let axis = Axis::new(u8::try_from(offset / G_AXIS_CONFIG_LEN).unwrap_or(0));
                match offset % G_AXIS_CONFIG_LEN {
                    0 => {
                        axis.is_some_and(|ax| value == u16::from(self.config.bus.axes.contains(ax)))
                    }
                    1 | 3 => value > 0,
                    2 => value == 7 || value == 8,
                    // The stroke's high word: strokes above i32::MAX (0.01 mm) make no sense.
                    4 => value < 0x8000,
                    5 => true,
                    6 => value == 1 || value == 2,
                    _ => false,
                }
            }
            a if (G_REQUEST..G_REQUEST + REQ_LEN as u16).contains(&a) => true,
            _ => return Err(Exception::IllegalDataAddress),
        };
        if valid {
            Ok(())
        } else {
            Err(Exception::IllegalDataValue)
        }
    }

    fn gateway_apply(&mut self, address: u16, value: u16) -> Result<(), Exception> {
        match address {
            G_FAILSAFE => self.failsafe = 0,
            G_WATCHDOG => self.config.watchdog = Duration::from_millis(u64::from(value)),
            G_BUS_BAUD => {
                if let Some(baud) = Baud::from_bits_per_second(u32::from(value) * 100) {
                    self.bus_line.0 = baud;
                }
            }
            G_BUS_RTIM => {
                if let Some(rtim) = u8::try_from(value).ok().and_then(Rtim::new) {
                    self.bus_line.1 = rtim;
                }
            }
            G_RETRIES => self.engine.set_retries(u8::try_from(value).unwrap_or(3)),
            G_APPLY if value == 1 => {
                let (baud, rtim) = self.bus_line;
                self.config.bus.baud = baud;
                self.config.bus.rtim = rtim;
                self.engine.reconfigure(baud, rtim);
            }
            G_WD_ACTION => {
                self.config.watchdog_action = if value == 0 {
                    WatchdogAction::StopAll
                } else {
                    WatchdogAction::LatchOnly
                }
            }
            G_PIO_AXIS => self.config.pio_axis = u8::try_from(value).ok().and_then(Axis::new),
            G_SYNC_MASK => self.sync_mask = value,
            G_SYNC_START if value == 1 => self.start_sync()?,
            a if (G_AXIS_CONFIG..G_AXIS_CONFIG + 16 * G_AXIS_CONFIG_LEN).contains(&a) => {
                let offset = a - G_AXIS_CONFIG;
                let i = usize::from(offset / G_AXIS_CONFIG_LEN);
                let Some(c) = self.config.axes.get_mut(i) else {
                    return Err(Exception::IllegalDataAddress);
                };
                match offset % G_AXIS_CONFIG_LEN {
                    1 => c.scale.lead = Lead::from_hundredths(value).unwrap_or(c.scale.lead),
                    2 => {
                        c.scale.home = if value == 7 {
                            HomeDirection::MotorEnd
                        } else {
                            HomeDirection::NonMotorEnd
                        }
                    }
                    3 => c.scale.pulses_per_rev = value,
                    4 => {
                        let lo = (c.stroke.0 as u32) & 0xFFFF;
                        c.stroke =
                            Length(i32::try_from(join(value, lo as u16)).unwrap_or(i32::MAX));
                    }
                    5 => {
                        let hi = (c.stroke.0 as u32) >> 16;
                        c.stroke =
                            Length(i32::try_from(join(hi as u16, value)).unwrap_or(i32::MAX));
                    }
                    6 => {
                        c.scale.complement = if value == 1 {
                            Complement::Ones
                        } else {
                            Complement::Twos
                        }
                    }
                    _ => {}
                }
            }
            a if (G_REQUEST..G_REQUEST + REQ_LEN as u16).contains(&a) => {
                if let Some(slot) = self.request.get_mut(usize::from(a - G_REQUEST)) {
                    *slot = value;
                }
            }
            _ => {}
        }
        Ok(())
    }
}

/// The address of the `i`-th register or coil of a request starting at `address`, if there is one.
fn nth(address: u16, i: usize) -> Option<u16> {
    u16::try_from(i).ok().and_then(|i| address.checked_add(i))
}

/// Whether `address` is an axis register readable from `table` (the position table aside).
fn axis_address(address: u16, table: RegisterTable) -> bool {
    matches!(address, PNOW..=DSSE | CMST..=CMCT)
        || (table == RegisterTable::Holding && (address == DRG1 || address == POSR))
}

/// Register `offset` of a block of u32 counters, two registers each, high word first.
fn counter_register(counters: &[u32], offset: u16) -> u16 {
    let word = counters.get(usize::from(offset / 2)).copied().unwrap_or(0);
    split(word)
        .get(usize::from(offset % 2))
        .copied()
        .unwrap_or(0)
}

/// The point field a command channel request names: its offset from 0x400.
fn channel_field(field: u16) -> Option<PointField> {
    PointField::from_address(crate::Address(0x400 + u32::from(field)))
}

impl DataModel for Gateway {
    fn serves(&self, unit: u8) -> bool {
        unit == self.config.unit || self.config.axis_of_unit(unit).is_some()
    }

    fn read_bits(
        &mut self,
        unit: u8,
        table: BitTable,
        address: u16,
        out: &mut [bool],
    ) -> Result<(), Exception> {
        self.plc_activity();
        let axis = self
            .config
            .axis_of_unit(unit)
            .ok_or(Exception::IllegalDataAddress)?;
        if table != BitTable::Coils {
            return Err(Exception::IllegalDataAddress);
        }
        for (i, slot) in out.iter_mut().enumerate() {
            let a = nth(address, i).ok_or(Exception::IllegalDataAddress)?;
            *slot = self.axis_coil(axis, a)?;
        }
        Ok(())
    }

    fn read_registers(
        &mut self,
        unit: u8,
        table: RegisterTable,
        address: u16,
        out: &mut [u16],
    ) -> Result<(), Exception> {
        self.plc_activity();
        let axis = self.config.axis_of_unit(unit);
        if let Some(axis) = axis {
            // Every address must exist in this table before anything is fetched from the bus.
            for i in 0..out.len() {
                let a = nth(address, i).ok_or(Exception::IllegalDataAddress)?;
                let in_table = super::table::locate(a).is_some();
                if (in_table && table != RegisterTable::Holding)
                    || (!in_table && !axis_address(a, table))
                {
                    return Err(Exception::IllegalDataAddress);
                }
            }
            let table =
                super::table::BASE..super::table::BASE + super::table::ROWS * super::table::ROW_LEN;
            let touches =
                (0..out.len()).any(|i| nth(address, i).is_some_and(|a| table.contains(&a)));
            if touches && !self.table_rows_ready(axis, address, out.len()) {
                // Not read from the controller yet: it is being fetched; ask again shortly.
                return Err(Exception::ServerDeviceFailure);
            }
        }
        for (i, slot) in out.iter_mut().enumerate() {
            let a = nth(address, i).ok_or(Exception::IllegalDataAddress)?;
            *slot = match axis {
                Some(axis) => self.axis_read(axis, table, a)?,
                None => self.gateway_read(a)?,
            };
        }
        Ok(())
    }

    fn write_bits(&mut self, unit: u8, address: u16, values: &[bool]) -> Result<(), Exception> {
        self.plc_activity();
        if unit == crate::modbus::BROADCAST {
            // Coils are checked by address only: the first axis refuses before any effect.
            for axis in self.config.bus.axes.iter() {
                self.axis_coils(axis, address, values)?;
            }
            return Ok(());
        }
        let axis = self
            .config
            .axis_of_unit(unit)
            .ok_or(Exception::IllegalDataAddress)?;
        self.axis_coils(axis, address, values)
    }

    fn write_registers(&mut self, unit: u8, address: u16, values: &[u16]) -> Result<(), Exception> {
        self.plc_activity();
        if unit == crate::modbus::BROADCAST {
            // Broadcast: DRG1 or POSR of every axis (checked by value only, so the first axis
            // refuses before any effect). Not a direct move: travel differs between axes.
            if address != DRG1 && address != POSR {
                return Err(Exception::IllegalDataAddress);
            }
            for axis in self.config.bus.axes.iter() {
                self.axis_write(axis, address, values)?;
            }
            return Ok(());
        }
        if let Some(axis) = self.config.axis_of_unit(unit) {
            return self.axis_write(axis, address, values);
        }
        // Gateway unit: check every register, then apply them in order.
        for (i, &value) in values.iter().enumerate() {
            let a = nth(address, i).ok_or(Exception::IllegalDataAddress)?;
            self.gateway_check(a, value)?;
        }
        // A start in this write is checked with the mask the same write sets.
        let at = |register: u16| {
            register
                .checked_sub(address)
                .and_then(|i| values.get(usize::from(i)))
                .copied()
        };
        if at(G_SYNC_START) == Some(1) {
            let mask = at(G_SYNC_MASK).unwrap_or(self.sync_mask);
            self.sync_check(AxisSet(mask))?;
        }
        let request_range = G_REQUEST..G_REQUEST + REQ_LEN as u16;
        let touches_request =
            (0..values.len()).any(|i| nth(address, i).is_some_and(|a| request_range.contains(&a)));
        let mut request = self.request;
        for (i, &value) in values.iter().enumerate() {
            let Some(a) = nth(address, i) else {
                continue;
            };
            if let Some(slot) = a
                .checked_sub(G_REQUEST)
                .and_then(|o| request.get_mut(usize::from(o)))
            {
                *slot = value;
            }
        }
        let start = if touches_request {
            self.channel_check(request)?
        } else {
            None
        };
        for (i, &value) in values.iter().enumerate() {
            let Some(a) = nth(address, i) else {
                continue;
            };
            if a == G_SYNC_START {
                continue;
            }
            self.gateway_apply(a, value)?;
        }
        if touches_request {
            self.channel_request(start)?;
        }
        if let Some(i) = (0..values.len()).find(|&i| nth(address, i) == Some(G_SYNC_START)) {
            let value = values.get(i).copied().unwrap_or(0);
            self.gateway_apply(G_SYNC_START, value)?;
        }
        Ok(())
    }
}
