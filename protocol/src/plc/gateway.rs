//! The gateway: the bus master plus everything the PLC reads and writes, and the rules that
//! tie them together (commands and their fate, the fail-safe, the held SON).
//!
//! The registers themselves are in [`axis_unit`](super::axis_unit) and
//! [`gateway_unit`](super::gateway_unit); the parts with their own state are the
//! [fail-safe](super::failsafe), the [synchronized start](super::sync), the
//! [command channel](super::channel) and the [position table](super::points). Each part reads
//! and drives the [`Engine`]; none calls back into the gateway: it reports what happened and the
//! gateway updates what the PLC sees.

use super::boot::Boot;
use super::channel::Channel;
use super::command::{CommandState, Motion, PlcAxis, Reason};
use super::config::GatewayConfig;
use super::failsafe::{FailSafe, Trip};
use super::persist::{Persist, SettingsRequest};
use super::points::PointCache;
use super::refused::Refused;
use super::sync::{SyncEnd, SyncStart};
use super::teach::{Step, Teach};
use crate::axes::{AxisMap, AxisSet};
use crate::engine::point_jobs::PointReadback;
use crate::engine::{
    Engine, Event, Job, JobError, JobId, JobKind, JobOutput, Link, Output, SubmitError,
};
use crate::modbus::Identity;
use crate::pio::TEACHING;
use crate::time::{earliest, Duration, Instant};
use crate::{Axis, PositionNo};

/// While SON is held ON and the servo is off, it is turned on again at most this often.
const SON_RETRY: Duration = Duration::from_millis(2000);

/// The gateway; see the module documentation (`protocol/src/plc/gateway.rs`).
#[derive(Debug)]
pub struct Gateway {
    pub(super) config: GatewayConfig,
    /// Who the gateway is (FC2B/0E, FC11), and its firmware version (VERSION).
    pub(super) identity: &'static Identity,
    pub(super) axes: AxisMap<PlcAxis>,
    pub(super) failsafe: FailSafe,
    pub(super) sync: SyncStart,
    pub(super) channel: Channel,
    pub(super) points: PointCache,
    /// Pattern 1's PWRT under way.
    teach: Teach,
    /// How the last PWRT ended (stored or not), not yet taken by the PIO.
    taught: Option<bool>,
    /// The settings taken on APPLY or at the next start, and SAVE.
    pub(super) persist: Persist,
    /// APPLY changed the PLC line: the firmware switches after the reply.
    pub(super) plc_line_changed: bool,
    /// The latest time the gateway was given (UPTIME).
    pub(super) now: Instant,
    /// The engine's lost-event count when the gateway last looked.
    events_lost: u32,
    /// Axes that refused a broadcast write (BUS).
    pub(super) broadcast_refusals: u32,
    /// A firmware image's transfer (feature `update`).
    #[cfg(feature = "update")]
    pub(super) update: super::update::Update,
    /// The bus master (last: see [`Gateway::new`]).
    pub(super) engine: Engine,
}

impl Gateway {
    /// A gateway with its bus master. Not inlined, and the engine built last, so that it is
    /// built in place (see [`Node::new`](crate::node::Node::new)): a call made after it into
    /// the same result would keep the engine in a temporary (7 KB, measured on the MCU).
    #[inline(never)]
    pub const fn new(config: GatewayConfig, identity: &'static Identity, boot: Boot) -> Gateway {
        Gateway {
            config,
            identity,
            axes: AxisMap::new(PlcAxis::new()),
            failsafe: FailSafe::new(),
            sync: SyncStart::new(),
            channel: Channel::new(),
            points: PointCache::new(),
            teach: Teach::new(),
            taught: None,
            persist: Persist::new(&config, boot),
            plc_line_changed: false,
            now: Instant::ZERO,
            events_lost: 0,
            broadcast_refusals: 0,
            #[cfg(feature = "update")]
            update: super::update::Update::new(),
            engine: Engine::new(config.bus),
        }
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
        self.failsafe.latched()
    }

    /// The state of an axis' last command and its CMER code.
    pub fn command_state(&self, axis: Axis) -> (CommandState, u16) {
        let plc = &self.axes[axis];
        (plc.state, plc.reason)
    }

    /// Bytes received on the RS485 bus; whether they completed a frame or a rejected candidate
    /// ([`Engine::receive`](crate::engine::Engine::receive)).
    pub fn receive(&mut self, now: Instant, bytes: &[u8]) -> bool {
        self.now = now;
        let changed = self.engine.receive(now, bytes);
        self.handle_events();
        changed
    }

    /// A valid Modbus request to the gateway or one of its axes arrived at `now`: the PLC is
    /// alive (re-arms the watchdog), and its silence counts from `quiet_from` (the end of the
    /// reply, or `now` when there is none).
    pub fn plc_activity(&mut self, now: Instant, quiet_from: Instant) {
        self.now = now;
        self.failsafe.activity(quiet_from);
    }

    /// The stop input (wired like PIO *STP; a functional stop, not a safety function): `active`
    /// when it is OFF. Its activation stops every axis (fail-safe) and no motion starts while it
    /// stays active.
    pub fn set_stop_input(&mut self, now: Instant, active: bool) {
        self.now = now;
        if self.failsafe.set_stop_input(active) {
            self.stop_all();
        }
    }

    /// What to do on the bus at `now`: the watchdog, job bookkeeping, then the engine. An
    /// idle answer's deadline is the earlier of the engine's and the watchdog's.
    pub fn poll(&mut self, now: Instant) -> Output {
        self.now = now;
        let trip = self.failsafe.check(
            now,
            self.config.settings.watchdog.duration(),
            self.config.settings.watchdog_action,
        );
        if trip == Some(Trip::StopAll) {
            self.stop_all();
        }
        self.handle_events();
        self.hold_servo_on(now);
        let output = self.engine.poll(now);
        self.handle_events();
        match output {
            Output::Idle(until) => Output::Idle(earliest(until, self.watchdog_deadline())),
            other => other,
        }
    }

    /// What the firmware is asked to do with the flash (SAVE, a factory reset, RESTART), once.
    pub fn take_settings_request(&mut self) -> Option<SettingsRequest> {
        self.persist.request.take()
    }

    /// The firmware update's transfer (feature `update`).
    #[cfg(feature = "update")]
    pub fn update(&self) -> &super::update::Update {
        &self.update
    }

    /// The bootloader's part of BOOTSTAT (feature `update`): see
    /// [`Node::set_boot_state`](crate::node::Node::set_boot_state).
    #[cfg(feature = "update")]
    pub fn set_boot_state(&mut self, state: super::update::BootState) {
        self.update.set_boot(state);
    }

    /// The version of the image marked (feature `update`): see
    /// [`Node::set_image_version`](crate::node::Node::set_image_version).
    #[cfg(feature = "update")]
    pub fn set_image_version(&mut self, version: u32) {
        self.update.set_image_version(version);
    }

    /// The board and its DFU partition: from now on the PLC link may send an image (feature
    /// `update`).
    #[cfg(feature = "update")]
    pub fn set_update_target(&mut self, target: super::update::Target) {
        self.update.set_target(target);
    }

    /// The flash job of the transfer, if one is due and the bus is quiet
    /// ([`quiet_for_flash`](Self::quiet_for_flash)): handed out once (feature `update`).
    #[cfg(feature = "update")]
    pub fn take_update_job(&mut self) -> Option<super::update::UpdateJob<'_>> {
        // Whether a job is due first: the quiet check walks every axis, and this runs at every
        // idle poll (scripts/cpu-load.sh counts it).
        if self.update.is_due() && self.quiet_for_flash() && self.update.take_due() {
            self.update.job()
        } else {
            None
        }
    }

    /// The caller's result of the flash job handed out (feature `update`).
    #[cfg(feature = "update")]
    pub fn update_done(&mut self, result: Result<(), super::update::UpdateError>) {
        self.update.done(result);
    }

    /// The settings record a SAVE stores ([`SettingsRequest::Save`]): the settings in force with the
    /// pending ones (those APPLY or the next start takes).
    pub fn settings_record(&self) -> [u8; super::settings::RECORD_LEN] {
        self.persist.record(&self.config)
    }

    /// The firmware's answer to a save: the new save count, or a failure (SAVESTAT).
    pub fn stored(&mut self, result: Result<u32, ()>) {
        self.persist.saved(result);
    }

    /// The PLC line, if APPLY changed it since the last call: the firmware switches its UART
    /// (after the reply to the APPLY has gone out at the old settings).
    pub fn take_plc_line(&mut self) -> Option<super::PlcLine> {
        core::mem::take(&mut self.plc_line_changed).then_some(self.config.settings.plc)
    }

    /// When the PLC watchdog trips if the PLC stays silent.
    pub fn watchdog_deadline(&self) -> Option<Instant> {
        self.failsafe
            .deadline(self.config.settings.watchdog.duration())
    }

    /// Whether every configured axis answers.
    pub fn all_online(&self) -> bool {
        self.config.bus.axes.iter().all(|a| self.engine.online(a))
    }

    /// Whether something needs the operator's attention: a latched fail-safe, or an axis in
    /// alarm or offline.
    pub fn alarm(&self) -> bool {
        self.failsafe.latched() != 0 || {
            let (offline, alarm) = self.trouble(self.config.bus.axes);
            offline || alarm
        }
    }

    /// Whether any of `axes` is offline, and whether any is in alarm (one walk over them for
    /// both, shared with the diagnostic register).
    pub(super) fn trouble(&self, axes: AxisSet) -> (bool, bool) {
        let (mut offline, mut alarm) = (false, false);
        for a in axes.iter() {
            let state = self.engine.axis(a);
            offline |= state.link == Link::Offline;
            alarm |= state.report.is_some_and(|r| r.outputs.alarm_active());
        }
        (offline, alarm)
    }

    /// SON is a level, as on a PCON: while the PLC holds it ON, a servo that went off (the alarm
    /// reset turns it off, a servo job failed) is turned on again, every 2 s at most, when
    /// nothing runs on the axis, it is not in alarm and the fail-safe is not engaged. SON OFF is
    /// only ever acted on as a change: a controller's servo is on at power-up, and a PLC that
    /// never uses SON keeps it.
    fn hold_servo_on(&mut self, now: Instant) {
        if self.failsafe.engaged() {
            return;
        }
        for axis in self.config.bus.axes.iter() {
            // Runs on every poll: the PLC's own state first, the engine's only for SON ON.
            let plc = &self.axes[axis];
            if !plc.son() || plc.job.is_some() || now < plc.son_retry {
                continue;
            }
            let state = self.engine.axis(axis);
            let servo_off = state.link == Link::Online
                && state
                    .report
                    .is_some_and(|r| !r.status.servo() && !r.outputs.alarm_active());
            if servo_off && !self.engine.busy(axis) {
                self.axes[axis].son_retry = now + SON_RETRY;
                // Not a PLC command: CMST and CMCT keep showing the PLC's own.
                let _ = self.engine.submit(Job {
                    axis,
                    kind: JobKind::Servo(true),
                });
            }
        }
    }

    /// Stop every axis, before anything else, and give up a synchronized start.
    fn stop_all(&mut self) {
        // Every configured axis, offline ones too: one that dropped out for a moment during a
        // move would carry on when it answers again. A dead one only costs a time-out.
        for axis in self.config.bus.axes.iter() {
            // A stop jumps every queue; it cannot be refused for a configured axis. Its
            // cancellations are read at once, so that none is lost.
            let _ = self.engine.submit(Job {
                axis,
                kind: JobKind::Stop,
            });
            self.handle_events();
        }
        self.give_up_sync();
    }

    /// Give up the synchronized start in progress, if any, and cancel what it buffered.
    fn give_up_sync(&mut self) {
        if let Some(end) = self.sync.fail(&mut self.engine) {
            self.sync_ended(end);
        }
    }

    /// The axes on which no motion may start: STP or EMG held, the stop input active, or the
    /// fail-safe latched and not acknowledged.
    pub(super) fn blocked(&self) -> AxisSet {
        if self.failsafe_holds() {
            return AxisSet::ALL;
        }
        self.axes
            .iter()
            .filter(|(_, plc)| plc.paused())
            .map(|(axis, _)| axis)
            .collect()
    }

    /// The fail-safe holds every axis: the stop input is active, or a latched cause that holds
    /// motion is not acknowledged yet ([`failsafe`](super::failsafe)).
    fn failsafe_holds(&self) -> bool {
        self.failsafe
            .holds_motion(self.config.settings.watchdog_action)
    }

    /// A RES pulse on the discrete inputs (PIOAXIS set, its axis online and showing no alarm):
    /// the fail-safe's acknowledgement by wire, refused (nothing changes) while the stop input
    /// is active; it acknowledges a watchdog latch during the master's silence too, and
    /// disarms the watchdog until a master speaks again (`protocol/src/plc/failsafe.rs`).
    pub fn acknowledge_by_wire(&mut self) {
        self.failsafe.acknowledge(false);
    }

    /// The PIO refused a strobe: its inputs selected no point (`inputs`: what they were). CMST
    /// shows it as a refused command (3, reason 13, the inputs in CMER's low byte), as it does
    /// a refused register write; nothing is sent.
    pub fn pio_refused(&mut self, axis: Axis, inputs: u8) {
        let plc = &mut self.axes[axis];
        plc.job = None;
        plc.sync = false;
        plc.state = CommandState::Failed;
        plc.reason = Reason::PioInput.code(inputs);
    }

    /// Pattern 1's PWRT: store the present position of `axis` into `point` (PNOW read, the row
    /// read, the row stored with the new position: `protocol/src/plc/teach.rs`); CMST shows it
    /// as one command. Refused while the axis does not answer or another PWRT runs.
    pub fn teach(&mut self, axis: Axis, point: PositionNo) -> Result<(), Refused> {
        if !TEACHING || !self.engine.online(axis) {
            return Err(Refused::Offline);
        }
        match self.teach.start(axis, point, &mut self.engine) {
            Ok(id) => {
                self.axes[axis].take(Some(id), Motion::None);
                Ok(())
            }
            Err(reason) => {
                self.axes[axis].fail(reason.code(0));
                Err(Refused::QueueFull)
            }
        }
    }

    /// How the last PWRT ended (`true`: stored), once.
    pub fn take_taught(&mut self) -> Option<bool> {
        self.taught.take()
    }

    /// Point `point` of `axis` as the controller holds it, if the gateway has it cached; else
    /// fetched (the PIO's reed switches of pattern 5 ask for theirs on every sample: used,
    /// they stay cached).
    pub fn point_row(&mut self, axis: Axis, point: PositionNo) -> Option<PointReadback> {
        let row = self.points.get(axis, point);
        if row.is_none() {
            self.points.fetch(axis, point, &mut self.engine);
        }
        row
    }

    /// Submit a command for the PLC (a register write, or the PIO logic's strobe) and record its
    /// fate in CMST/CMER. Motion is refused while STP/EMG or the stop input is active
    /// ([`Refused::Stopped`], recorded); a full queue is refused and recorded too; anything but a
    /// stop is refused while the axis does not answer ([`Refused::Offline`], nothing recorded),
    /// so that it can never run late when the axis appears.
    pub fn command(&mut self, axis: Axis, kind: JobKind) -> Result<(), Refused> {
        let stop = kind == JobKind::Stop;
        if !stop && !self.engine.online(axis) {
            return Err(Refused::Offline);
        }
        // A point's position, if its row is cached (the PLC wrote or read it): the schedule
        // then estimates the arrival as it does for a direct move.
        let kind = match kind {
            JobKind::MoveToPoint(point, None) => {
                JobKind::MoveToPoint(point, self.points.aim(axis, point))
            }
            other => other,
        };
        // (A stop does not move the axis: it is never blocked.)
        let motion = Motion::of(&kind);
        let blocked = motion != Motion::None && self.blocked().contains(axis);
        if motion != Motion::None && !blocked && self.sync.involves(axis) {
            // A move of its own supersedes the synchronized start the axis is in, as a stop
            // does: the start is given up and what it buffered cancelled first, else its `t`
            // would take the axis to the start's point after this move (found by the soak,
            // `scripts/soak.sh`).
            self.give_up_sync();
        }
        let result = if blocked {
            // The fail-safe's own reason, so that the PLC knows an acknowledgement is due.
            Err(if self.failsafe_holds() && !self.failsafe.stop_input() {
                Reason::Failsafe
            } else {
                Reason::Paused
            })
        } else {
            self.engine.submit(Job { axis, kind }).map_err(|e| match e {
                SubmitError::QueueFull | SubmitError::AxisDisabled => Reason::QueueFull,
            })
        };
        if stop {
            // A stop is an interrupt, not a command with an outcome of its own: CMST keeps
            // showing the command it cancels (failed, reason 6).
            self.handle_events();
            // After the stop (which cancels the axis' queued jobs): give the synchronized start
            // up and cancel what it buffered.
            if self.sync.involves(axis) {
                self.give_up_sync();
            }
            return result.map(|_| ()).map_err(|_| Refused::QueueFull);
        }
        let plc = &mut self.axes[axis];
        match result {
            Ok(id) => {
                plc.take(Some(id), motion);
                Ok(())
            }
            Err(reason) => {
                plc.job = None;
                plc.sync = false;
                plc.state = CommandState::Failed;
                plc.reason = reason.code(0);
                Err(match reason {
                    Reason::QueueFull => Refused::QueueFull,
                    _ => Refused::Stopped,
                })
            }
        }
    }

    /// [`command`](Self::command) for a PLC write: a command that STP, EMG or the stop input holds
    /// is taken, and fails at once (CMST 3, reason 10), as a PCON takes a start it does not carry
    /// out; the write stands. The other refusals refuse the write.
    pub(super) fn command_written(&mut self, axis: Axis, kind: JobKind) -> Result<(), Refused> {
        match self.command(axis, kind) {
            Err(Refused::Stopped) => Ok(()),
            other => other,
        }
    }

    /// Read the engine's events: job results become CMST, next steps of the parts.
    pub(super) fn handle_events(&mut self) {
        while let Some(event) = self.engine.next_event() {
            match event {
                Event::JobDone { id, axis, result } => self.job_done(id, axis, result),
                Event::Online(axis) => self.points.forget_axis(axis),
                _ => {}
            }
        }
        let lost = self.engine.bus_counters().events_lost;
        if lost != self.events_lost {
            self.events_lost = lost;
            self.reconcile();
        }
    }

    /// Events were lost (the queue overflowed): a command whose job is gone fails, so that no
    /// CMST stays "taken" for ever.
    fn reconcile(&mut self) {
        for axis in self.config.bus.axes.iter() {
            if let Some(id) = self.axes[axis].job.filter(|&id| !self.engine.pending(id)) {
                self.job_done(id, axis, Err(JobError::Cancelled));
            }
        }
    }

    fn job_done(&mut self, id: JobId, axis: Axis, result: Result<JobOutput, JobError>) {
        let jog_speed = self.config.settings.pio_jog.hundredths();
        let teach = if TEACHING {
            let config = &self.config.settings.axes[axis];
            self.teach
                .job_done(id, &result, config, jog_speed, &mut self.engine)
        } else {
            None
        };
        let plc = &mut self.axes[axis];
        match teach {
            // CMST follows the PWRT's next job.
            Some(Step::Next(next)) if plc.job == Some(id) => plc.job = Some(next),
            Some(Step::Ended(axis, point, ended)) => {
                self.points.forget(axis, point);
                self.taught = Some(ended.is_ok());
                let plc = &mut self.axes[axis];
                if plc.job == Some(id) {
                    match ended {
                        Ok(()) => {
                            plc.job = None;
                            plc.state = CommandState::Done;
                            plc.reason = 0;
                        }
                        Err(cmer) => plc.fail(cmer),
                    }
                }
            }
            _ => {}
        }
        let plc = &mut self.axes[axis];
        if plc.job == Some(id) {
            plc.job = None;
            plc.motion = Motion::None;
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
        let blocked = self.blocked();
        if let Some(end) = self
            .sync
            .job_done(id, axis, &result, blocked, &mut self.engine)
        {
            self.sync_ended(end);
        }
        self.points.job_done(id, axis, &result);
        if let Some((axis, point)) =
            self.channel
                .job_done(id, &result, &self.config.settings.axes, &mut self.engine)
        {
            self.points.forget(axis, point);
        }
    }

    /// A synchronized start began: each axis of the mask shows it taken.
    pub(super) fn sync_taken(&mut self, mask: AxisSet) {
        for axis in mask.iter() {
            self.axes[axis].take(None, Motion::Move);
            self.axes[axis].sync = true;
        }
    }

    /// A synchronized start ended: each axis still showing it follows its move to the end, or
    /// fails with the start.
    fn sync_ended(&mut self, end: SyncEnd) {
        let (SyncEnd::Started(axes) | SyncEnd::Failed(axes, _)) = end;
        for axis in axes.iter() {
            if !self.axes[axis].sync {
                continue;
            }
            let reason = match end {
                SyncEnd::Started(_) => {
                    let job = Job {
                        axis,
                        kind: JobKind::AwaitInPosition,
                    };
                    let plc = &mut self.axes[axis];
                    plc.sync = false;
                    match self.engine.submit(job) {
                        Ok(id) => {
                            plc.job = Some(id);
                            continue;
                        }
                        Err(_) => Reason::QueueFull.code(0),
                    }
                }
                SyncEnd::Failed(_, reason) => reason,
            };
            self.axes[axis].fail(reason);
        }
    }
}
