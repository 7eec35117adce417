//! The gateway unit (id 63 by default, as IAI's RGW-SIO): the gateway's own settings, counters,
//! the synchronized start and the command channel. See [`super::map`] for the table.
//!
//! Writes are checked register by register before any is applied; a register that exists but
//! cannot be written answers 03, one that does not exist 02 (as the axis units do).

use super::axis_unit::link_code;
use super::config::complement_code;
use super::gateway::Gateway;
use super::map::*;
use super::persist::SettingsRequest;
use super::refused::Refused;
use super::registers::{join, split};
use super::write::{admit, axis_cfg, nth, per_axis, AxisSetting, GatewayWrite, Pending};
use crate::engine::LinkError;
use crate::modbus::{Exception, SlaveCounters};
use crate::Axis;

/// DIAG word offsets past the seven u32 counters.
const DIAG_LINK: u16 = 14;
const DIAG_LAST_ERROR: u16 = 15;

/// Register `offset` of a block of u32 counters, two registers each, high word first.
pub(super) fn counter_register(counters: &[u32], offset: u16) -> u16 {
    let word = counters.get(usize::from(offset / 2)).copied().unwrap_or(0);
    split(word)
        .get(usize::from(offset % 2))
        .copied()
        .unwrap_or(0)
}

impl Gateway {
    /// One register of the gateway unit. What takes work to compute (the version, the uptime)
    /// is computed only for its own registers, not for every register read.
    pub(super) fn gateway_read(&self, address: u16, link: &SlaveCounters) -> Result<u16, Refused> {
        Ok(match address {
            G_VERSION | 0x0001 => {
                let (major, minor, patch) = self.identity.version();
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
            G_WATCHDOG => self.config.settings.watchdog.millis(),
            G_BUS_BAUD => u16::try_from(self.persist.baud.bits_per_second() / 100).unwrap_or(0),
            G_BUS_RTIM => u16::from(self.persist.rtim.get()),
            G_PLC_BAUD => self.persist.plc.baud.register(),
            G_PLC_PARITY => self.persist.plc.parity as u16,
            G_UNIT_ID => u16::from(self.persist.unit.get()),
            G_AXIS_BASE => u16::from(self.persist.axis_base.get()),
            G_SAVE | G_FACTORY | G_RESTART => 0,
            G_SAVE_STATUS => self.persist.status as u16,
            G_SAVE_COUNT | 0x0016 => {
                counter_register(&[self.persist.boot.save_count], address - G_SAVE_COUNT)
            }
            G_CONFIG_SOURCE => self.persist.boot.source as u16,
            G_CONFIG_ERRORS => self.persist.boot.load_errors,
            G_RESET_CAUSE => self.persist.boot.reset as u16,
            G_RETRIES => u16::from(self.engine.config().retries),
            G_APPLY | G_SYNC_START => 0,
            G_WD_ACTION => self.config.settings.watchdog_action as u16,
            G_PIO_AXIS => self
                .config
                .settings
                .pio_axis
                .map_or(0xFFFF, |a| u16::from(a.get())),
            G_PIO_PATTERN => self.config.settings.pio_pattern.code(),
            G_PIO_START => self.config.settings.pio_start as u16,
            G_PIO_JOG => self.config.settings.pio_jog.hundredths(),
            G_PIO_INCH => self.config.settings.pio_inch.hundredths(),
            G_SYNC_MASK => self.sync.mask().0,
            G_SYNC_STATUS => self.sync.status() as u16,
            a => {
                if let Some(value) = self.channel.read(a) {
                    return Ok(value);
                }
                #[cfg(feature = "update")]
                if let Some(value) = self.update.read(a) {
                    return Ok(value);
                }
                if let Some((axis, field)) = per_axis(a, G_AXIS_CONFIG, G_AXIS_CONFIG_LEN) {
                    return Ok(self.axis_config_read(axis, field));
                }
                if let Some((axis, offset)) = per_axis(a, G_DIAG, G_DIAG_LEN) {
                    return Ok(self.diagnostics(axis, offset));
                }
                if let Some(offset) = a.checked_sub(G_PLC).filter(|&o| o < G_PLC_LEN) {
                    let exceptions = [
                        Exception::IllegalFunction,
                        Exception::IllegalDataAddress,
                        Exception::IllegalDataValue,
                        Exception::ServerDeviceFailure,
                        Exception::GatewayPathUnavailable,
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
                if let Some(offset) = a.checked_sub(G_BUS).filter(|&o| o < G_BUS_LEN) {
                    let c = self.engine.bus_counters();
                    let values = [
                        c.unsolicited,
                        c.events_lost,
                        c.queue_full,
                        c.establishments,
                        c.stops_owed,
                        self.broadcast_refusals,
                    ];
                    return Ok(counter_register(&values, offset));
                }
                return Err(Refused::NoSuchAddress);
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
            DIAG_LINK => link_code(state.link, self.engine.stop_owed(axis)),
            DIAG_LAST_ERROR => match state.last_error {
                None => 0,
                Some(LinkError::Timeout) => 0x0100,
                Some(LinkError::Rejected(code)) => 0x0300 | u16::from(code.0),
            },
            _ => counter_register(&words, offset),
        }
    }

    fn axis_config_read(&self, axis: Axis, field: u16) -> u16 {
        let c = self.config.settings.axes[axis];
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

    /// Whether the firmware update may start flash work now: no axis moving or with a job
    /// waiting, no synchronized start running, no SAVE pending.
    #[cfg(feature = "update")]
    fn update_gate(&self) -> super::update::Gate {
        let moving = self.sync.status() == super::sync::SyncStatus::Running
            || self
                .config
                .bus
                .axes
                .iter()
                .any(|a| self.engine.busy(a) || self.engine.axis(a).moving());
        let saving = self.persist.request.is_some()
            || self.persist.status == super::persist::SaveStatus::Saving;
        super::update::Gate { moving, saving }
    }

    /// Whether the caller may stall on the update's flash work now (feature `update`): no
    /// axis moves or has a job waiting, no synchronized start runs, no stop is owed. A flash
    /// step blocks the gateway's loop (an L475 page erase up to 25 ms), and a stop must never
    /// wait behind it: while this is false the transfer's work waits instead (a move started
    /// during a transfer pauses it), and a stop that falls due during a step can only be for
    /// an axis that stands.
    #[cfg(feature = "update")]
    pub fn quiet_for_flash(&self) -> bool {
        !self.update_gate().moving
            && !self
                .config
                .bus
                .axes
                .iter()
                .any(|a| self.engine.stop_owed(a))
    }

    /// The rules of a parsed write that depend on the gateway's state, checked before any
    /// register of the write is carried out: APPLY only while nothing moves, runs or waits;
    /// FAILSAFE's acknowledgement only once its cause is gone (the stop input inactive); a
    /// PIOPAT the board has the ports for; and the rules across settings, [`admit`](super::write::admit)'s.
    fn admit(&self, write: GatewayWrite) -> Result<(), Refused> {
        // A SAVE or a factory reset erases settings pages: not while an update's flash job
        // runs (the F429 erases a 128 KiB sector of the same bank by itself, 1-2 s, which the
        // store would have to wait out with the gateway task stopped). Ask again (04), as an
        // update waits for a pending SAVE.
        #[cfg(feature = "update")]
        if matches!(write, GatewayWrite::Save | GatewayWrite::FactoryReset)
            && self.update.flash_busy()
        {
            return Err(Refused::Busy);
        }
        let admitted = match write {
            GatewayWrite::Apply => self.bus_idle(),
            // As a safety relay's reset: only once the cause is gone (`failsafe`).
            GatewayWrite::AckFailsafe => self.failsafe.may_acknowledge(),
            GatewayWrite::PioPattern(pattern) => self.config.pio_ports.run(pattern),
            GatewayWrite::UnitId(_)
            | GatewayWrite::AxisBase(_)
            | GatewayWrite::Axis(_, AxisSetting::Enabled(true))
            | GatewayWrite::SyncMask(_) => {
                let pending = Pending {
                    unit: self.persist.unit,
                    axis_base: self.persist.axis_base,
                    enabled: self.persist.axes,
                    bus: self.config.bus.axes,
                };
                admit(&pending, write).is_ok()
            }
            _ => true,
        };
        if admitted {
            Ok(())
        } else {
            Err(Refused::OutOfRange)
        }
    }

    /// Carries out one admitted register write (the command channel's block and SYNCSTART
    /// aside, which [`gateway_write`](Self::gateway_write) does itself).
    #[inline(never)]
    fn apply(&mut self, write: GatewayWrite) {
        match write {
            GatewayWrite::Nothing | GatewayWrite::ChannelRequest(..) | GatewayWrite::SyncStart => {}
            GatewayWrite::AckFailsafe => self.failsafe.acknowledge(true),
            GatewayWrite::Watchdog(time) => self.config.settings.watchdog = time,
            GatewayWrite::WatchdogAction(action) => self.config.settings.watchdog_action = action,
            GatewayWrite::BusBaud(baud) => self.persist.baud = baud,
            GatewayWrite::BusRtim(rtim) => self.persist.rtim = rtim,
            GatewayWrite::Retries(retries) => {
                // In the settings a SAVE stores, as well as in the engine that uses them.
                self.config.bus.retries = retries;
                self.engine.set_retries(retries);
            }
            GatewayWrite::PlcBaud(baud) => self.persist.plc.baud = baud,
            GatewayWrite::PlcParity(parity) => self.persist.plc.parity = parity,
            GatewayWrite::UnitId(unit) => self.persist.unit = unit,
            GatewayWrite::AxisBase(base) => self.persist.axis_base = base,
            #[cfg(feature = "tcp")]
            GatewayWrite::Net(setting) => self.config.settings.net.set(setting),
            GatewayWrite::Apply => {
                let plc = self.config.settings.plc;
                self.persist.apply_to(&mut self.config);
                self.plc_line_changed |= self.config.settings.plc != plc;
                let bus = &self.config.bus;
                self.engine.reconfigure(bus.axes, bus.baud, bus.rtim);
            }
            GatewayWrite::Save => self.persist.save(),
            GatewayWrite::Restart => self.persist.request = Some(SettingsRequest::Restart),
            GatewayWrite::FactoryReset => {
                self.persist.request = Some(SettingsRequest::FactoryReset)
            }
            GatewayWrite::PioAxis(axis) => self.config.settings.pio_axis = axis,
            GatewayWrite::PioPattern(pattern) => self.config.settings.pio_pattern = pattern,
            GatewayWrite::PioStart(start) => self.config.settings.pio_start = start,
            GatewayWrite::PioJog(speed) => self.config.settings.pio_jog = speed,
            GatewayWrite::PioInch(inch) => self.config.settings.pio_inch = inch,
            GatewayWrite::SyncMask(mask) => self.sync.set_mask(mask),
            GatewayWrite::Axis(axis, setting) => self.apply_axis_setting(axis, setting),
        }
    }

    /// An AXISCFG field of `axis`, stored.
    fn apply_axis_setting(&mut self, axis: Axis, setting: AxisSetting) {
        let c = &mut self.config.settings.axes[axis];
        // The stroke's other word stays as it is.
        let [hi, lo] = split(u32::try_from(c.stroke.0).unwrap_or(0));
        match setting {
            AxisSetting::Enabled(on) => {
                self.persist.axes = if on {
                    self.persist.axes.with(axis)
                } else {
                    self.persist.axes.without(axis)
                };
            }
            AxisSetting::Lead(lead) => c.scale.lead = lead,
            AxisSetting::Home(home) => c.scale.home = home,
            AxisSetting::Pulses(pulses) => c.scale.pulses_per_rev = pulses,
            AxisSetting::StrokeHigh(hi) => c.stroke = stroke(hi, lo),
            AxisSetting::StrokeLow(lo) => c.stroke = stroke(hi, lo),
            AxisSetting::Complement(complement) => c.scale.complement = complement,
        }
    }

    /// FC06/FC10 to the gateway unit: every register parsed and admitted, then carried out in
    /// order (parsed again: parsing is pure); the command channel's request block as a whole,
    /// and SYNCSTART last (with the mask the same write sets).
    pub(super) fn gateway_write(&mut self, address: u16, values: &[u16]) -> Result<(), Refused> {
        #[cfg(feature = "update")]
        {
            let gate = self.update_gate();
            if let Some(result) = self.update.write(address, values, gate) {
                return result;
            }
        }
        // SYNCSTART, and the mask it starts with: the one this write sets, else the one held.
        let mut start_sync = false;
        let mut mask = self.sync.mask();
        // The command channel's request block as the write leaves it, if the write is to it.
        let mut request = self.channel.request();
        let mut requested = false;
        for (i, &value) in values.iter().enumerate() {
            let a = nth(address, i).ok_or(Refused::NoSuchAddress)?;
            let write = GatewayWrite::parse(a, value)?;
            self.admit(write)?;
            match write {
                GatewayWrite::SyncStart => start_sync = true,
                GatewayWrite::SyncMask(set) => mask = set,
                GatewayWrite::ChannelRequest(offset, value) => {
                    if let Some(slot) = request.get_mut(usize::from(offset)) {
                        *slot = value;
                        requested = true;
                    }
                }
                _ => {}
            }
        }
        if start_sync {
            let blocked = self.blocked();
            self.sync.check(mask, blocked, &mut self.engine)?;
        }
        // (Never on a build without the channel, whose parser refuses the block: said here
        // too, so that such a build has none of the channel's code.)
        let request = (CHANNEL && requested).then_some(request);
        let start = match request {
            Some(request) => self.channel.check(request, &self.config)?,
            None => None,
        };
        if let Some(request) = request {
            self.channel.store(request, start, &mut self.engine)?;
        }
        for (i, &value) in values.iter().enumerate() {
            // Parsed and admitted above: parsed again, it is the same write.
            if let Some(write) = nth(address, i).and_then(|a| GatewayWrite::parse(a, value).ok()) {
                self.apply(write);
            }
        }
        if start_sync {
            let blocked = self.blocked();
            let mask = self.sync.mask();
            let axes = &self.axes;
            self.sync
                .start(blocked, |axis| axes[axis].posr, &mut self.engine)?;
            self.sync_taken(mask);
        }
        Ok(())
    }
}

/// A stroke from AXISCFG's two words: within i32 by [`AxisSetting::StrokeHigh`]'s range.
fn stroke(hi: u16, lo: u16) -> crate::units::Length {
    crate::units::Length(i32::try_from(join(hi, lo)).unwrap_or(i32::MAX))
}
