//! What a PLC's write means, before anything happens: the register map turns an address and
//! its values into a typed write, with each register's range and conversion written here once.
//! The gateway then carries out a checked write without checking it again
//! (`axis_unit`, `gateway_unit`); the few rules that
//! depend on the gateway's state are an `admit` step: those across settings (a unit id not an
//! axis', a mask of axes on the bus) pure, in [`admit`], for the gateway and for tools; those
//! of the moment (an APPLY only while the bus is idle) the gateway's own.
//!
//! Parsing is pure: it looks at the address and the values only, so a multi-register write can
//! be parsed for its check and again, register by register, as it is carried out, without
//! keeping 123 parsed registers on the F103's stack.

use core::num::NonZeroU16;

use super::config::{
    complement_of, home_of, AxisBase, InchStep, JogSpeed, Parity, PlcBaud, UnitId, WatchdogAction,
    WatchdogTime,
};
use super::map::{self, *};
use super::refused::Refused;
use super::registers::join;
use crate::axes::AxisSet;
use crate::engine::MAX_RETRIES;
use crate::line::Baud;
use crate::modbus::Bits;
use crate::pio::{Pattern, StartMode};
use crate::units::{Complement, Lead};
use crate::{Axis, HomeDirection, PositionNo, Rtim};

/// The supported DRG1 bits, as written: levels (SON, STP, EMG) and edges (ALRS, HOME, CSTR)
/// that the gateway tells apart from the word it held before.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Drg1(u16);

impl Drg1 {
    /// No bit set (the word at power-up).
    pub const NONE: Drg1 = Drg1(0);

    /// The word, if it sets only supported bits.
    pub fn new(word: u16) -> Option<Drg1> {
        (word & !DRG1_SUPPORTED == 0).then_some(Drg1(word))
    }

    /// The word.
    pub const fn bits(self) -> u16 {
        self.0
    }

    /// Whether `bit` (a `DRG1_*` constant) is set.
    pub const fn has(self, bit: u16) -> bool {
        self.0 & bit != 0
    }

    /// The word with `bit` set or cleared.
    pub const fn with(self, bit: u16, on: bool) -> Drg1 {
        Drg1(if on { self.0 | bit } else { self.0 & !bit })
    }

    /// SON: the servo is to be on.
    pub const fn son(self) -> bool {
        self.has(DRG1_SON)
    }

    /// STP or EMG: no motion.
    pub const fn paused(self) -> bool {
        self.has(DRG1_STP | DRG1_EMG)
    }
}

/// A direct numeric move (0x9900, 7 to 9 registers) in the PLC's units, as written: the
/// register layout and the ranges that do not depend on the axis are checked. Kept as its
/// registers (0x9900 reads them back), the fields read from them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DirectMove {
    /// PCMD(2) INP(2) VCMD(2) ACMD PPOW CTLF, zero past those written.
    registers: [u16; DIRECT_MAX as usize],
}

/// CTLF b3: an incremental move.
const CTLF_INC: u16 = 1 << 3;

impl DirectMove {
    fn parse(values: &[u16]) -> Result<DirectMove, Refused> {
        let len = u16::try_from(values.len()).unwrap_or(u16::MAX);
        if !(DIRECT_MIN..=DIRECT_MAX).contains(&len) {
            return Err(Refused::NoSuchAddress);
        }
        let mut registers = [0; DIRECT_MAX as usize];
        for (slot, &v) in registers.iter_mut().zip(values) {
            *slot = v;
        }
        let [_, _, inp_hi, inp_lo, vcmd_hi, vcmd_lo, _, ppow, ctlf] = registers;
        if ppow != 0 || ctlf & !CTLF_INC != 0 {
            return Err(Refused::OutOfRange);
        }
        let speed = join(vcmd_hi, vcmd_lo);
        if speed == 0 || i32::try_from(join(inp_hi, inp_lo)).is_err() {
            return Err(Refused::OutOfRange);
        }
        Ok(DirectMove { registers })
    }

    /// PCMD: the target from home, or the distance ([`relative`](Self::relative)), 0.01 mm.
    pub fn pcmd(&self) -> i32 {
        let [hi, lo, ..] = self.registers;
        join(hi, lo) as i32
    }

    /// INP: the positioning band, 0.01 mm (within i32: checked).
    pub fn band(&self) -> i32 {
        let [_, _, hi, lo, ..] = self.registers;
        i32::try_from(join(hi, lo)).unwrap_or(i32::MAX)
    }

    /// VCMD: the speed, 0.01 mm/s (not 0: checked).
    pub fn speed(&self) -> u32 {
        let [_, _, _, _, hi, lo, ..] = self.registers;
        join(hi, lo)
    }

    /// ACMD: the acceleration, 0.01 G.
    pub fn accel(&self) -> u16 {
        let [.., accel, _, _] = self.registers;
        accel
    }

    /// CTLF b3: an incremental move.
    pub fn relative(&self) -> bool {
        let [.., ctlf] = self.registers;
        ctlf & CTLF_INC != 0
    }

    /// The registers as written (0x9900 reads them back), zero past those written.
    pub fn registers(&self) -> [u16; DIRECT_MAX as usize] {
        self.registers
    }
}

/// A write to an axis unit (FC05/06/0F/10), parsed.
#[derive(Clone, Copy, Debug)]
pub enum AxisWrite<'a> {
    /// DRG1.
    Drg1(Drg1),
    /// POSR: the point CSTR moves to.
    Position(PositionNo),
    /// 0x9900: a direct move.
    Direct(DirectMove),
    /// A whole position-table row (15 or 16 registers at 0x1000 + 16 n).
    Row(PositionNo, &'a [u16]),
    /// Coils, every one of them an axis unit's.
    Coils(u16, Bits<'a>),
}

impl<'a> AxisWrite<'a> {
    /// The write of `values` at `address` (FC06/FC10).
    pub fn registers(address: u16, values: &'a [u16]) -> Result<AxisWrite<'a>, Refused> {
        Ok(match (address, values) {
            (DRG1, &[value]) => AxisWrite::Drg1(Drg1::new(value).ok_or(Refused::OutOfRange)?),
            (POSR, &[value]) => AxisWrite::Position(
                u8::try_from(value)
                    .ok()
                    .and_then(PositionNo::new)
                    .ok_or(Refused::OutOfRange)?,
            ),
            (DIRECT, _) => AxisWrite::Direct(DirectMove::parse(values)?),
            (DRG1..=POSR, _) | (PNOW..=CMCT, _) => return Err(Refused::OutOfRange),
            // A row is written whole, from its first register.
            (a, _) => match super::table::locate(a) {
                Some((row, 0)) if (15..=16).contains(&values.len()) => {
                    AxisWrite::Row(row_point(row)?, values)
                }
                _ => return Err(Refused::NoSuchAddress),
            },
        })
    }

    /// The write of coils from `address` (FC05/FC0F): 02 unless every one is an axis unit's.
    pub fn coils(address: u16, values: Bits<'a>) -> Result<AxisWrite<'a>, Refused> {
        coils_exist(address, values.len())?;
        Ok(AxisWrite::Coils(address, values))
    }
}

/// The coils of an axis unit.
const COILS: [u16; 5] = [COIL_SON, COIL_ALRS, COIL_STP, COIL_HOME, COIL_STOP];

/// 02 unless `count` coils from `address` are all coils of an axis unit.
pub(super) fn coils_exist(address: u16, count: usize) -> Result<(), Refused> {
    if (0..count).all(|i| nth(address, i).is_some_and(|a| COILS.contains(&a))) {
        Ok(())
    } else {
        Err(Refused::NoSuchAddress)
    }
}

/// The point of a position-table row.
pub(super) fn row_point(row: u16) -> Result<PositionNo, Refused> {
    u8::try_from(row)
        .ok()
        .and_then(PositionNo::new)
        .ok_or(Refused::NoSuchAddress)
}

/// The address of the `i`-th register or coil of a request starting at `address`, if there is
/// one.
pub(super) fn nth(address: u16, i: usize) -> Option<u16> {
    u16::try_from(i).ok().and_then(|i| address.checked_add(i))
}

/// One AXISCFG field of an axis (0x0100 + 8 n).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AxisSetting {
    /// On the bus (taken on APPLY or at the next start).
    Enabled(bool),
    /// The lead.
    Lead(Lead),
    /// The home end.
    Home(HomeDirection),
    /// Encoder pulses per revolution.
    Pulses(NonZeroU16),
    /// The stroke's high word (0.01 mm; at most 0x7FFF, so the stroke stays within i32).
    StrokeHigh(u16),
    /// The stroke's low word.
    StrokeLow(u16),
    /// How negative positions are encoded.
    Complement(Complement),
}

/// AXISCFG field offsets.
pub(super) mod axis_cfg {
    pub const ENABLED: u16 = 0;
    pub const LEAD: u16 = 1;
    pub const HOME: u16 = 2;
    pub const PULSES: u16 = 3;
    pub const STROKE_HI: u16 = 4;
    pub const STROKE_LO: u16 = 5;
    pub const COMPLEMENT: u16 = 6;
}

impl AxisSetting {
    fn parse(field: u16, value: u16) -> Option<AxisSetting> {
        Some(match field {
            axis_cfg::ENABLED if value <= 1 => AxisSetting::Enabled(value == 1),
            axis_cfg::LEAD => AxisSetting::Lead(Lead::from_hundredths(value)?),
            axis_cfg::HOME => AxisSetting::Home(home_of(value)?),
            axis_cfg::PULSES => AxisSetting::Pulses(NonZeroU16::new(value)?),
            axis_cfg::STROKE_HI if i32::try_from(join(value, 0)).is_ok() => {
                AxisSetting::StrokeHigh(value)
            }
            axis_cfg::STROKE_LO => AxisSetting::StrokeLow(value),
            axis_cfg::COMPLEMENT => AxisSetting::Complement(complement_of(value)?),
            _ => return None,
        })
    }
}

/// One gateway-unit register write (FC06, or one register of FC10), parsed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GatewayWrite {
    /// A trigger register written 0 (SAVE, APPLY, FACTORY, RESTART, SYNCSTART): nothing.
    Nothing,
    /// FAILSAFE = 0: the latch acknowledged.
    AckFailsafe,
    /// WATCHDOG: the PLC silence that stops the axes (0: off).
    Watchdog(WatchdogTime),
    /// WDACTION.
    WatchdogAction(WatchdogAction),
    /// BUSBAUD (taken on APPLY).
    BusBaud(Baud),
    /// BUSRTIM (taken on APPLY).
    BusRtim(Rtim),
    /// RETRIES (at once).
    Retries(u8),
    /// PLCBAUD (taken on APPLY).
    PlcBaud(PlcBaud),
    /// PLCPARITY (taken on APPLY).
    PlcParity(Parity),
    /// UNITID (taken on APPLY).
    UnitId(UnitId),
    /// APPLY = 1.
    Apply,
    /// SAVE = 1.
    Save,
    /// RESTART = 1.
    Restart,
    /// FACTORY = its key.
    FactoryReset,
    /// PIOAXIS (`None`: no axis).
    PioAxis(Option<Axis>),
    /// PIOPAT.
    PioPattern(Pattern),
    /// AXISBASE (taken on APPLY).
    AxisBase(AxisBase),
    /// A register of the network block (feature `tcp`).
    #[cfg(feature = "tcp")]
    Net(crate::net::NetSetting),
    /// PIOSTART.
    PioStart(StartMode),
    /// PIOJOG.
    PioJog(JogSpeed),
    /// PIOINCH.
    PioInch(InchStep),
    /// SYNCMASK.
    SyncMask(AxisSet),
    /// SYNCSTART = 1 (started after the write's other registers, with its mask).
    SyncStart,
    /// A register of the command channel's request block: its offset in the block and its
    /// value (the block is taken whole, once the write's registers are in it).
    ChannelRequest(u16, u16),
    /// An AXISCFG field.
    Axis(Axis, AxisSetting),
}

impl GatewayWrite {
    /// `value` at `address` of the gateway unit: 02 for an address that does not exist, 03 for
    /// a read-only register or a value out of its range.
    pub fn parse(address: u16, value: u16) -> Result<GatewayWrite, Refused> {
        if !map::gateway_writable(address).ok_or(Refused::NoSuchAddress)? {
            return Err(Refused::OutOfRange);
        }
        let trigger = |write: GatewayWrite| match value {
            0 => Some(GatewayWrite::Nothing),
            1 => Some(write),
            _ => None,
        };
        let write = match address {
            G_FAILSAFE => (value == 0).then_some(GatewayWrite::AckFailsafe),
            G_WATCHDOG => WatchdogTime::from_millis(value).map(GatewayWrite::Watchdog),
            G_WD_ACTION => WatchdogAction::from_code(value).map(GatewayWrite::WatchdogAction),
            G_BUS_BAUD => {
                Baud::from_bits_per_second(u32::from(value) * 100).map(GatewayWrite::BusBaud)
            }
            G_BUS_RTIM => u8::try_from(value)
                .ok()
                .and_then(Rtim::new)
                .map(GatewayWrite::BusRtim),
            G_RETRIES => u8::try_from(value)
                .ok()
                .filter(|&r| r <= MAX_RETRIES)
                .map(GatewayWrite::Retries),
            G_PLC_BAUD => PlcBaud::from_register(value).map(GatewayWrite::PlcBaud),
            G_PLC_PARITY => Parity::from_code(value).map(GatewayWrite::PlcParity),
            G_UNIT_ID => UnitId::of(value).map(GatewayWrite::UnitId),
            G_AXIS_BASE => AxisBase::of(value).map(GatewayWrite::AxisBase),
            G_APPLY => trigger(GatewayWrite::Apply),
            G_SAVE => trigger(GatewayWrite::Save),
            G_RESTART => trigger(GatewayWrite::Restart),
            G_SYNC_START => trigger(GatewayWrite::SyncStart),
            G_FACTORY => match value {
                0 => Some(GatewayWrite::Nothing),
                FACTORY_KEY => Some(GatewayWrite::FactoryReset),
                _ => None,
            },
            G_PIO_AXIS => match value {
                0xFFFF => Some(GatewayWrite::PioAxis(None)),
                _ => u8::try_from(value)
                    .ok()
                    .and_then(Axis::new)
                    .map(|axis| GatewayWrite::PioAxis(Some(axis))),
            },
            G_PIO_PATTERN => Pattern::from_code(value).map(GatewayWrite::PioPattern),
            G_PIO_START => StartMode::from_code(value).map(GatewayWrite::PioStart),
            G_PIO_JOG => JogSpeed::from_hundredths(value).map(GatewayWrite::PioJog),
            G_PIO_INCH => InchStep::from_hundredths(value).map(GatewayWrite::PioInch),
            G_SYNC_MASK => Some(GatewayWrite::SyncMask(AxisSet(value))),
            a if a.checked_sub(G_REQUEST).is_some_and(|i| i < G_REQUEST_LEN) => {
                if !CHANNEL {
                    // A build without the command channel (the F103's): not there.
                    return Err(Refused::NoSuchAddress);
                }
                Some(GatewayWrite::ChannelRequest(a - G_REQUEST, value))
            }
            #[cfg(feature = "tcp")]
            a if a.checked_sub(G_NET).is_some_and(|i| i < G_NET_LEN) => {
                crate::net::NetSetting::parse(a - G_NET, value).map(GatewayWrite::Net)
            }
            a => per_axis(a, G_AXIS_CONFIG, G_AXIS_CONFIG_LEN).and_then(|(axis, field)| {
                AxisSetting::parse(field, value).map(|s| GatewayWrite::Axis(axis, s))
            }),
        };
        write.ok_or(Refused::OutOfRange)
    }
}

/// The settings a gateway-unit write is admitted against ([`admit`]): the ones pending (as the
/// registers read them, taken on APPLY) and the axes on the bus now.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Pending {
    /// UNITID as written (the gateway's unit from the next APPLY or start).
    pub unit: UnitId,
    /// AXISBASE as written.
    pub axis_base: AxisBase,
    /// The axes enabled in AXISCFG (on the bus from the next APPLY or start).
    pub enabled: AxisSet,
    /// The axes on the bus now.
    pub bus: AxisSet,
}

/// Why [`admit`] refuses a write (exception 03 on the wire).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Conflict {
    /// This axis (on the bus, or enabled) would have the gateway's own unit id.
    AxisUnit(Axis),
    /// SYNCMASK names an axis that is not on the bus.
    NotOnBus,
}

/// The rules across registers of a parsed gateway-unit write, on the settings as they are
/// before it: a UNITID that is no axis' unit and an AXISBASE that gives no axis the gateway's
/// unit (axes on the bus or enabled), an axis enabled whose unit is not the gateway's, a
/// synchronized-start mask of axes on the bus. Pure, and the one copy of these rules: the
/// gateway admits each register of a write with it, and a tool can plan a sequence of writes
/// with it (`rcgw`). Writes these rules do not concern are admitted.
pub fn admit(pending: &Pending, write: GatewayWrite) -> Result<(), Conflict> {
    let axes = AxisSet(pending.bus.0 | pending.enabled.0);
    let clash = |unit: UnitId, base: AxisBase| match base.axis_of(unit.get(), axes) {
        Some(axis) => Err(Conflict::AxisUnit(axis)),
        None => Ok(()),
    };
    match write {
        GatewayWrite::UnitId(unit) => clash(unit, pending.axis_base),
        GatewayWrite::AxisBase(base) => clash(pending.unit, base),
        GatewayWrite::Axis(axis, AxisSetting::Enabled(true))
            if axis.get().checked_add(pending.axis_base.get()) == Some(pending.unit.get()) =>
        {
            Err(Conflict::AxisUnit(axis))
        }
        GatewayWrite::SyncMask(mask) if mask.0 & !pending.bus.0 != 0 => Err(Conflict::NotOnBus),
        _ => Ok(()),
    }
}

/// The axis and field offset of an address in a per-axis block of `len` registers at `base`.
pub(super) fn per_axis(address: u16, base: u16, len: u16) -> Option<(Axis, u16)> {
    let offset = address.checked_sub(base)?;
    let axis = Axis::new(u8::try_from(offset / len).ok()?)?;
    Some((axis, offset % len))
}
