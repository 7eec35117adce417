//! The settings that survive a power cycle, as the bytes stored in flash.
//!
//! What is stored: the gateway unit's id, the PLC line (rate, parity), the PLC watchdog and its
//! action, the bus (rate, RTIM, resends), the PIO axis, the axes on the bus and every axis'
//! configuration. What is not: anything the gateway learns at run time (links, positions,
//! counters) or knows by itself (its identity, the board).
//!
//! # Format
//! One record of [`RECORD_LEN`] bytes, little endian:
//!
//! | Bytes | Field |
//! |---|---|
//! | 0 | format version ([`FORMAT`]) |
//! | 1 | gateway unit id |
//! | 2-5 | PLC line rate, bit/s |
//! | 6 | PLC parity: 0 none, 1 odd, 2 even |
//! | 7-8 | watchdog, ms |
//! | 9 | watchdog action: 0 stop all, 1 latch only |
//! | 10 | bus rate (BRSL code, complete edition §7-2-1) |
//! | 11 | RTIM, ms |
//! | 12 | resends |
//! | 13 | PIO axis (0xFF: none) |
//! | 14-15 | axes on the bus (bit n = axis n) |
//! | 16 + 10 n | axis n: lead (0.01 mm, 2), pulses/rev (2), home end (1: 7 or 8), complement (1: 1 or 2), stroke (0.01 mm, 4) |
//! | 176 | PIO pattern (IAI's number: 0, 1, 4 or 5) |
//! | 177 | PIO start mode: 0 level, 1 edge |
//! | 178-179 | PIO jog speed, 0.01 mm/s (1-65535) |
//! | 180-181 | PIO inching step, 0.01 mm (1-100) |
//! | 182 | unit id of axis 0 (1-232) |
//! | 183-186 | Ethernet: the board's IPv4 address |
//! | 187 | Ethernet: subnet prefix length (1-32) |
//! | 188-191 | Ethernet: default router (0.0.0.0 none) |
//! | 192 | Modbus TCP: connections at once (1-4) |
//! | 193-194 | Modbus TCP: idle time, s (0-3600) |
//! | 195-210 | Modbus TCP: four allowed client addresses (0.0.0.0 empty) |
//! | 211-212 | CRC-16/MODBUS of bytes 0-210 |
//!
//! [`Settings::decode`] accepts a record only if its version, length, CRC and every field's
//! range are right: a record that is not exactly what [`Settings::encode`] writes is refused
//! as a whole, never applied in part. It also reads the formats before: 2, without the unit
//! base and the network (182 bytes and the CRC: axis 0 is unit 1, the network's defaults), and
//! 1, also without the PIO patterns (176 bytes and the CRC: pattern 0, level mode, the jog's
//! factory values); so the settings a gateway stored before an update survive it.

use super::config::{
    complement_code, complement_of, home_of, stroke_of, AxisBase, AxisConfig, GatewayConfig,
    GatewaySettings, InchStep, JogSpeed, Parity, PlcBaud, PlcLine, UnitId, WatchdogAction,
    WatchdogTime,
};
use crate::axes::AxisSet;
use crate::engine::MAX_RETRIES;
use crate::line::Baud;
use crate::modbus::crc;
use crate::net::{idle_ok, max_connections_ok, prefix_ok, Ipv4, NetConfig, Policy};
use crate::pio::{Pattern, StartMode};
use crate::units::Lead;
use crate::{Axis, Rtim};

/// The format version this code writes (it reads [`FORMAT_2`] and [`FORMAT_1`] too).
pub const FORMAT: u8 = 3;
/// The format before the unit base and the network: [`RECORD_LEN_2`] bytes.
pub const FORMAT_2: u8 = 2;
/// The format before the PIO patterns: [`RECORD_LEN_1`] bytes.
pub const FORMAT_1: u8 = 1;
/// Bytes of one axis' configuration.
const AXIS_LEN: usize = 10;
/// Where the axes start.
const AXES_AT: usize = 16;
/// Where the PIO's pattern and start mode are.
const PIO_AT: usize = AXES_AT + 16 * AXIS_LEN;
/// Where the unit base and the network are.
const NET_AT: usize = PIO_AT + 6;
/// The record's length, CRC included.
pub const RECORD_LEN: usize = NET_AT + 29 + 2;
/// A format 2 record's length, CRC included.
pub const RECORD_LEN_2: usize = NET_AT + 2;
/// A format 1 record's length, CRC included.
pub const RECORD_LEN_1: usize = PIO_AT + 2;

pub use super::config::PLC_BAUDS;

/// Why a stored record is not used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SettingsError {
    /// Not [`RECORD_LEN`] bytes.
    Length,
    /// Another format version.
    Version,
    /// The CRC does not match: the record is damaged.
    Crc,
    /// A field is out of its range (named by its byte offset).
    Field(u8),
}

/// The stored settings: the part of a [`GatewayConfig`] that survives a power cycle, its
/// [`settings`](GatewayConfig::settings) and its bus' rate, RTIM, resends and axes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Settings {
    /// Everything but the bus' part.
    pub gateway: GatewaySettings,
    /// Bus rate.
    pub baud: Baud,
    /// RTIM.
    pub rtim: Rtim,
    /// Resends.
    pub retries: u8,
    /// Axes on the bus.
    pub axes: AxisSet,
}

impl Settings {
    /// The settings of `config`.
    pub fn of(config: &GatewayConfig) -> Settings {
        Settings {
            gateway: config.settings,
            baud: config.bus.baud,
            rtim: config.bus.rtim,
            retries: config.bus.retries,
            axes: config.bus.axes,
        }
    }

    /// `config` with these settings in force.
    #[must_use]
    pub fn apply(&self, mut config: GatewayConfig) -> GatewayConfig {
        self.apply_to(&mut config);
        config
    }

    /// [`Settings::apply`] in place (the firmware's start-up keeps one configuration, no copies).
    pub fn apply_to(&self, config: &mut GatewayConfig) {
        let pattern = config.settings.pio_pattern;
        config.settings = self.gateway;
        // A pattern the board cannot run (settings from another board) stays as it was (the
        // default, at a start).
        if !config.pio_ports.run(self.gateway.pio_pattern) {
            config.settings.pio_pattern = pattern;
        }
        config.bus.baud = self.baud;
        config.bus.rtim = self.rtim;
        config.bus.retries = self.retries;
        config.bus.axes = self.axes;
    }

    /// The record, as stored.
    pub fn encode(&self) -> [u8; RECORD_LEN] {
        let mut out = [0u8; RECORD_LEN];
        let g = &self.gateway;
        let mut w = Fields(&mut out, 0);
        w.u8(FORMAT);
        w.u8(g.unit.get());
        w.bytes(&g.plc.baud.bits_per_second().to_le_bytes());
        w.u8(g.plc.parity as u8);
        w.bytes(&g.watchdog.millis().to_le_bytes());
        w.u8(g.watchdog_action as u8);
        w.u8(self.baud.brsl());
        w.u8(self.rtim.get());
        // As the engine uses it (it clamps a larger one): a record holding more is refused.
        w.u8(self.retries.min(MAX_RETRIES));
        w.u8(g.pio_axis.map_or(0xFF, Axis::get));
        w.bytes(&self.axes.0.to_le_bytes());
        for (_, c) in g.axes.iter() {
            w.bytes(&c.scale.lead.hundredths().to_le_bytes());
            w.bytes(&c.scale.pulses_per_rev.get().to_le_bytes());
            w.u8(c.scale.home.code());
            w.u8(complement_code(c.scale.complement));
            w.bytes(&c.stroke.0.to_le_bytes());
        }
        // Both codes are below 256.
        w.u8(g.pio_pattern.code() as u8);
        w.u8(g.pio_start as u8);
        w.bytes(&g.pio_jog.hundredths().to_le_bytes());
        w.bytes(&g.pio_inch.hundredths().to_le_bytes());
        w.u8(g.axis_base.get());
        w.bytes(&g.net.ip.0);
        w.u8(g.net.prefix);
        w.bytes(&g.net.router.0);
        w.u8(g.net.policy.max_connections);
        w.bytes(&g.net.policy.idle_s.to_le_bytes());
        for address in &g.net.policy.allow {
            w.bytes(&address.0);
        }
        let sum = crc::checksum(out.get(..RECORD_LEN - 2).unwrap_or(&[]));
        if let Some(tail) = out.get_mut(RECORD_LEN - 2..) {
            tail.copy_from_slice(&sum.to_le_bytes());
        }
        out
    }

    /// The settings of a stored record, if it is a whole, valid one.
    pub fn decode(record: &[u8]) -> Result<Settings, SettingsError> {
        let len = match record.first() {
            Some(&FORMAT) => RECORD_LEN,
            Some(&FORMAT_2) => RECORD_LEN_2,
            Some(&FORMAT_1) => RECORD_LEN_1,
            _ if record.len() != RECORD_LEN => return Err(SettingsError::Length),
            _ => return Err(SettingsError::Version),
        };
        if record.len() != len {
            return Err(SettingsError::Length);
        }
        let (body, tail) = record.split_at(len - 2);
        if tail != crc::checksum(body).to_le_bytes() {
            return Err(SettingsError::Crc);
        }
        let r = Reader(body);
        let bad = |at: usize| SettingsError::Field(u8::try_from(at).unwrap_or(u8::MAX));
        let unit = UnitId::new(r.u8(1)).ok_or(bad(1))?;
        let baud = PlcBaud::new(r.u32(2)).ok_or(bad(2))?;
        let parity = Parity::from_code(r.u8(6).into()).ok_or(bad(6))?;
        let watchdog = WatchdogTime::from_millis(r.u16(7)).ok_or(bad(7))?;
        let watchdog_action = WatchdogAction::from_code(r.u8(9).into()).ok_or(bad(9))?;
        let bus_baud = Baud::from_brsl(r.u8(10).into()).ok_or(bad(10))?;
        let rtim = Rtim::new(r.u8(11)).ok_or(bad(11))?;
        let retries = Some(r.u8(12))
            .filter(|&n| n <= MAX_RETRIES)
            .ok_or(bad(12))?;
        let pio_axis = match r.u8(13) {
            0xFF => None,
            a => Some(Axis::new(a).ok_or(bad(13))?),
        };
        let axes = AxisSet(r.u16(14));
        let mut axis_config = crate::AxisMap::new(AxisConfig::DEFAULT);
        for (axis, slot) in axis_config.iter_mut() {
            let at = AXES_AT + AXIS_LEN * usize::from(axis.get());
            let lead = Lead::from_hundredths(r.u16(at)).ok_or(bad(at))?;
            let pulses = core::num::NonZeroU16::new(r.u16(at + 2)).ok_or(bad(at + 2))?;
            let home = home_of(r.u8(at + 4).into()).ok_or(bad(at + 4))?;
            let complement = complement_of(r.u8(at + 5).into()).ok_or(bad(at + 5))?;
            let stroke = stroke_of(r.u32(at + 6)).ok_or(bad(at + 6))?;
            slot.scale.lead = lead;
            slot.scale.pulses_per_rev = pulses;
            slot.scale.home = home;
            slot.scale.complement = complement;
            slot.stroke = stroke;
        }
        let (pio_pattern, pio_start, pio_jog, pio_inch) = if len == RECORD_LEN_1 {
            let jog = (JogSpeed::DEFAULT, InchStep::DEFAULT);
            (Pattern::Positioning, StartMode::Level, jog.0, jog.1)
        } else {
            let pattern = Pattern::from_code(r.u8(PIO_AT).into()).ok_or(bad(PIO_AT))?;
            let start = StartMode::from_code(r.u8(PIO_AT + 1).into()).ok_or(bad(PIO_AT + 1))?;
            let jog = JogSpeed::from_hundredths(r.u16(PIO_AT + 2)).ok_or(bad(PIO_AT + 2))?;
            let inch = InchStep::from_hundredths(r.u16(PIO_AT + 4)).ok_or(bad(PIO_AT + 4))?;
            (pattern, start, jog, inch)
        };
        let (axis_base, net) = if len == RECORD_LEN {
            let base = AxisBase::new(r.u8(NET_AT)).ok_or(bad(NET_AT))?;
            let prefix = Some(r.u8(NET_AT + 5))
                .filter(|&p| prefix_ok(p.into()))
                .ok_or(bad(NET_AT + 5))?;
            let max_connections = Some(r.u8(NET_AT + 10))
                .filter(|&n| max_connections_ok(n.into()))
                .ok_or(bad(NET_AT + 10))?;
            let idle_s = Some(r.u16(NET_AT + 11))
                .filter(|&s| idle_ok(s))
                .ok_or(bad(NET_AT + 11))?;
            let mut allow = [Ipv4::UNSPECIFIED; 4];
            for (at, slot) in (NET_AT + 13..).step_by(4).zip(allow.iter_mut()) {
                *slot = Ipv4(r.array(at));
            }
            let net = NetConfig {
                ip: Ipv4(r.array(NET_AT + 1)),
                prefix,
                router: Ipv4(r.array(NET_AT + 6)),
                policy: Policy {
                    allow,
                    max_connections,
                    idle_s,
                },
            };
            (base, net)
        } else {
            (AxisBase::DEFAULT, NetConfig::DEFAULT)
        };
        let settings = Settings {
            gateway: GatewaySettings {
                unit,
                axis_base,
                plc: PlcLine { baud, parity },
                axes: axis_config,
                watchdog,
                watchdog_action,
                pio_axis,
                pio_pattern,
                pio_start,
                pio_jog,
                pio_inch,
                net,
            },
            baud: bus_baud,
            rtim,
            retries,
            axes,
        };
        // The gateway unit must not be one of the axes' units.
        if axis_base.axis_of(unit.get(), axes).is_some() {
            return Err(bad(1));
        }
        Ok(settings)
    }
}

/// Writes fields one after the other (the record is sized for all of them).
struct Fields<'a>(&'a mut [u8], usize);

impl Fields<'_> {
    fn bytes(&mut self, bytes: &[u8]) {
        if let Some(slot) = self.0.get_mut(self.1..self.1 + bytes.len()) {
            slot.copy_from_slice(bytes);
        }
        self.1 += bytes.len();
    }

    fn u8(&mut self, value: u8) {
        self.bytes(&[value]);
    }
}

/// The fields of a record's body. [`Settings::decode`] has checked the body's length against its
/// format before it reads a field, and reads only the fields of that format: no read can miss,
/// so each gives its value rather than an `Option` every field would unwrap again (a read past
/// the end, which none is, would give zeros).
struct Reader<'a>(&'a [u8]);

impl Reader<'_> {
    /// The `N` bytes at `at`.
    fn array<const N: usize>(&self, at: usize) -> [u8; N] {
        let mut out = [0; N];
        if let Some(bytes) = self.0.get(at..at + N) {
            out.copy_from_slice(bytes);
        }
        out
    }

    fn u8(&self, at: usize) -> u8 {
        self.0.get(at).copied().unwrap_or(0)
    }

    fn u16(&self, at: usize) -> u16 {
        u16::from_le_bytes(self.array(at))
    }

    fn u32(&self, at: usize) -> u32 {
        u32::from_le_bytes(self.array(at))
    }
}
