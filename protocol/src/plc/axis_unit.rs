//! The axis units (unit id = axis + 1): IAI PCON's registers and coils, what they show and
//! what writing them does. See [`map`](super::map) for the table.
//!
//! Command bits act on rising edges (HOME, CSTR, ALRS), SON and STP/EMG are levels, as PIO
//! signals are. A write comes here parsed ([`AxisWrite`]); what is checked here is what depends
//! on the axis (its travel, its units, whether it is at rest or online) before anything
//! happens: an invalid write never reaches the bus.

use super::command::{Motion, Reason};
use super::gateway::Gateway;
use super::map::*;
use super::refused::Refused;
use super::registers::status_block;
use super::table;
use super::write::{nth, row_point, AxisWrite, DirectMove, Drg1};
use crate::engine::{JobKind, Link};
use crate::modbus::{Bits, RegisterTable};
use crate::units::{Accel, Length, Speed};
use crate::{Axis, HomeDirection, PositionNo};

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
    pub(super) fn axis_read(&mut self, axis: Axis, address: u16) -> Result<u16, Refused> {
        let plc = self.axes[axis];
        let config = self.config.settings.axes[axis];
        let state = self.engine.axis(axis);
        match address {
            PNOW..=DSSE => {
                let paused = plc.paused() || self.failsafe.stop_input();
                let homing = plc.starting() && plc.motion == Motion::Home;
                let block = status_block(state, &config, paused, plc.starting(), homing)
                    .ok_or(Refused::NotReady)?;
                block
                    .get(usize::from(address - PNOW))
                    .copied()
                    .ok_or(Refused::NoSuchAddress)
            }
            CMST => Ok(plc.state as u16),
            CMER => Ok(plc.reason),
            LINK => Ok(link_code(state.link, self.engine.stop_owed(axis))),
            CMCT => Ok(plc.taken),
            DRG1 => Ok(plc.drg1.bits()),
            POSR => Ok(u16::from(plc.posr.get())),
            a => {
                if let Some(&value) = a
                    .checked_sub(DIRECT)
                    .and_then(|i| plc.direct.get(usize::from(i)))
                {
                    return Ok(value);
                }
                let (row, offset) = table::locate(a).ok_or(Refused::NoSuchAddress)?;
                let point = row_point(row)?;
                let readback = self.points.get(axis, point).ok_or(Refused::NotReady)?;
                table::registers(&readback, &config)
                    .get(usize::from(offset))
                    .copied()
                    .ok_or(Refused::NoSuchAddress)
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

    /// A write to DRG1: levels (SON, STP, EMG) and rising edges (ALRS, HOME, CSTR). A stop in
    /// it (STP or EMG coming on, SON going off) is taken first ([`stop_first`](Self::stop_first));
    /// without one, every command the write causes must be possible, or the write has no effect
    /// (refused) and the PLC can repeat it.
    fn write_drg1(&mut self, axis: Axis, value: Drg1) -> Result<(), Refused> {
        let old = self.axes[axis];
        let rising = |bit: u16| value.has(bit) && !old.drg1.has(bit);
        let son_changed = value.son() != old.son();
        let stops = stop_edge(old.drg1, value);
        if stops {
            self.stop_first(axis);
        } else {
            let needed = usize::from(son_changed)
                + usize::from(rising(DRG1_ALRS))
                + usize::from(rising(DRG1_HOME))
                + usize::from(rising(DRG1_CSTR));
            if needed > 0 && !self.engine.online(axis) {
                return Err(Refused::Offline);
            }
            if needed > 0 && self.engine.room(axis) < needed {
                return Err(Refused::Busy);
            }
        }
        self.axes[axis].drg1 = value;
        if son_changed {
            self.command_written(axis, JobKind::Servo(value.son()))?;
        }
        if rising(DRG1_ALRS) {
            self.command_written(axis, JobKind::AlarmReset)?;
        }
        if rising(DRG1_HOME) {
            let home = self.home_direction(axis);
            self.command_written(axis, JobKind::Home(home))?;
        }
        if rising(DRG1_CSTR) {
            self.command_written(axis, JobKind::MoveToPoint(old.posr, None))?;
        }
        Ok(())
    }

    /// The stop a write carries, before anything else in it: it needs no queue room and is
    /// taken whether the axis answers or not (an axis that does not is owed it until it does:
    /// [`Engine::stop_owed`](crate::engine::Engine::stop_owed)). It also empties the axis'
    /// queue, so the rest of the write finds room.
    fn stop_first(&mut self, axis: Axis) {
        // `command` never refuses a stop for an axis on the bus.
        let _ = self.command(axis, JobKind::Stop);
    }

    /// Whether `write` stops the axis now: STP or EMG coming on, SON going off, or the STOP
    /// coil.
    fn write_stops(&self, axis: Axis, write: &AxisWrite<'_>) -> bool {
        let old = self.axes[axis].drg1;
        match *write {
            AxisWrite::Drg1(value) => stop_edge(old, value),
            AxisWrite::Coils(address, values) => {
                values
                    .iter()
                    .enumerate()
                    .any(|(i, on)| match nth(address, i) {
                        Some(COIL_STOP) => on,
                        Some(COIL_STP) => on && !old.has(DRG1_STP),
                        Some(COIL_SON) => !on && old.son(),
                        _ => false,
                    })
            }
            _ => false,
        }
    }

    pub(super) fn home_direction(&self, axis: Axis) -> HomeDirection {
        self.config.settings.axes[axis].scale.home
    }

    /// A direct move (0x9900) on this axis: within its travel (from where it rests, for an
    /// incremental one), in its units.
    fn direct_move(&self, axis: Axis, m: &DirectMove) -> Result<JobKind, Refused> {
        let config = self.config.settings.axes[axis];
        let scale = config.scale;
        let target = if m.relative() {
            // The end of a relative move must be inside the travel too, from where it is now:
            // so only from rest, with nothing queued that would move it first.
            let state = self.engine.axis(axis);
            if self.engine.busy(axis) || state.moving() {
                return Err(Refused::Busy);
            }
            let here = state
                .position
                .map(|p| scale.position_from_wire(p).0)
                .ok_or(Refused::NotReady)?;
            let end = here.saturating_add(m.pcmd());
            if end < 0 || end > config.stroke.0 {
                return Err(Refused::OutOfRange);
            }
            scale.distance_to_wire(Length(m.pcmd()))
        } else {
            if m.pcmd() < 0 || m.pcmd() > config.stroke.0 {
                return Err(Refused::OutOfRange);
            }
            scale.position_to_wire(Length(m.pcmd()))
        }
        .map_err(|_| Refused::OutOfRange)?;
        scale
            .band_to_wire(Length(m.band()))
            .map_err(|_| Refused::OutOfRange)?;
        let velocity = scale
            .velocity(Speed(m.speed()))
            .map_err(|_| Refused::OutOfRange)?;
        let acceleration = scale
            .acceleration(Accel(u32::from(m.accel())))
            .map_err(|_| Refused::OutOfRange)?;
        Ok(JobKind::DirectMove {
            target,
            relative: m.relative(),
            velocity,
            acceleration,
        })
    }

    /// A parsed write to an axis unit (FC05/06/0F/10), carried out. A write that stops the axis
    /// is never refused for what follows its stop: an axis that does not answer, a full queue
    /// or a busy axis fails that part in CMST (CMER 11 or 9) and the write stands, so the PLC
    /// sees its stop taken (a value the map cannot take is still 02/03, before anything).
    pub(super) fn axis_write(&mut self, axis: Axis, write: &AxisWrite<'_>) -> Result<(), Refused> {
        let stops = self.write_stops(axis, write);
        let result = self.axis_write_parts(axis, write);
        match result {
            Err(refused @ (Refused::Offline | Refused::QueueFull | Refused::Busy)) if stops => {
                let reason = if refused == Refused::Offline {
                    Reason::Offline
                } else {
                    Reason::QueueFull
                };
                self.axes[axis].fail(reason.code(0));
                Ok(())
            }
            other => other,
        }
    }

    fn axis_write_parts(&mut self, axis: Axis, write: &AxisWrite<'_>) -> Result<(), Refused> {
        match *write {
            AxisWrite::Drg1(value) => self.write_drg1(axis, value),
            AxisWrite::Position(point) => {
                self.axes[axis].posr = point;
                Ok(())
            }
            AxisWrite::Direct(ref m) => {
                let kind = self.direct_move(axis, m)?;
                self.command_written(axis, kind)?;
                self.axes[axis].direct = m.registers();
                Ok(())
            }
            AxisWrite::Row(point, values) => self.table_write(axis, point, values),
            AxisWrite::Coils(address, values) => self.axis_coils(axis, address, values),
        }
    }

    /// Row `point`, written whole at 0x1000 + 16 n: stored unless the controller already holds
    /// it.
    fn table_write(
        &mut self,
        axis: Axis,
        point: PositionNo,
        values: &[u16],
    ) -> Result<(), Refused> {
        let config = self.config.settings.axes[axis];
        let data = table::point(values, &config)?;
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

    /// FC05/FC0F to an axis unit (every coil an axis unit's: [`AxisWrite::coils`]): the stops
    /// first, then the rest in address order (two passes over the coils through one loop
    /// body, so that each coil's code is there once).
    fn axis_coils(&mut self, axis: Axis, address: u16, values: Bits<'_>) -> Result<(), Refused> {
        for stops in [true, false] {
            for (i, on) in values.iter().enumerate() {
                let Some(a) = nth(address, i) else {
                    continue;
                };
                let plc = self.axes[axis];
                let (bit, level) = match (a, stops) {
                    (COIL_STOP, true) if on => {
                        self.stop_first(axis);
                        continue;
                    }
                    (COIL_STP, true) => (DRG1_STP, on),
                    (COIL_SON, false) => (DRG1_SON, on),
                    (COIL_ALRS, false) => {
                        if on && !plc.coil_alrs {
                            self.command_written(axis, JobKind::AlarmReset)?;
                        }
                        self.axes[axis].coil_alrs = on;
                        continue;
                    }
                    (COIL_HOME, false) => {
                        if on && !plc.coil_home {
                            let home = self.home_direction(axis);
                            self.command_written(axis, JobKind::Home(home))?;
                        }
                        self.axes[axis].coil_home = on;
                        continue;
                    }
                    _ => continue,
                };
                self.write_drg1(axis, plc.drg1.with(bit, level))?;
            }
        }
        Ok(())
    }

    /// FC01 of one coil of an axis unit.
    pub(super) fn axis_coil(&self, axis: Axis, address: u16) -> Result<bool, Refused> {
        let plc = &self.axes[axis];
        match address {
            COIL_SON => Ok(plc.son()),
            COIL_ALRS => Ok(plc.coil_alrs),
            COIL_STP => Ok(plc.drg1.has(DRG1_STP)),
            COIL_HOME => Ok(plc.coil_home),
            COIL_STOP => Ok(false),
            _ => Err(Refused::NoSuchAddress),
        }
    }
}

/// Whether a DRG1 write from `old` to `new` stops the axis: STP or EMG coming on, or SON
/// going off.
fn stop_edge(old: Drg1, new: Drg1) -> bool {
    (new.paused() && !old.paused()) || (old.son() && !new.son())
}

/// LINK: 0 unknown, 1 online, 2 offline, 3 a stop owed (it got no answer: the axis is offline,
/// and the first frame it answers will be its stop).
pub(super) fn link_code(link: Link, stop_owed: bool) -> u16 {
    match link {
        _ if stop_owed => 3,
        Link::Unknown => 0,
        Link::Online => 1,
        Link::Offline => 2,
    }
}
