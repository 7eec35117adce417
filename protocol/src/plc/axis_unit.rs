//! The axis units (unit id = axis + 1): IAI PCON's registers and coils, what they show and
//! what writing them does. See [`map`](super::map) for the table.
//!
//! Command bits act on rising edges (HOME, CSTR, ALRS), SON and STP/EMG are levels, as PIO
//! signals are. Every write is checked completely before anything happens: an invalid one gets
//! an exception and never reaches the bus.

use super::gateway::{CommandState, Gateway};
use super::map::*;
use super::registers::{join, status_block};
use super::table;
use crate::engine::{JobId, JobKind, Link};
use crate::modbus::{Bits, Exception, RegisterTable};
use crate::time::Instant;
use crate::units::{Accel, Length, Speed};
use crate::{Axis, HomeDirection, PositionNo};

/// How a running command moves the axis: PEND and PM are masked until it is done, as a PCON
/// drops PEND when it accepts a start (the last status may predate the move), and GHMS shows
/// a home.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) enum Motion {
    /// It does not move the axis.
    #[default]
    None,
    /// A move.
    Move,
    /// The homing procedure.
    Home,
}

impl Motion {
    pub(super) fn of(kind: &JobKind) -> Motion {
        match kind {
            JobKind::Home(_) => Motion::Home,
            JobKind::MoveToPoint(_)
            | JobKind::DirectMove { .. }
            | JobKind::Jog(_)
            | JobKind::MoveAbsolute(_)
            | JobKind::MoveRelative(_) => Motion::Move,
            _ => Motion::None,
        }
    }
}

/// Registers of a direct move (0x9900).
const DIRECT_LEN: usize = DIRECT_MAX as usize;

/// The PLC-side state of one axis.
#[derive(Clone, Copy, Debug)]
pub(super) struct PlcAxis {
    pub(super) drg1: u16,
    pub(super) posr: u16,
    coil_alrs: bool,
    coil_home: bool,
    pub(super) state: CommandState,
    pub(super) reason: u16,
    taken: u16,
    /// The job of the command CMST shows, while it runs.
    pub(super) job: Option<JobId>,
    pub(super) motion: Motion,
    /// CMST shows a synchronized start whose moves have not started yet (no job of its own).
    pub(super) sync: bool,
    /// SON is held ON but the servo is off: try again then.
    pub(super) son_retry: Instant,
    /// The last direct move accepted, as written (0x9900 reads it back).
    direct: [u16; DIRECT_LEN],
}

impl PlcAxis {
    pub(super) const fn new() -> PlcAxis {
        PlcAxis {
            drg1: 0,
            posr: 0,
            coil_alrs: false,
            coil_home: false,
            state: CommandState::Idle,
            reason: 0,
            taken: 0,
            job: None,
            motion: Motion::None,
            sync: false,
            son_retry: Instant::ZERO,
            direct: [0; DIRECT_LEN],
        }
    }

    pub(super) fn son(&self) -> bool {
        self.drg1 & DRG1_SON != 0
    }

    pub(super) fn paused(&self) -> bool {
        self.drg1 & (DRG1_STP | DRG1_EMG) != 0
    }

    /// A command was taken (CMST 1, CMCT + 1).
    pub(super) fn take(&mut self, job: Option<JobId>, motion: Motion) {
        self.job = job;
        self.motion = motion;
        self.sync = false;
        self.state = CommandState::Taken;
        self.reason = 0;
        self.taken = self.taken.wrapping_add(1);
    }

    /// The command CMST shows failed.
    pub(super) fn fail(&mut self, reason: u16) {
        self.job = None;
        self.motion = Motion::None;
        self.sync = false;
        self.state = CommandState::Failed;
        self.reason = reason;
    }

    /// A motion command is taken and not finished.
    fn starting(&self) -> bool {
        self.motion != Motion::None && self.state == CommandState::Taken
    }
}

/// Whether `address` is an axis register readable from `table` (the position table aside).
pub(super) fn readable(address: u16, table: RegisterTable) -> bool {
    matches!(address, PNOW..=DSSE | CMST..=CMCT)
        || (table == RegisterTable::Holding
            && (address == DRG1
                || address == POSR
                || (DIRECT..DIRECT + DIRECT_MAX).contains(&address)))
}

impl Gateway {
    /// One register of an axis unit that [`readable`] (or the position table, for holding
    /// registers) allows in the table read: the caller has checked every address of the request
    /// first, so the table is not looked at again here.
    pub(super) fn axis_read(&mut self, axis: Axis, address: u16) -> Result<u16, Exception> {
        let plc = self.axes[axis];
        let config = self.config.axes[axis];
        let state = self.engine.axis(axis);
        match address {
            PNOW..=DSSE => {
                let paused = plc.paused() || self.failsafe.stop_input();
                let homing = plc.starting() && plc.motion == Motion::Home;
                let block = status_block(state, &config, paused, plc.starting(), homing)
                    .ok_or(Exception::ServerDeviceFailure)?;
                block
                    .get(usize::from(address - PNOW))
                    .copied()
                    .ok_or(Exception::IllegalDataAddress)
            }
            CMST => Ok(plc.state as u16),
            CMER => Ok(plc.reason),
            LINK => Ok(link_code(state.link)),
            CMCT => Ok(plc.taken),
            DRG1 => Ok(plc.drg1),
            POSR => Ok(plc.posr),
            a => {
                if let Some(&value) = a
                    .checked_sub(DIRECT)
                    .and_then(|i| plc.direct.get(usize::from(i)))
                {
                    return Ok(value);
                }
                let (row, offset) = table::locate(a).ok_or(Exception::IllegalDataAddress)?;
                let point = row_point(row)?;
                let readback = self
                    .points
                    .get(axis, point)
                    .ok_or(Exception::ServerDeviceFailure)?;
                table::registers(&readback, &config)
                    .get(usize::from(offset))
                    .copied()
                    .ok_or(Exception::IllegalDataAddress)
            }
        }
    }

    /// Rows of `axis` that a read of `count` registers at `address` needs: whether all are
    /// cached; if not, the first missing one is fetched (one read per axis at a time).
    pub(super) fn table_rows_ready(&mut self, axis: Axis, address: u16, count: usize) -> bool {
        let mut missing = None;
        for a in (0..count).filter_map(|i| nth(address, i)) {
            let Some(point) = table::locate(a).and_then(|(row, _)| row_point(row).ok()) else {
                continue;
            };
            // Marks the rows this request needs as used, so that fetching the others does not
            // push them out.
            if self.points.get(axis, point).is_none() && missing.is_none() {
                missing = Some(point);
            }
        }
        let Some(point) = missing else {
            return true;
        };
        self.points.fetch(axis, point, &mut self.engine);
        false
    }

    /// A write to DRG1: levels (SON, STP, EMG) and rising edges (ALRS, HOME, CSTR).
    fn write_drg1(&mut self, axis: Axis, value: u16) -> Result<(), Exception> {
        let old = self.axes[axis];
        let rising = |bit: u16| value & bit != 0 && old.drg1 & bit == 0;
        let son_changed = (value & DRG1_SON != 0) != old.son();
        // Every command this write causes must be possible, or the write has no effect
        // (exception 04) and the PLC can repeat it; a stop needs no room and is always taken.
        let needed = usize::from(son_changed)
            + usize::from(rising(DRG1_ALRS))
            + usize::from(rising(DRG1_HOME))
            + usize::from(rising(DRG1_CSTR));
        if needed > 0 && (!self.engine.online(axis) || self.engine.room(axis) < needed) {
            return Err(Exception::ServerDeviceFailure);
        }
        self.axes[axis].drg1 = value;
        let now_paused = value & (DRG1_STP | DRG1_EMG) != 0;
        if now_paused && !old.paused() {
            self.command(axis, JobKind::Stop)?;
        }
        if son_changed {
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

    pub(super) fn home_direction(&self, axis: Axis) -> HomeDirection {
        self.config.axes[axis].scale.home
    }

    /// Validate a direct numeric move (0x9900) into a job.
    fn direct_move(&self, axis: Axis, values: &[u16]) -> Result<JobKind, Exception> {
        let config = self.config.axes[axis];
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
        let band = i32::try_from(inp).map_err(|_| Exception::IllegalDataValue)?;
        scale
            .band_to_wire(Length(band))
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

    /// FC06/FC10 to an axis unit.
    pub(super) fn axis_write(
        &mut self,
        axis: Axis,
        address: u16,
        values: &[u16],
    ) -> Result<(), Exception> {
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
                self.axes[axis].posr = *value;
                Ok(())
            }
            (DIRECT, _) => {
                let len = u16::try_from(values.len()).unwrap_or(u16::MAX);
                if !(DIRECT_MIN..=DIRECT_MAX).contains(&len) {
                    return Err(Exception::IllegalDataAddress);
                }
                let kind = self.direct_move(axis, values)?;
                self.command(axis, kind)?;
                let mut direct = [0; DIRECT_LEN];
                for (slot, &v) in direct.iter_mut().zip(values) {
                    *slot = v;
                }
                self.axes[axis].direct = direct;
                Ok(())
            }
            (DRG1..=POSR, _) | (PNOW..=CMCT, _) => Err(Exception::IllegalDataValue),
            // A row is written whole, from its first register.
            (a, _) => match table::locate(a) {
                Some((row, 0)) => self.table_write(axis, row, values),
                _ => Err(Exception::IllegalDataAddress),
            },
        }
    }

    /// Row `row`, written whole at 0x1000 + 16 n: stored unless the controller already holds
    /// it.
    fn table_write(&mut self, axis: Axis, row: u16, values: &[u16]) -> Result<(), Exception> {
        if !(15..=16).contains(&values.len()) {
            return Err(Exception::IllegalDataAddress);
        }
        let config = self.config.axes[axis];
        let data = table::point(values, &config)?;
        let point = row_point(row)?;
        // Unchanged, as the PLC sees it (the cached row in the PLC's units): nothing to do and
        // no bus time spent. Otherwise the store job compares with the controller itself.
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
            .points
            .get(axis, point)
            .is_some_and(|r| table::registers(&r, &config) == wanted);
        if unchanged {
            return Ok(());
        }
        // Not a PLC command: CMST keeps showing the axis' last command. The PLC reads the row
        // back to see it stored (verified on the controller).
        self.points.store(axis, point, data, &mut self.engine)
    }

    /// FC05/FC0F to an axis unit: the stops first, then the rest in address order (two passes
    /// over the coils through one loop body, so that each coil's code is there once).
    pub(super) fn axis_coils(
        &mut self,
        axis: Axis,
        address: u16,
        values: Bits<'_>,
    ) -> Result<(), Exception> {
        coils_exist(address, values.len())?;
        for stops in [true, false] {
            for (i, on) in values.iter().enumerate() {
                let Some(a) = nth(address, i) else {
                    continue;
                };
                let plc = self.axes[axis];
                let (bit, level) = match (a, stops) {
                    (COIL_STOP, true) if on => {
                        self.command(axis, JobKind::Stop)?;
                        continue;
                    }
                    (COIL_STP, true) => (DRG1_STP, on),
                    (COIL_SON, false) => (DRG1_SON, on),
                    (COIL_ALRS, false) => {
                        if on && !plc.coil_alrs {
                            self.command(axis, JobKind::AlarmReset)?;
                        }
                        self.axes[axis].coil_alrs = on;
                        continue;
                    }
                    (COIL_HOME, false) => {
                        if on && !plc.coil_home {
                            let home = self.home_direction(axis);
                            self.command(axis, JobKind::Home(home))?;
                        }
                        self.axes[axis].coil_home = on;
                        continue;
                    }
                    _ => continue,
                };
                self.write_drg1(axis, with_bit(plc.drg1, bit, level))?;
            }
        }
        Ok(())
    }

    /// FC01 of one coil of an axis unit.
    pub(super) fn axis_coil(&self, axis: Axis, address: u16) -> Result<bool, Exception> {
        let plc = &self.axes[axis];
        match address {
            COIL_SON => Ok(plc.son()),
            COIL_ALRS => Ok(plc.coil_alrs),
            COIL_STP => Ok(plc.drg1 & DRG1_STP != 0),
            COIL_HOME => Ok(plc.coil_home),
            COIL_STOP => Ok(false),
            _ => Err(Exception::IllegalDataAddress),
        }
    }
}

/// The coils of an axis unit.
const COILS: [u16; 5] = [COIL_SON, COIL_ALRS, COIL_STP, COIL_HOME, COIL_STOP];

/// 02 unless `count` coils from `address` are all coils of an axis unit.
pub(super) fn coils_exist(address: u16, count: usize) -> Result<(), Exception> {
    if (0..count).all(|i| nth(address, i).is_some_and(|a| COILS.contains(&a))) {
        Ok(())
    } else {
        Err(Exception::IllegalDataAddress)
    }
}

/// LINK: 0 unknown, 1 online, 2 offline.
pub(super) fn link_code(link: Link) -> u16 {
    match link {
        Link::Unknown => 0,
        Link::Online => 1,
        Link::Offline => 2,
    }
}

/// The point of a position-table row.
fn row_point(row: u16) -> Result<PositionNo, Exception> {
    u8::try_from(row)
        .ok()
        .and_then(PositionNo::new)
        .ok_or(Exception::IllegalDataAddress)
}

/// `word` with `bit` set or cleared.
const fn with_bit(word: u16, bit: u16, on: bool) -> u16 {
    if on {
        word | bit
    } else {
        word & !bit
    }
}

/// The address of the `i`-th register or coil of a request starting at `address`, if there is
/// one.
pub(super) fn nth(address: u16, i: usize) -> Option<u16> {
    u16::try_from(i).ok().and_then(|i| address.checked_add(i))
}
