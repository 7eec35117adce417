//! What a controller does with each command (complete edition §4-4; rejections §4-3, §8-1-5).
//!
//! Order of the checks for a move: motor initialization (74; only n, q, R4, T4, W4, Q1 are
//! accepted meanwhile), RUN off (70: servo off or alarm), homing in progress (75), and for `a`
//! and `m` only, not homed (71). Q2 with position data and Q3 home first when ZFIN is off
//! (§4-4-5, §4-4-6, §6-2); the brief edition lists 71 for `a`/`m`, and the complete edition's
//! "(a, m, o, and Q2 commands)" under 71 contradicts its own §4-4-5, so `o` and Q2 never get 71.
//!
//! Q2 `01` is accepted and moves (its own example and §6-4 do so, although §4-4-5's text says
//! it is rejected); PM1-PM8 stay 0 after it (§7-1 (2)).

use protocol::alarm::AlarmCode;
use protocol::memory::{common, PointField};
use protocol::{
    Address, Command, DataType, HomeDirection, MemoryCode, PositionNo, ResetKind, Transfer,
};

use super::controller::{
    Body, Controller, Homing, Motion, E_POSITION_DATA, W_ADDRESS, W_HOMING, W_INITIALIZING,
    W_NOT_HOMED, W_OPERAND1, W_RESET_SERVO_ON, W_RUN_OFF,
};
use super::memory::{
    ci, default_row, factory_common, forward_row, locate, pi, position_in_range, row_value_valid,
    Cell, POINT_LEN,
};
use super::motion::{Limits, Profile};

/// OTIM is in units of 16 ms (§7-2-1).
const OTIM_UNIT_US: u64 = 16_000;

/// Commands accepted during motor initialization (§8-1-5, warning 74).
fn allowed_during_init(command: &Command) -> bool {
    matches!(
        command,
        Command::Status
            | Command::Servo(_)
            | Command::ReadMemory { .. }
            | Command::SetWriteAddress { .. }
            | Command::WriteMemory { .. }
            | Command::LoadToEdit(_)
    )
}

impl Controller {
    /// Execute a command received (or released by `t`) at `now`.
    pub(super) fn execute(&mut self, now: u64, command: Command) -> Result<Body, u8> {
        if self.initializing && !allowed_during_init(&command) {
            return Err(W_INITIALIZING);
        }
        match command {
            Command::ReadMemory { address } => self
                .read(address)
                .map(|value| Body::Memory(MemoryCode::ReadMemory, value)),
            Command::SetWriteAddress { address } => match locate(address) {
                Some(Cell::Pnow | Cell::Vnow | Cell::Rom) | None => Err(W_ADDRESS),
                Some(_) => {
                    self.memory.edit.write_address = Some(address.0);
                    Ok(Body::Memory(MemoryCode::SetWriteAddress, address.0))
                }
            },
            Command::WriteMemory { value } => {
                let address = self.memory.edit.write_address.ok_or(W_ADDRESS)?;
                self.write(Address(address), value)?;
                let next = address.wrapping_add(1);
                self.memory.edit.write_address = Some(next);
                Ok(Body::Memory(MemoryCode::WriteMemory, next))
            }
            Command::LoadToEdit(transfer) => {
                self.load(transfer);
                Ok(Body::Status)
            }
            Command::EditToExecution(DataType::CommonParameters) => {
                self.memory.forward_common();
                Ok(Body::Status)
            }
            Command::EditToExecution(DataType::PositionData) => {
                self.check_move(false)?;
                self.move_edit_row(now, None);
                Ok(Body::Status)
            }
            Command::MoveToPoint(point) => {
                self.check_move(false)?;
                let written = self.memory.nv.written.get(usize::from(point.get()));
                if written != Some(&true) {
                    self.raise(now, E_POSITION_DATA);
                    return Ok(Body::Status);
                }
                self.load(Transfer::Point(point));
                self.move_edit_row(now, Some(point));
                Ok(Body::Status)
            }
            Command::StoreFromEdit(transfer) => {
                Ok(Body::Memory(MemoryCode::Store, self.store(transfer)))
            }
            Command::MoveAbsolute(position) => {
                self.check_move(true)?;
                let target = i64::from(position.0);
                if !position_in_range(target) {
                    return Err(W_OPERAND1);
                }
                self.start_move(now, target, None);
                Ok(Body::Status)
            }
            Command::MoveRelative(distance) => {
                self.check_move(true)?;
                let target = self.target() + i64::from(distance.0);
                if !position_in_range(target) {
                    return Err(W_OPERAND1);
                }
                self.start_move(now, target, None);
                Ok(Body::Status)
            }
            Command::CancelMotion => {
                self.cancel(now);
                Ok(Body::Status)
            }
            Command::Buffer(buffered) => {
                let inner = buffered.command().map_err(|_| W_OPERAND1)?;
                // "To cancel a buffered command ... buffer an n command" (§4-4-10).
                self.buffered = (inner != Command::Status).then_some(inner);
                Ok(Body::Status)
            }
            Command::Status => Ok(Body::Status),
            Command::Home(direction) => {
                self.check_move(false)?;
                self.start_homing(now, direction, None);
                Ok(Body::Status)
            }
            Command::SetResponseDelay(rtim) => {
                // Effective from the reply of this command (§6-1 step 2).
                self.rtim = rtim.get();
                Ok(Body::Status)
            }
            Command::Servo(on) => {
                self.set_servo(now, on);
                Ok(Body::Status)
            }
            Command::Reset(ResetKind::AlarmReset) => {
                if self.servo {
                    return Err(W_RESET_SERVO_ON);
                }
                self.alarm = AlarmCode::NONE;
                Ok(Body::Status)
            }
            Command::Reset(ResetKind::InitializeData) => {
                self.initialize_data(now);
                Ok(Body::Status)
            }
            Command::ExecuteBuffered => self.run_buffered(now),
            Command::SetVelocityAcceleration {
                velocity,
                acceleration,
            } => {
                self.memory
                    .set_exec_field(PointField::Velocity, velocity.get().into());
                self.memory
                    .set_exec_field(PointField::Acceleration, acceleration.get().into());
                self.replan(now);
                Ok(Body::Status)
            }
        }
    }

    /// `t` (§4-4-17): run the buffered command, if any; the buffered bit goes to 0.
    pub(super) fn run_buffered(&mut self, now: u64) -> Result<Body, u8> {
        match self.buffered.take() {
            Some(command) if command != Command::ExecuteBuffered => {
                self.execute(now, command).map(|_| Body::Status)
            }
            _ => Ok(Body::Status),
        }
    }

    fn check_move(&self, needs_home: bool) -> Result<(), u8> {
        if !self.run() {
            Err(W_RUN_OFF)
        } else if self.homing.is_some() {
            Err(W_HOMING)
        } else if needs_home && !self.zfin {
            Err(W_NOT_HOMED)
        } else {
            Ok(())
        }
    }

    /// Stop at once (servo off, alarm, power loss): the motor is no longer driven.
    fn halt(&mut self, now: u64) {
        let (x, _) = self.kinematics(now);
        self.x = x;
        if self.homing.take().is_some() {
            self.pfin = false;
        }
        self.motion = None;
    }

    /// Enter alarm `code` (§8-1).
    pub(super) fn raise(&mut self, now: u64, code: AlarmCode) {
        self.halt(now);
        self.alarm = code;
    }

    fn set_servo(&mut self, now: u64, on: bool) {
        if on && !self.servo {
            self.servo = true;
            // The position loop holds the present position: in position.
            if self.alarm == AlarmCode::NONE && !self.initializing {
                self.pfin = true;
            }
        } else if !on && self.servo {
            self.halt(now);
            self.servo = false;
        }
    }

    /// `d` (§4-4-9): PCMD := PNOW; a moving axis decelerates and settles there.
    fn cancel(&mut self, now: u64) {
        let (x, v) = self.kinematics(now);
        let target = x.round() as i64;
        self.set_target_word(target);
        let was_active = self.homing.take().is_some() | self.motion.is_some();
        if was_active || v != 0.0 {
            self.pfin = false;
            self.pm = 0;
            self.motion = Some(Motion {
                profile: Profile::plan(now, x, v, target, self.limits(), self.band()),
                point: None,
            });
        }
    }

    /// `v` during a move changes it on the fly (§6-3).
    fn replan(&mut self, now: u64) {
        let limits = self.limits();
        let band = self.band();
        let (x, v) = self.kinematics(now);
        if let Some(motion) = self.motion.as_mut() {
            let target = motion.profile.target();
            motion.profile = Profile::plan(now, x, v, target, limits, band);
        }
    }

    fn limits(&self) -> Limits {
        Limits::from_units(
            self.memory.exec_field(PointField::Velocity),
            self.memory.exec_field(PointField::Acceleration),
        )
    }

    fn band(&self) -> u64 {
        u64::from(self.memory.exec_field(PointField::Band))
    }

    fn set_target_word(&mut self, target: i64) {
        let word = i32::try_from(target).unwrap_or(0) as u32;
        self.memory.set_exec_field(PointField::Position, word);
    }

    /// Q2 `01` / Q3: forward the edit row with the FLGP rules and move to it.
    fn move_edit_row(&mut self, now: u64, point: Option<PositionNo>) {
        let row = forward_row(&self.memory.edit.point, &self.memory.edit.common);
        self.memory.exec.point = row;
        let target = i64::from(row[pi(PointField::Position)] as i32);
        if !position_in_range(target) {
            self.raise(now, E_POSITION_DATA);
            return;
        }
        self.start_move(now, target, point);
    }

    /// A PTP move command: PCMD := target, PFIN and PM off; home first if ZFIN is off.
    fn start_move(&mut self, now: u64, target: i64, point: Option<PositionNo>) {
        self.set_target_word(target);
        self.pfin = false;
        self.pm = 0;
        if self.zfin {
            self.plan_motion(now, target, point);
        } else {
            let direction = self.config.home_direction;
            self.start_homing(now, direction, Some((target, point)));
        }
    }

    fn plan_motion(&mut self, now: u64, target: i64, point: Option<PositionNo>) {
        let (x, v) = self.kinematics(now);
        self.homing = None;
        let target = self.clamp_target(target);
        self.motion = Some(Motion {
            profile: Profile::plan(now, x, v, target, self.limits(), self.band()),
            point,
        });
        self.pfin = false;
        self.pm = 0;
        self.last_move_start = Some(now);
    }

    /// Targets stay within the software stroke limits and the mechanical ends.
    fn clamp_target(&self, target: i64) -> i64 {
        let low = self.memory.exec_position(common::LIML).max(self.mech_min());
        let high = self.memory.exec_position(common::LIMM).min(self.mech_max);
        if low <= high {
            target.clamp(low, high)
        } else {
            target.clamp(self.mech_min(), self.mech_max)
        }
    }

    /// Home (§4-4-13, §6-2): drive to the mechanical end at OVCM/OACC, stall there for OTIM,
    /// then ZFIN on and coordinate 0. The drive to the end is planned like a positioning move,
    /// so it slows down into the stop; a real axis hits it at OVCM, which with the factory
    /// values is v / 2a, about 10 ms, sooner. No home offset is modelled.
    fn start_homing(
        &mut self,
        now: u64,
        direction: HomeDirection,
        then: Option<(i64, Option<PositionNo>)>,
    ) {
        let (x, v) = self.kinematics(now);
        self.motion = None;
        let end = match direction {
            HomeDirection::MotorEnd => self.mech_max,
            HomeDirection::NonMotorEnd => self.mech_min(),
        };
        let exec = &self.memory.exec.common;
        let limits = Limits::from_units(exec[ci(common::OVCM)], exec[ci(common::OACC)]);
        let stall = u64::from(exec[ci(common::OTIM)]).saturating_mul(OTIM_UNIT_US);
        let profile = Profile::plan(now, x, v, end, limits, 0);
        let done_at = profile.end().saturating_add(stall);
        self.homing = Some(Homing {
            profile,
            direction,
            done_at,
            then,
        });
        self.pfin = false;
        self.pm = 0;
        self.last_move_start = Some(now);
    }

    pub(super) fn finish_homing(&mut self, homing: Homing) {
        self.mech_max = match homing.direction {
            HomeDirection::MotorEnd => 0,
            HomeDirection::NonMotorEnd => i64::from(self.config.actuator.stroke),
        };
        self.x = 0.0;
        self.zfin = true;
        self.pfin = true;
        self.pm = 0;
        self.homing = None;
        match homing.then {
            Some((target, point)) => self.plan_motion(homing.done_at, target, point),
            None => self.set_target_word(0),
        }
    }

    /// `r02` (§4-4-16): factory parameters to the edit area, default operation parameters to
    /// the execution area, target := present position. The line settings stay.
    fn initialize_data(&mut self, now: u64) {
        let factory = factory_common(&self.config.actuator);
        let mut edit_row = default_row(&factory);
        edit_row[pi(PointField::Position)] = 0;
        self.memory.edit.common = factory;
        self.memory.edit.point = edit_row;
        self.memory.exec.common = factory;
        self.memory.exec.point = default_row(&factory);
        self.cancel(now);
    }

    fn load(&mut self, transfer: Transfer) {
        let nv = &self.memory.nv;
        match transfer {
            Transfer::CommonParameters => self.memory.edit.common = nv.common,
            Transfer::Point(point) => {
                let row = nv.points.get(usize::from(point.get())).copied();
                self.memory.edit.point = row.unwrap_or([0; POINT_LEN]);
            }
        }
    }

    /// V5 (§4-4-7): edit area to non-volatile memory; the area's write count, incremented.
    fn store(&mut self, transfer: Transfer) -> u32 {
        let nv = &mut self.memory.nv;
        match transfer {
            Transfer::CommonParameters => {
                nv.common = self.memory.edit.common;
                nv.common_writes = nv.common_writes.wrapping_add(1);
                nv.common_writes
            }
            Transfer::Point(point) => {
                let index = usize::from(point.get());
                if let Some(row) = nv.points.get_mut(index) {
                    *row = self.memory.edit.point;
                }
                if let Some(written) = nv.written.get_mut(index) {
                    *written = true;
                }
                match nv.point_writes.get_mut(index) {
                    Some(count) => {
                        *count = count.wrapping_add(1);
                        *count
                    }
                    None => 0,
                }
            }
        }
    }

    /// R4 (§4-4-1).
    fn read(&self, address: Address) -> Result<u32, u8> {
        let memory = &self.memory;
        let value = match locate(address).ok_or(W_ADDRESS)? {
            Cell::EditCommon(i) => memory.edit.common.get(i).copied(),
            Cell::EditPoint(i) => memory.edit.point.get(i).copied(),
            Cell::ExecCommon(i) if i == ci(common::BRSL) => Some(u32::from(self.baud.brsl())),
            Cell::ExecCommon(i) if i == ci(common::RTIM) => Some(u32::from(self.rtim)),
            Cell::ExecCommon(i) => memory.exec.common.get(i).copied(),
            Cell::ExecPoint(i) => memory.exec.point.get(i).copied(),
            Cell::Pnow => Some(clamp_i32(self.position()) as u32),
            Cell::Vnow => Some(clamp_i32(self.velocity_units()) as u32),
            Cell::Rom => Some(self.config.rom_version),
        };
        value.ok_or(W_ADDRESS)
    }

    /// W4 (§4-4-3) at `address`. The monitors are read-only, and the execution area's BRSL and
    /// RTIM change only through `p`, a break or the communication-change broadcast (§7-3-2), so
    /// those addresses are illegal for writing.
    fn write(&mut self, address: Address, value: u32) -> Result<(), u8> {
        let memory = &mut self.memory;
        let slot = match locate(address).ok_or(W_ADDRESS)? {
            Cell::EditCommon(i) => memory.edit.common.get_mut(i),
            Cell::EditPoint(i) => {
                if !row_value_valid(i, value) {
                    return Err(W_OPERAND1);
                }
                memory.edit.point.get_mut(i)
            }
            Cell::ExecCommon(i) if i == ci(common::BRSL) || i == ci(common::RTIM) => None,
            Cell::ExecCommon(i) => memory.exec.common.get_mut(i),
            Cell::ExecPoint(i) => {
                if !row_value_valid(i, value) {
                    return Err(W_OPERAND1);
                }
                memory.exec.point.get_mut(i)
            }
            Cell::Pnow | Cell::Vnow | Cell::Rom => None,
        };
        let slot = slot.ok_or(W_ADDRESS)?;
        *slot = value;
        Ok(())
    }
}

fn clamp_i32(value: i64) -> i32 {
    i32::try_from(value).unwrap_or(if value < 0 { i32::MIN } else { i32::MAX })
}
