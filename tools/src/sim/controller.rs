//! One Robo Cylinder controller (one axis): line interface, drive state and status.
//!
//! What it models, with the vendor document sections (complete edition unless noted):
//! - **Line** (§2, §6-1, §7-2-1 BRSL note): a baud rate and RTIM. A reply starts exactly RTIM ms
//!   after the last byte of the command was received (the minimum of §2 (1); V5 adds
//!   [`ControllerConfig::store_time_us`] for the non-volatile write). A break (line low for more
//!   than 10 bit times) returns the line to 9.6 kbit/s and RTIM 255 ms. The communication-change
//!   broadcast (STX + 14 ENQ + ETX) arms a switch to the edit area's BRSL/RTIM
//!   [`ControllerConfig::comm_change_delay_us`] after the first one received (§6-1 step 9:
//!   "communication is possible after 150 ms"); repeats while armed are ignored. A BRSL that is
//!   not a rate code means the default state, 9.6 kbit/s and 255 ms (§7-2-1 note).
//! - **Bytes at another baud rate** are not understood: the receiver drops what it had of a
//!   frame and the byte (counted in [`ControllerStats::wrong_baud_bytes`]), so the controller
//!   stays silent. A real UART sees framing errors and a varying number of wrong bytes; none of
//!   them can form a frame with a good BCC that is also addressed to it.
//! - **Responses of other controllers** (data starting with `U`, §3) are ignored.
//! - **Bad BCC** (warning 5F, brief edition §4-3 2): silent by default. See [`BadBccPolicy`].
//! - **Drive** (§4-2, §4-4, §6-2, §6-3): servo on at power-up (§4-4-15), homing to a mechanical
//!   end at OVCM/OACC then OTIM x 16 ms stalled against it (§7-2-1) before ZFIN and position 0,
//!   trapezoidal moves at the execution area's VCMD/ACMD ([`super::motion`]), PFIN when within
//!   the band (INP) of the target (and at power-up), PM1-PM8 showing the completed position
//!   number after Q3 or the abbreviated alarm code in alarm, ZONE between ZONL and ZONM with
//!   ZFIN on, *ALM negative logic. The software stroke limits LIMM/LIML clamp targets and set the
//!   interlock status bits.
//! - **Coordinates**: + is toward the motor. Homing to the motor end puts 0 at the motor end
//!   (coordinates negative, brief edition §4-3 3); homing to the other end puts 0 there
//!   (coordinates positive). The encoder is incremental ("needs homing after each power off",
//!   field research §1a): at power-up the slider stays where it physically is, and the
//!   coordinate there is 0 until homing.
//! - **Alarms** (§8-1): an injected error (80-FF) stops motion and aborts homing, RUN goes off,
//!   *ALM off, PM1-PM8 show the abbreviated code. The servo *instruction* bit stays as it was
//!   (warning 73 reads "servo ON instruction state bit ON", and §4-4-16 asks the host to turn the
//!   servo off before the reset): `r03` is rejected with 73 until `q0`.
//!
//! Not modelled: push moves (MXAC bit 1 moves like a normal positioning), maximum acceleration
//! (MXAC bit 0), current limits, servo gains, PIO inputs other than what
//! [`Controller::set_inputs`] sets.

use std::collections::BTreeMap;

use protocol::alarm::AlarmCode;
use protocol::frame::FRAME_LEN;
use protocol::line::{Baud, BAUD_AFTER_BREAK};
use protocol::memory::{common, PointField};
use protocol::{
    Axis, Command, Deframer, HomeDirection, Inputs, Outputs, PositionNo, Rtim, Status,
    StatusReport, RTIM_AFTER_BREAK,
};

use super::memory::{ci, Actuator, Memory, NonVolatile, PointRow};
use super::motion::{Limits, Profile};
use super::wire::ms;

/// What a controller does with a frame whose BCC is wrong.
///
/// The documents list warning 5F "BCC error" (brief edition §4-3 2) but never say when it is
/// sent. [`Silent`](BadBccPolicy::Silent) is the default: a frame with a bad BCC cannot be
/// trusted to be addressed to this controller at all (the axis character may be the corrupted
/// one), and on a shared bus answering it risks two controllers talking at once; ignoring such
/// a frame is what multidrop slaves conventionally do (IAI's own Modbus mode does it by the
/// Modbus rule). The complete edition's §5 time-out-and-retry procedure covers both cases,
/// so a host must handle silence anyway. [`RejectIfAddressed`](BadBccPolicy::RejectIfAddressed)
/// models a controller that answers a bad-BCC frame whose axis character is its own with a
/// rejection carrying 5F, as field research §4 suggests to expect "if parseable".
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BadBccPolicy {
    /// Ignore the frame (default).
    #[default]
    Silent,
    /// Answer with a rejection, warning 5F, if the axis character is this controller's.
    RejectIfAddressed,
}

/// Warning: BCC error (brief edition §4-3 2).
pub const W_BCC: u8 = 0x5F;
/// Warning: illegal serial character or illegal memory address (§8-1-5).
pub const W_ADDRESS: u8 = 0x61;
/// Warning: first operand incorrect.
pub const W_OPERAND1: u8 = 0x62;
/// Warning: second operand incorrect.
pub const W_OPERAND2: u8 = 0x63;
/// Warning: third operand incorrect.
pub const W_OPERAND3: u8 = 0x64;
/// Warning: move while RUN is off.
pub const W_RUN_OFF: u8 = 0x70;
/// Warning: a/m before homing.
pub const W_NOT_HOMED: u8 = 0x71;
/// Warning: alarm reset with the servo on.
pub const W_RESET_SERVO_ON: u8 = 0x73;
/// Warning: command during motor initialization.
pub const W_INITIALIZING: u8 = 0x74;
/// Warning: move while homing.
pub const W_HOMING: u8 = 0x75;
/// Error: abnormal position data (§8-1-4), raised by Q3 to an empty point.
pub const E_POSITION_DATA: AlarmCode = AlarmCode(0xB1);

/// How a controller is built.
#[derive(Clone, Debug, PartialEq)]
pub struct ControllerConfig {
    /// Stroke and lead.
    pub actuator: Actuator,
    /// Distance of the slider from the motor end at the first power-up, pulses.
    pub start_from_motor_end: u32,
    /// Where Q2/Q3 home when ZFIN is off (§4-4-5: "the system will home before moving"); the
    /// documents' default is the motor end.
    pub home_direction: HomeDirection,
    /// Motor initialization after power-up (warning 74 meanwhile, PFIN off); 0 by default so
    /// that tests can start at once.
    pub init_time_us: u64,
    /// Extra processing before a V5 response (the non-volatile write). The §5 time-out gives V5
    /// 180 ms more than other commands; default 20 ms.
    pub store_time_us: u64,
    /// From the first communication-change broadcast to the new line settings; default 150 ms
    /// (§6-1 step 9).
    pub comm_change_delay_us: u64,
    /// BRSL and RTIM stored in non-volatile memory; `None` (factory) leaves BRSL 0, so the line
    /// starts in the default state, 9.6 kbit/s and 255 ms. The brief edition's controllers
    /// ship at 38.4 kbit/s: `Some((Baud::B38400, ..))` models them.
    pub stored_line: Option<(Baud, Rtim)>,
    /// What to do with a bad-BCC frame.
    pub bad_bcc: BadBccPolicy,
    /// The word R4 0x6800 returns.
    pub rom_version: u32,
    /// Point-table rows present in non-volatile memory at the first power-up.
    pub points: Vec<(PositionNo, PointRow)>,
}

impl Default for ControllerConfig {
    fn default() -> Self {
        ControllerConfig {
            actuator: Actuator::default(),
            start_from_motor_end: 2_000,
            home_direction: HomeDirection::MotorEnd,
            init_time_us: 0,
            store_time_us: ms(20),
            comm_change_delay_us: ms(u64::from(protocol::line::COMM_CHANGE_SETTLE_MS)),
            stored_line: None,
            bad_bcc: BadBccPolicy::Silent,
            rom_version: 0x0000_0104,
            points: Vec::new(),
        }
    }
}

/// What a controller has counted.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ControllerStats {
    /// Bytes received at its own baud rate.
    pub bytes_received: u64,
    /// Bytes sent at another baud rate, not understood.
    pub wrong_baud_bytes: u64,
    /// Good-BCC frames addressed to this axis (accepted or rejected).
    pub frames_addressed: u64,
    /// Good-BCC command frames for other axes, except `t` (counted in `broadcasts`).
    pub frames_for_others: u64,
    /// `t` broadcasts addressed to another axis (executed without replying).
    pub broadcasts: u64,
    /// Communication-change broadcasts received.
    pub comm_change_frames: u64,
    /// Line settings changed by the communication-change broadcast.
    pub comm_changes: u64,
    /// Responses of other controllers heard (and ignored).
    pub foreign_replies: u64,
    /// Frames with a bad BCC.
    pub bad_bcc: u64,
    /// Other broken candidates (truncated, missing ETX, non-hex BCC).
    pub bad_frames: u64,
    /// Rejections sent, by warning code.
    pub rejections: BTreeMap<u8, u64>,
    /// Replies prepared.
    pub replies_scheduled: u64,
    /// Replies put on the line.
    pub replies_sent: u64,
    /// Prepared replies replaced by a newer command before they were sent.
    pub replies_superseded: u64,
    /// Prepared replies cancelled (break, power loss, fault injection).
    pub replies_cancelled: u64,
    /// Breaks detected.
    pub breaks: u64,
    /// Power-ups (the first one included).
    pub power_ups: u64,
}

/// A reply waiting for its time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PendingReply {
    /// When its first byte goes out (µs).
    pub at: u64,
    /// The 16 bytes.
    pub bytes: [u8; FRAME_LEN],
}

/// A positioning move in progress.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Motion {
    pub(super) profile: Profile,
    /// The point number PM1-PM8 show when it completes (Q3 only).
    pub(super) point: Option<PositionNo>,
}

/// Homing in progress.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Homing {
    /// The move to the mechanical end.
    pub(super) profile: Profile,
    pub(super) direction: HomeDirection,
    /// When ZFIN turns on: contact plus OTIM.
    pub(super) done_at: u64,
    /// The move Q2/Q3 asked for, made after homing: raw target and point number.
    pub(super) then: Option<(i64, Option<PositionNo>)>,
}

/// One simulated controller. See the [module documentation](self).
#[derive(Clone, Debug)]
pub struct Controller {
    pub(super) axis: Axis,
    pub(super) config: ControllerConfig,
    pub(super) now: u64,
    pub(super) powered: bool,
    pub(super) baud: Baud,
    pub(super) rtim: u8,
    pub(super) comm_change: Option<(u64, Baud, u8)>,
    pub(super) deframer: Deframer,
    pub(super) memory: Memory,
    pub(super) servo: bool,
    pub(super) alarm: AlarmCode,
    pub(super) zfin: bool,
    pub(super) pfin: bool,
    pub(super) pm: u8,
    pub(super) initializing: bool,
    pub(super) init_until: u64,
    /// Position at rest (coordinate, pulses) when neither moving nor homing.
    pub(super) x: f64,
    /// Coordinate of the motor-end mechanical stop.
    pub(super) mech_max: i64,
    pub(super) motion: Option<Motion>,
    pub(super) homing: Option<Homing>,
    pub(super) buffered: Option<Command>,
    pub(super) inputs: Inputs,
    pub(super) reply: Option<PendingReply>,
    pub(super) last_move_start: Option<u64>,
    pub(super) stats: ControllerStats,
}

/// Result of executing a command: the kind of response, or a warning code.
pub(super) enum Body {
    Status,
    Memory(protocol::MemoryCode, u32),
}

impl Controller {
    /// A controller at `axis`, powered up at `now` with factory settings changed by `config`.
    pub fn new(axis: Axis, config: ControllerConfig, now: u64) -> Controller {
        let mut nv = NonVolatile::factory(&config.actuator);
        if let Some((baud, rtim)) = config.stored_line {
            nv.common[ci(common::BRSL)] = u32::from(baud.brsl());
            nv.common[ci(common::RTIM)] = u32::from(rtim.get());
        }
        for &(point, row) in &config.points {
            let index = usize::from(point.get());
            if let (Some(slot), Some(written)) =
                (nv.points.get_mut(index), nv.written.get_mut(index))
            {
                *slot = row;
                *written = true;
            }
        }
        let mech_max = i64::from(config.start_from_motor_end.min(config.actuator.stroke));
        let mut controller = Controller {
            axis,
            now,
            powered: false,
            baud: BAUD_AFTER_BREAK,
            rtim: RTIM_AFTER_BREAK.get(),
            comm_change: None,
            deframer: Deframer::new(),
            memory: Memory::power_up(nv),
            servo: false,
            alarm: AlarmCode::NONE,
            zfin: false,
            pfin: false,
            pm: 0,
            initializing: false,
            init_until: now,
            x: 0.0,
            mech_max,
            motion: None,
            homing: None,
            buffered: None,
            inputs: Inputs::default(),
            reply: None,
            last_move_start: None,
            stats: ControllerStats::default(),
            config,
        };
        controller.power_on(now);
        controller
    }

    // ----- time -----

    /// Bring the state up to `now` (earlier times are ignored: time only moves forward).
    /// Everything the controller does by itself (moves, homing, the end of motor
    /// initialization, a pending communication change) is computed lazily here.
    pub fn update(&mut self, now: u64) {
        let now = now.max(self.now);
        if !self.powered {
            self.now = now;
            return;
        }
        if let Some((at, baud, rtim)) = self.comm_change {
            if at <= now {
                self.baud = baud;
                self.rtim = rtim;
                self.comm_change = None;
                self.stats.comm_changes += 1;
            }
        }
        if self.initializing && self.init_until <= now {
            self.initializing = false;
            if self.motion.is_none() && self.homing.is_none() {
                self.pfin = true;
            }
        }
        if let Some(homing) = self.homing.take() {
            if homing.done_at <= now {
                self.finish_homing(homing);
            } else {
                self.homing = Some(homing);
            }
        }
        if let Some(motion) = &self.motion {
            let (in_band, end) = (motion.profile.in_band_at(), motion.profile.end());
            let (target, point) = (motion.profile.target(), motion.point);
            if in_band <= now && !self.pfin {
                self.pfin = true;
                self.pm = point.map_or(0, PositionNo::get);
            }
            if end <= now {
                self.x = self.clamp_mechanical(target as f64);
                self.motion = None;
            }
        }
        self.now = now;
    }

    /// Coordinate of the motor-end stop minus the stroke: the other mechanical end.
    pub(super) fn mech_min(&self) -> i64 {
        self.mech_max - i64::from(self.config.actuator.stroke)
    }

    pub(super) fn clamp_mechanical(&self, x: f64) -> f64 {
        x.clamp(self.mech_min() as f64, self.mech_max as f64)
    }

    /// Position (pulses, coordinate) and velocity (pulses/ms) at `t` (not before the last
    /// update).
    pub(super) fn kinematics(&self, t: u64) -> (f64, f64) {
        let (x, v) = if let Some(homing) = &self.homing {
            homing.profile.state(t)
        } else if let Some(motion) = &self.motion {
            motion.profile.state(t)
        } else {
            (self.x, 0.0)
        };
        (self.clamp_mechanical(x), v)
    }

    // ----- status -----

    /// RUN: servo on, no alarm, motor initialized (§4-2 Status bit 2).
    pub fn run(&self) -> bool {
        self.servo && self.alarm == AlarmCode::NONE && !self.initializing
    }

    /// The direct-response body as of the last update; `rejection` sets Status bit 7 and puts
    /// the warning in the Alarm byte (§4-3).
    pub fn report(&self, rejection: Option<u8>) -> StatusReport {
        let position = self.position();
        let exec = &self.memory;
        let in_range = |low: protocol::Address, high: protocol::Address| {
            (exec.exec_position(low)..=exec.exec_position(high)).contains(&position)
        };
        let status = Status::POWER
            .with(Status::SERVO, self.servo)
            .with(Status::RUN, self.run())
            .with(Status::HOME, self.zfin)
            .with(Status::BUFFERED, self.buffered.is_some())
            .with(
                Status::PLUS_INTERLOCK,
                self.zfin && position >= exec.exec_position(common::LIMM),
            )
            .with(
                Status::MINUS_INTERLOCK,
                self.zfin && position <= exec.exec_position(common::LIML),
            )
            .with(Status::REJECTED, rejection.is_some());
        let in_alarm = self.alarm != AlarmCode::NONE;
        let pm = if in_alarm {
            self.alarm
                .info()
                .and_then(|info| info.abbreviated)
                .unwrap_or(0)
        } else {
            self.pm
        };
        let outputs = Outputs::from_bits(pm & 0x0F)
            .with(Outputs::PFIN, self.pfin)
            .with(Outputs::ZFIN, self.zfin)
            .with(
                Outputs::ZONE,
                self.zfin && in_range(common::ZONL, common::ZONM),
            )
            .with(Outputs::ALM_N, !in_alarm);
        StatusReport {
            status,
            alarm: rejection.map_or(self.alarm, AlarmCode),
            inputs: self.inputs,
            outputs,
        }
    }

    // ----- accessors -----

    /// The axis number.
    pub fn axis(&self) -> Axis {
        self.axis
    }
    /// The configuration it was built with.
    pub fn config(&self) -> &ControllerConfig {
        &self.config
    }
    /// Time of the last update (µs).
    pub fn now(&self) -> u64 {
        self.now
    }
    /// Whether it has power.
    pub fn powered(&self) -> bool {
        self.powered
    }
    /// Its line rate.
    pub fn baud(&self) -> Baud {
        self.baud
    }
    /// Its minimum response delay RTIM (ms).
    pub fn rtim_ms(&self) -> u8 {
        self.rtim
    }
    /// Answer after `ms` from now on, whatever the master set: a controller behind a converter
    /// faster or slower than the wire time the master counts on (benchmarks vary the
    /// transaction time with it).
    pub fn set_rtim_ms(&mut self, ms: u8) {
        self.rtim = ms;
    }
    /// A communication change waiting: when, and the rate and RTIM it will set.
    pub fn pending_comm_change(&self) -> Option<(u64, Baud, u8)> {
        self.comm_change
    }
    /// The servo-on instruction state (Status bit 1).
    pub fn servo(&self) -> bool {
        self.servo
    }
    /// The alarm (00 or an error 80-FF).
    pub fn alarm(&self) -> AlarmCode {
        self.alarm
    }
    /// ZFIN / HOME.
    pub fn homed(&self) -> bool {
        self.zfin
    }
    /// Whether homing is in progress.
    pub fn homing(&self) -> bool {
        self.homing.is_some()
    }
    /// Whether motor initialization is in progress (warning 74).
    pub fn initializing(&self) -> bool {
        self.initializing
    }
    /// PFIN.
    pub fn pfin(&self) -> bool {
        self.pfin
    }
    /// Whether a move (not homing) is in progress.
    pub fn moving(&self) -> bool {
        self.motion.is_some()
    }
    /// The present position (PNOW), pulses, rounded.
    pub fn position(&self) -> i64 {
        self.kinematics(self.now).0.round() as i64
    }
    /// The present velocity (VNOW), 0.2 rpm, signed (+ toward the motor).
    pub fn velocity_units(&self) -> i64 {
        Limits::velocity_units(self.kinematics(self.now).1)
    }
    pub(super) fn physical_position_f64(&self) -> f64 {
        self.mech_max as f64 - self.kinematics(self.now).0
    }
    /// Distance of the slider from the motor end, pulses: unchanged by power cycles.
    pub fn physical_position(&self) -> i64 {
        self.physical_position_f64().round() as i64
    }
    /// The execution area's target position PCMD.
    pub fn target(&self) -> i64 {
        i64::from(self.memory.exec_field(PointField::Position) as i32)
    }
    /// The buffered command waiting for `t`.
    pub fn buffered(&self) -> Option<Command> {
        self.buffered
    }
    /// When the last move or homing started (µs).
    pub fn last_move_start(&self) -> Option<u64> {
        self.last_move_start
    }
    /// The move in progress.
    pub fn profile(&self) -> Option<&Profile> {
        self.motion.as_ref().map(|m| &m.profile)
    }
    /// When homing in progress completes (µs).
    pub fn homing_done_at(&self) -> Option<u64> {
        self.homing.as_ref().map(|h| h.done_at)
    }
    /// The three memory areas.
    pub fn memory(&self) -> &Memory {
        &self.memory
    }
    /// The three memory areas, for test set-up.
    pub fn memory_mut(&mut self) -> &mut Memory {
        &mut self.memory
    }
    /// What it has counted.
    pub fn stats(&self) -> &ControllerStats {
        &self.stats
    }
    /// The prepared reply.
    pub fn pending_reply(&self) -> Option<&PendingReply> {
        self.reply.as_ref()
    }

    /// Set the PIO inputs the IN byte reports.
    pub fn set_inputs(&mut self, inputs: Inputs) {
        self.inputs = inputs;
    }

    /// Raise an error (80-FF) at `now` (§8-1): motion stops, RUN and *ALM go off, PM1-PM8
    /// show the abbreviated code. Warnings (01-7F) are not alarms and are refused.
    pub fn inject_alarm(&mut self, now: u64, code: AlarmCode) -> Result<(), AlarmCode> {
        if code.level() != protocol::alarm::Level::Error {
            return Err(code);
        }
        self.update(now);
        self.raise(now, code);
        Ok(())
    }
}
