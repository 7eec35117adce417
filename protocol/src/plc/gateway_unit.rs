//! The gateway unit (id 63 by default, as IAI's RGW-SIO): the gateway's own settings, counters,
//! the synchronized start and the command channel. See [`super::map`] for the table.
//!
//! Writes are checked register by register before any is applied; a register that exists but
//! cannot be written answers 03, one that does not exist 02 (as the axis units do).

use super::axis_unit::{link_code, nth};
use super::channel::Channel;
use super::config::{
    axis_of, complement_code, complement_of, home_of, stroke_of, unit_ok, watchdog_ok, Parity,
    WatchdogAction,
};
use super::gateway::Gateway;
use super::map::{self, *};
use super::persist::Store;
use super::registers::{join, split};
use super::settings::PLC_BAUDS;
use crate::axes::AxisSet;
use crate::engine::{LinkError, MAX_RETRIES};
use crate::line::Baud;
use crate::modbus::{Exception, SlaveCounters};
use crate::time::Duration;
use crate::units::Lead;
use crate::{Axis, PositionNo, Rtim};

/// If `apply`, `slot` takes `parsed` when it is a value; whether it is one (the register's
/// verdict). The shape of most registers: one conversion for the check and the store.
fn store<T>(apply: bool, parsed: Option<T>, slot: &mut T) -> bool {
    let valid = parsed.is_some();
    if let (true, Some(value)) = (apply, parsed) {
        *slot = value;
    }
    valid
}

/// AXISCFG field offsets.
mod axis_cfg {
    pub const ENABLED: u16 = 0;
    pub const LEAD: u16 = 1;
    pub const HOME: u16 = 2;
    pub const PULSES: u16 = 3;
    pub const STROKE_HI: u16 = 4;
    pub const STROKE_LO: u16 = 5;
    pub const COMPLEMENT: u16 = 6;
}

/// DIAG word offsets past the seven u32 counters.
const DIAG_LINK: u16 = 14;
const DIAG_LAST_ERROR: u16 = 15;

/// The axis and field offset of an address in a per-axis block of `len` registers at `base`.
fn per_axis(address: u16, base: u16, len: u16) -> Option<(Axis, u16)> {
    let offset = address.checked_sub(base)?;
    let axis = Axis::new(u8::try_from(offset / len).ok()?)?;
    Some((axis, offset % len))
}

/// Register `offset` of a block of u32 counters, two registers each, high word first.
fn counter_register(counters: &[u32], offset: u16) -> u16 {
    let word = counters.get(usize::from(offset / 2)).copied().unwrap_or(0);
    split(word)
        .get(usize::from(offset % 2))
        .copied()
        .unwrap_or(0)
}

impl Gateway {
    /// One register of the gateway unit. What takes work to compute (the version, the uptime)
    /// is computed only for its own registers, not for every register read.
    pub(super) fn gateway_read(
        &self,
        address: u16,
        link: &SlaveCounters,
    ) -> Result<u16, Exception> {
        Ok(match address {
            G_VERSION | 0x0001 => {
                let (major, minor, patch) = self.config.identity.version();
                if address == G_VERSION {
                    u16::from(major) << 8 | u16::from(minor)
                } else {
                    patch
                }
            }
            G_UPTIME | 0x0003 => {
                let uptime = u32::try_from(self.now.as_secs()).unwrap_or(u32::MAX);
                counter_register(&[uptime], address - G_UPTIME)
            }
            G_FAILSAFE => self.failsafe.latched(),
            G_FAILSAFE_COUNT => self.failsafe.count(),
            G_WATCHDOG => u16::try_from(self.config.watchdog.as_millis()).unwrap_or(u16::MAX),
            G_BUS_BAUD => u16::try_from(self.persist.baud.bits_per_second() / 100).unwrap_or(0),
            G_BUS_RTIM => u16::from(self.persist.rtim.get()),
            G_PLC_BAUD => u16::try_from(self.persist.plc.baud / 100).unwrap_or(0),
            G_PLC_PARITY => self.persist.plc.parity as u16,
            G_UNIT_ID => u16::from(self.persist.unit),
            G_SAVE | G_FACTORY | G_RESTART => 0,
            G_SAVE_STATUS => self.persist.status as u16,
            G_SAVE_COUNT | 0x0016 => {
                counter_register(&[self.persist.saves], address - G_SAVE_COUNT)
            }
            G_CONFIG_SOURCE => self.config.boot.source as u16,
            G_CONFIG_ERRORS => self.config.boot.load_errors,
            G_RESET_CAUSE => self.config.boot.reset as u16,
            G_RETRIES => u16::from(self.engine.config().retries),
            G_APPLY | G_SYNC_START => 0,
            G_WD_ACTION => self.config.watchdog_action as u16,
            G_PIO_AXIS => self.config.pio_axis.map_or(0xFFFF, |a| u16::from(a.get())),
            G_SYNC_MASK => self.sync.mask().0,
            G_SYNC_STATUS => self.sync.status() as u16,
            a => {
                if let Some(value) = self.channel.read(a) {
                    return Ok(value);
                }
                if let Some((axis, field)) = per_axis(a, G_AXIS_CONFIG, G_AXIS_CONFIG_LEN) {
                    return Ok(self.axis_config_read(axis, field));
                }
                if let Some((axis, offset)) = per_axis(a, G_DIAG, G_DIAG_LEN) {
                    return Ok(self.diagnostics(axis, offset));
                }
                if let Some(offset) = a.checked_sub(G_PLC).filter(|&o| o < 14) {
                    let exceptions = [
                        Exception::IllegalFunction,
                        Exception::IllegalDataAddress,
                        Exception::IllegalDataValue,
                        Exception::ServerDeviceFailure,
                    ]
                    .into_iter()
                    .fold(0u32, |n, e| n.wrapping_add(link.exceptions(e)));
                    let values = [
                        link.frames,
                        link.crc_errors,
                        exceptions,
                        link.replies,
                        link.ignored,
                        link.broadcasts,
                        link.malformed,
                    ];
                    return Ok(counter_register(&values, offset));
                }
                if let Some(offset) = a.checked_sub(G_BUS).filter(|&o| o < 8) {
                    let c = self.engine.bus_counters();
                    let values = [c.unsolicited, c.events_lost, c.queue_full, c.establishments];
                    return Ok(counter_register(&values, offset));
                }
                return Err(Exception::IllegalDataAddress);
            }
        })
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
            DIAG_LINK => link_code(state.link),
            DIAG_LAST_ERROR => match state.last_error {
                None => 0,
                Some(LinkError::Timeout) => 0x0100,
                Some(LinkError::Rejected(code)) => 0x0300 | u16::from(code.0),
            },
            _ => counter_register(&words, offset),
        }
    }

    fn axis_config_read(&self, axis: Axis, field: u16) -> u16 {
        let c = self.config.axes[axis];
        let stroke = split(u32::try_from(c.stroke.0).unwrap_or(0));
        match field {
            axis_cfg::ENABLED => u16::from(self.persist.axes.contains(axis)),
            axis_cfg::LEAD => c.scale.lead.hundredths(),
            axis_cfg::HOME => u16::from(c.scale.home.code()),
            axis_cfg::PULSES => c.scale.pulses_per_rev.get(),
            axis_cfg::STROKE_HI => stroke[0],
            axis_cfg::STROKE_LO => stroke[1],
            axis_cfg::COMPLEMENT => u16::from(complement_code(c.scale.complement)),
            _ => 0,
        }
    }

    /// Nothing moving, running or waiting, and no establishment under way: APPLY (a break and
    /// the whole establishment, during which no stop could reach an axis) is only safe then.
    fn bus_idle(&self) -> bool {
        !self.engine.establishing()
            && self.sync.status() != super::sync::SyncStatus::Running
            && self
                .config
                .bus
                .axes
                .iter()
                .all(|a| !self.engine.busy(a) && !self.engine.axis(a).moving())
    }

    /// One gateway register write, checked, and carried out if `apply` (the command channel
    /// and SYNCSTART aside, which [`gateway_write`](Self::gateway_write) does itself). A write
    /// runs this twice: first every register is checked (02 for an address that does not
    /// exist, 03 for a read-only register or a value out of range) and nothing changes, then
    /// every register is applied in order. One function for both, so that each register's
    /// rule and conversion are written (and in the firmware) once. When applying, the verdicts
    /// do not count (the map look-up and APPLY's idle test are skipped; the other rules are
    /// worked out and ignored): the check said yes to each, and an earlier register of the same
    /// write (APPLY, say) may have changed what a later one's rule looks at.
    fn gateway_register(&mut self, address: u16, value: u16, apply: bool) -> Result<(), Exception> {
        if !apply && !map::gateway_writable(address).ok_or(Exception::IllegalDataAddress)? {
            return Err(Exception::IllegalDataValue);
        }
        let valid = match address {
            G_FAILSAFE => {
                if apply {
                    self.failsafe.clear();
                }
                value == 0
            }
            G_WATCHDOG => {
                if apply {
                    self.config.watchdog = Duration::from_millis(u64::from(value));
                }
                watchdog_ok(value)
            }
            G_BUS_BAUD => store(
                apply,
                Baud::from_bits_per_second(u32::from(value) * 100),
                &mut self.persist.baud,
            ),
            G_BUS_RTIM => store(
                apply,
                u8::try_from(value).ok().and_then(Rtim::new),
                &mut self.persist.rtim,
            ),
            G_PLC_BAUD => {
                let baud = u32::from(value) * 100;
                if apply {
                    self.persist.plc.baud = baud;
                }
                PLC_BAUDS.contains(&baud)
            }
            G_PLC_PARITY => store(
                apply,
                Parity::from_code(value),
                &mut self.persist.plc.parity,
            ),
            // Not the unit of an axis that is (or will be) on the bus.
            G_UNIT_ID => {
                let axes = AxisSet(self.config.bus.axes.0 | self.persist.axes.0);
                let unit = u8::try_from(value);
                if let (true, Ok(unit)) = (apply, unit) {
                    self.persist.unit = unit;
                }
                unit_ok(value) && unit.is_ok_and(|u| axis_of(u, axes).is_none())
            }
            G_SAVE | G_RESTART => {
                if apply && value == 1 {
                    if address == G_SAVE {
                        self.persist.save(&self.config);
                    } else {
                        self.persist.request = Some(Store::Restart);
                    }
                }
                value <= 1
            }
            G_FACTORY => {
                if apply && value == FACTORY_KEY {
                    self.persist.request = Some(Store::FactoryReset);
                }
                value == 0 || value == FACTORY_KEY
            }
            G_RETRIES => {
                if apply {
                    self.engine
                        .set_retries(u8::try_from(value).unwrap_or(MAX_RETRIES));
                }
                value <= u16::from(MAX_RETRIES)
            }
            G_APPLY if apply => {
                if value == 1 {
                    let pending = self.persist.pending(&self.config);
                    self.plc_line_changed |= pending.plc != self.config.plc;
                    self.config.plc = pending.plc;
                    self.config.unit = pending.unit;
                    self.config.bus.axes = pending.bus.axes;
                    self.config.bus.baud = pending.bus.baud;
                    self.config.bus.rtim = pending.bus.rtim;
                    self.engine
                        .reconfigure(pending.bus.axes, pending.bus.baud, pending.bus.rtim);
                }
                true
            }
            G_APPLY => value == 0 || (value == 1 && self.bus_idle()),
            G_WD_ACTION => store(
                apply,
                WatchdogAction::from_code(value),
                &mut self.config.watchdog_action,
            ),
            G_PIO_AXIS => {
                let axis = u8::try_from(value).ok().and_then(Axis::new);
                if apply {
                    self.config.pio_axis = axis;
                }
                value == 0xFFFF || axis.is_some()
            }
            G_SYNC_MASK => {
                let valid = value & !self.config.bus.axes.0 == 0;
                if apply {
                    self.sync.set_mask(AxisSet(value));
                }
                valid
            }
            G_SYNC_START => value <= 1,
            a if Channel::is_request(a) => true,
            a => match per_axis(a, G_AXIS_CONFIG, G_AXIS_CONFIG_LEN) {
                Some((axis, field)) => self.axis_config_register(axis, field, value, apply),
                None => false,
            },
        };
        if valid || apply {
            Ok(())
        } else {
            Err(Exception::IllegalDataValue)
        }
    }

    /// AXISCFG field `field` of `axis`: whether `value` is valid, and if `apply` it is stored
    /// (see [`gateway_register`](Self::gateway_register)).
    fn axis_config_register(&mut self, axis: Axis, field: u16, value: u16, apply: bool) -> bool {
        if field == axis_cfg::ENABLED {
            // An axis whose unit is the gateway's cannot be enabled.
            let valid = value == 0 || (value == 1 && axis.get() + 1 != self.persist.unit);
            if apply {
                self.persist.axes = if value == 1 {
                    self.persist.axes.with(axis)
                } else {
                    self.persist.axes.without(axis)
                };
            }
            return valid;
        }
        let c = &mut self.config.axes[axis];
        match field {
            axis_cfg::LEAD => store(apply, Lead::from_hundredths(value), &mut c.scale.lead),
            axis_cfg::PULSES => store(
                apply,
                core::num::NonZeroU16::new(value),
                &mut c.scale.pulses_per_rev,
            ),
            axis_cfg::HOME => store(apply, home_of(value), &mut c.scale.home),
            axis_cfg::STROKE_HI | axis_cfg::STROKE_LO => {
                // The other word stays as it is.
                let [hi, lo] = split(u32::try_from(c.stroke.0).unwrap_or(0));
                let (hi, lo) = if field == axis_cfg::STROKE_HI {
                    (value, lo)
                } else {
                    (hi, value)
                };
                store(apply, stroke_of(join(hi, lo)), &mut c.stroke)
            }
            axis_cfg::COMPLEMENT => store(apply, complement_of(value), &mut c.scale.complement),
            _ => false,
        }
    }

    /// FC06/FC10 to the gateway unit: every register checked, then applied in order; the
    /// command channel's request block as a whole, and SYNCSTART last (with the mask the same
    /// write sets).
    pub(super) fn gateway_write(&mut self, address: u16, values: &[u16]) -> Result<(), Exception> {
        for (i, &value) in values.iter().enumerate() {
            let a = nth(address, i).ok_or(Exception::IllegalDataAddress)?;
            self.gateway_register(a, value, false)?;
        }
        let at = |register: u16| {
            register
                .checked_sub(address)
                .and_then(|i| values.get(usize::from(i)))
                .copied()
        };
        let start_sync = at(G_SYNC_START) == Some(1);
        if start_sync {
            let mask = at(G_SYNC_MASK).map_or(self.sync.mask(), AxisSet);
            self.sync.check(mask, self.blocked(), &self.engine)?;
        }
        let request = self.channel.after_write(address, values);
        let start = match request {
            Some(request) => self.channel.check(request, self.config.bus.axes)?,
            None => None,
        };
        if let Some(request) = request {
            self.channel.store(request, start, &mut self.engine)?;
        }
        for (i, &value) in values.iter().enumerate() {
            if let Some(a) = nth(address, i) {
                // Checked above: applying cannot fail.
                let _ = self.gateway_register(a, value, true);
            }
        }
        if start_sync {
            let blocked = self.blocked();
            let mask = self.sync.mask();
            let axes = &self.axes;
            let posr = |axis: Axis| {
                PositionNo::new(u8::try_from(axes[axis].posr).unwrap_or(0))
                    .unwrap_or(PositionNo::MIN)
            };
            self.sync.start(blocked, posr, &mut self.engine)?;
            self.sync_taken(mask);
        }
        Ok(())
    }
}
