//! What the gateway is set up with.

use crate::axes::{AxisMap, AxisSet};
use crate::engine::Config;
use crate::modbus::Identity;
use crate::net::NetConfig;
use crate::pio::{Pattern, Ports, StartMode};
use crate::time::Duration;
use crate::units::{Complement, Lead, Length, Scale, Speed};
use crate::{Axis, HomeDirection};

/// Who the gateway is unless the firmware says otherwise (it names its board in `model_name`).
pub const IDENTITY: Identity = Identity {
    vendor_name: "rc-gateway project",
    product_code: "RC-GW",
    revision: env!("CARGO_PKG_VERSION"),
    vendor_url: "",
    product_name: "Robo Cylinder Modbus gateway",
    model_name: "host",
};

/// The gateway's own Modbus unit id by default: 63, as IAI's RGW-SIO gateway mode uses.
pub const DEFAULT_GATEWAY_UNIT: u8 = 63;

/// PLC watchdog by default: 1 s. A PLC polls every 10-100 ms, so 1 s of silence is not a slow
/// scan but a cut cable or a stopped PLC; 1 s of travel is also as far as a runaway axis should
/// get. Set 0 to turn it off (then nothing stops the axes when the PLC goes away).
pub const DEFAULT_WATCHDOG_MS: u16 = 1000;

/// What the PLC watchdog does when it trips.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WatchdogAction {
    /// Stop every axis (the default).
    #[default]
    StopAll = 0,
    /// Only latch the event in FAILSAFE (for machines where another system stops the axes).
    LatchOnly = 1,
}

impl WatchdogAction {
    /// The action of a WDACTION value or stored code (its discriminant), if it is one.
    pub(crate) fn from_code(code: u16) -> Option<WatchdogAction> {
        match code {
            0 => Some(WatchdogAction::StopAll),
            1 => Some(WatchdogAction::LatchOnly),
            _ => None,
        }
    }
}

/// One axis as the PLC side needs it: units and travel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisConfig {
    /// Lead, pulses/rev, home end, complement: converts the PLC's 0.01 mm to pulses.
    pub scale: Scale,
    /// Usable travel from home, 0.01 mm: direct moves outside 0..=stroke are refused.
    pub stroke: Length,
}

impl AxisConfig {
    /// 6 mm lead, motor-end homing, 800 pulses/rev, 100 mm stroke, exact negation
    /// ([`Complement::Twos`]): a controller reports 0 pulses at home, which the brief edition's
    /// one's-complement rule would show the PLC as -0.01 mm; exact negation shows 0.00 mm.
    /// (The two differ by one pulse; AXISCFG selects either per axis.)
    pub const DEFAULT: AxisConfig = AxisConfig {
        scale: Scale {
            lead: Lead::of(crate::units::ActuatorType::SS, crate::units::SpeedType::M),
            pulses_per_rev: crate::units::DEFAULT_PULSES_PER_REV,
            home: HomeDirection::MotorEnd,
            complement: Complement::Twos,
        },
        stroke: Length(10_000), // 100 mm
    };
}

impl Default for AxisConfig {
    fn default() -> AxisConfig {
        AxisConfig::DEFAULT
    }
}

// What the gateway unit's registers and the stored record (`settings`) both accept: one rule
// for each, so that what the PLC can write is what a start reads back.

/// A home end's code (AXISCFG, the stored record): the `o` command's, 7 motor end, 8 the other.
pub(crate) fn home_of(code: u16) -> Option<HomeDirection> {
    u8::try_from(code)
        .ok()
        .and_then(|code| HomeDirection::from_code(code).ok())
}

/// A complement's code (AXISCFG, the stored record): 1 one's, 2 two's.
pub(crate) const fn complement_code(complement: Complement) -> u8 {
    match complement {
        Complement::Ones => 1,
        Complement::Twos => 2,
    }
}

/// The complement of a code of [`complement_code`], if it is one.
pub(crate) fn complement_of(code: u16) -> Option<Complement> {
    match code {
        1 => Some(Complement::Ones),
        2 => Some(Complement::Twos),
        _ => None,
    }
}

/// A stroke's value (AXISCFG's two words, the stored record), 0.01 mm: 0 to i32::MAX (0 is
/// one the PLC can set; a stroke above i32::MAX makes no sense).
pub(crate) fn stroke_of(raw: u32) -> Option<Length> {
    i32::try_from(raw).ok().map(Length)
}

/// The gateway's own Modbus unit id (UNITID): 1 to 247, Serial Line §2.2's slave addresses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct UnitId(u8);

impl UnitId {
    /// [`DEFAULT_GATEWAY_UNIT`].
    pub const DEFAULT: UnitId = UnitId(DEFAULT_GATEWAY_UNIT);

    /// The unit id `unit`, if it is a slave address.
    pub const fn new(unit: u8) -> Option<UnitId> {
        if unit >= 1 && unit <= 247 {
            Some(UnitId(unit))
        } else {
            None
        }
    }

    /// The unit id of a UNITID value or a stored byte, if it is one.
    pub(crate) fn of(value: u16) -> Option<UnitId> {
        u8::try_from(value).ok().and_then(UnitId::new)
    }

    /// The id.
    pub const fn get(self) -> u8 {
        self.0
    }
}

impl core::fmt::Display for UnitId {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        self.0.fmt(f)
    }
}

impl Default for UnitId {
    fn default() -> UnitId {
        UnitId::DEFAULT
    }
}

/// The unit id of axis 0 unless set: axis n is unit n + 1, as IAI's SIO-through mode.
pub const DEFAULT_AXIS_BASE: u8 = 1;
/// The highest AXISBASE: axis 15 is then unit 247, the last slave address (Serial Line §2.2).
pub const MAX_AXIS_BASE: u8 = 247 - 15;

/// The unit id of axis 0 (AXISBASE): axis n is unit `base + n`, so that several gateways on
/// one PLC line each take their own range. 1 to [`MAX_AXIS_BASE`]: every axis' unit a slave
/// address, 1 to 247.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisBase(u8);

impl AxisBase {
    /// [`DEFAULT_AXIS_BASE`].
    pub const DEFAULT: AxisBase = AxisBase(DEFAULT_AXIS_BASE);

    /// The base `base`, if it is one.
    pub const fn new(base: u8) -> Option<AxisBase> {
        if base >= 1 && base <= MAX_AXIS_BASE {
            Some(AxisBase(base))
        } else {
            None
        }
    }

    /// The base of an AXISBASE value or a stored byte, if it is one.
    pub(crate) fn of(value: u16) -> Option<AxisBase> {
        u8::try_from(value).ok().and_then(AxisBase::new)
    }

    /// The unit id of axis 0.
    pub const fn get(self) -> u8 {
        self.0
    }

    /// The axis of `axes` whose unit is `unit` (a unit id as addressed), if any: the gateway's
    /// own unit must not be one.
    pub fn axis_of(self, unit: u8, axes: AxisSet) -> Option<Axis> {
        unit.checked_sub(self.0)
            .and_then(Axis::new)
            .filter(|&a| axes.contains(a))
    }
}

impl core::fmt::Display for AxisBase {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        self.0.fmt(f)
    }
}

impl Default for AxisBase {
    fn default() -> AxisBase {
        AxisBase::DEFAULT
    }
}

/// A PLC watchdog time (WATCHDOG, the stored record): 0 (off) or 50-60000 ms.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WatchdogTime(u16);

impl WatchdogTime {
    /// No watchdog: nothing stops the axes when the PLC goes silent.
    pub const OFF: WatchdogTime = WatchdogTime(0);
    /// The factory time, [`DEFAULT_WATCHDOG_MS`].
    pub const DEFAULT: WatchdogTime = WatchdogTime(DEFAULT_WATCHDOG_MS);

    /// The time of `ms`, if it is one.
    pub const fn from_millis(ms: u16) -> Option<WatchdogTime> {
        if ms == 0 || (ms >= 50 && ms <= 60_000) {
            Some(WatchdogTime(ms))
        } else {
            None
        }
    }

    /// The time, ms (0: off).
    pub const fn millis(self) -> u16 {
        self.0
    }

    /// The time (zero: off).
    pub const fn duration(self) -> Duration {
        Duration::from_millis(self.0 as u64)
    }
}

/// Parity of the PLC line (8 data bits; one stop bit with parity, as Modbus RTU frames
/// characters of 11 bits, Serial Line §2.5.1; the line's timing uses 11 bits either way).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Parity {
    /// No parity.
    #[default]
    None = 0,
    /// Even parity (the Modbus default).
    Even = 2,
    /// Odd parity.
    Odd = 1,
}

impl Parity {
    /// The parity of a PLCPARITY value or stored code (its discriminant: 0 none, 1 odd,
    /// 2 even), if it is one.
    pub(crate) fn from_code(code: u16) -> Option<Parity> {
        match code {
            0 => Some(Parity::None),
            1 => Some(Parity::Odd),
            2 => Some(Parity::Even),
            _ => None,
        }
    }
}

/// PLC line rates the gateway accepts, bit/s.
pub const PLC_BAUDS: [u32; 8] = [1_200, 2_400, 4_800, 9_600, 19_200, 38_400, 57_600, 115_200];

/// A PLC line rate, one of [`PLC_BAUDS`] (PLCBAUD holds it in 100 bit/s, the stored record in
/// bit/s).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
// In 100 bit/s, as PLCBAUD: two bytes, so that a parsed write ([`GatewayWrite`](super::write::GatewayWrite))
// stays small enough to be returned in registers.
pub struct PlcBaud(u16);

impl PlcBaud {
    /// 115.2 kbit/s.
    pub const B115200: PlcBaud = PlcBaud(1152);

    /// The rate of `bits_per_second`, if the gateway accepts it.
    pub fn new(bits_per_second: u32) -> Option<PlcBaud> {
        PLC_BAUDS
            .contains(&bits_per_second)
            .then_some(PlcBaud((bits_per_second / 100) as u16))
    }

    /// The rate of a PLCBAUD value (100 bit/s), if it is one.
    pub(crate) fn from_register(hundreds: u16) -> Option<PlcBaud> {
        PLC_BAUDS
            .contains(&(u32::from(hundreds) * 100))
            .then_some(PlcBaud(hundreds))
    }

    /// Bits per second.
    pub const fn bits_per_second(self) -> u32 {
        self.0 as u32 * 100
    }

    /// The PLCBAUD value: 100 bit/s.
    pub(crate) const fn register(self) -> u16 {
        self.0
    }
}

/// The PLC line's settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PlcLine {
    /// The line rate (sets the Modbus t1.5/t3.5 timers).
    pub baud: PlcBaud,
    /// Parity.
    pub parity: Parity,
}

impl PlcLine {
    /// 115.2 kbit/s, no parity.
    pub const DEFAULT: PlcLine = PlcLine {
        baud: PlcBaud::B115200,
        parity: Parity::None,
    };
}

/// Pattern 1's jog speed unless set: 100 mm/s (0.01 mm/s), PCON's factory value.
pub const DEFAULT_PIO_JOG: u16 = 10_000;
/// Pattern 1's inching step unless set: 0.10 mm (0.01 mm), PCON's factory value.
pub const DEFAULT_PIO_INCH: u16 = 10;
/// Pattern 1's acceleration, of its jogs and of a point a PWRT fills that held nothing: 0.30 G
/// (0.01 G), PCON's default acceleration (its parameter No. 9, factory value).
pub const PIO_ACCEL: u16 = 30;
/// The longest inching step: 1.00 mm (0.01 mm), PCON's range.
pub const MAX_PIO_INCH: u16 = 100;

/// Pattern 1's jog speed (PIOJOG; PCON parameter No. 26): 0.01 to 655.35 mm/s.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct JogSpeed(u16);

impl JogSpeed {
    /// [`DEFAULT_PIO_JOG`].
    pub const DEFAULT: JogSpeed = JogSpeed(DEFAULT_PIO_JOG);

    /// The speed of `hundredths` (0.01 mm/s), if it is one (not 0).
    pub const fn from_hundredths(hundredths: u16) -> Option<JogSpeed> {
        if hundredths != 0 {
            Some(JogSpeed(hundredths))
        } else {
            None
        }
    }

    /// The speed, 0.01 mm/s (PIOJOG's value).
    pub const fn hundredths(self) -> u16 {
        self.0
    }

    /// The speed.
    pub const fn speed(self) -> Speed {
        Speed(self.0 as u32)
    }
}

/// Pattern 1's inching step (PIOINCH; PCON parameter No. 48): 0.01 to 1.00 mm.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InchStep(u16);

impl InchStep {
    /// [`DEFAULT_PIO_INCH`].
    pub const DEFAULT: InchStep = InchStep(DEFAULT_PIO_INCH);

    /// The step of `hundredths` (0.01 mm), if it is one: 1 to [`MAX_PIO_INCH`].
    pub const fn from_hundredths(hundredths: u16) -> Option<InchStep> {
        if hundredths != 0 && hundredths <= MAX_PIO_INCH {
            Some(InchStep(hundredths))
        } else {
            None
        }
    }

    /// The step, 0.01 mm (PIOINCH's value).
    pub const fn hundredths(self) -> u16 {
        self.0
    }

    /// The step.
    pub const fn length(self) -> Length {
        Length(self.0 as i32)
    }
}

/// What the PLC sets and SAVE stores, but for the bus' part (its rate, RTIM, resends and axes
/// are the engine's, in [`GatewayConfig::bus`]): [`GatewayConfig::settings`]. Kept together so
/// that the stored record ([`Settings`](super::settings::Settings): these and the bus' part) is
/// taken from a configuration and put back in one copy, not field by field.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GatewaySettings {
    /// The gateway's own Modbus unit id.
    pub unit: UnitId,
    /// The unit id of axis 0: axis n is unit `axis_base + n` (several gateways on one PLC
    /// line each take their own range).
    pub axis_base: AxisBase,
    /// The PLC line.
    pub plc: PlcLine,
    /// Per-axis units and travel.
    pub axes: AxisMap<AxisConfig>,
    /// PLC silence that trips the fail-safe ([`WatchdogTime::OFF`]: none).
    pub watchdog: WatchdogTime,
    /// What the watchdog does.
    pub watchdog_action: WatchdogAction,
    /// The axis the discrete I/O (PIO) drives, if any.
    pub pio_axis: Option<Axis>,
    /// The PIO's pattern (IAI's number: which port carries which signal).
    pub pio_pattern: Pattern,
    /// How the solenoid patterns' ST inputs start a move (PCON parameter No. 27).
    pub pio_start: StartMode,
    /// Pattern 1's jog speed (PIOJOG).
    pub pio_jog: JogSpeed,
    /// Pattern 1's inching step (PIOINCH).
    pub pio_inch: InchStep,
    /// The Ethernet board's address and the Modbus TCP server's policy (stored on every
    /// board; used where there is Ethernet).
    pub net: NetConfig,
}

impl GatewaySettings {
    /// [`GatewaySettings::new`].
    pub const DEFAULT: GatewaySettings = GatewaySettings::new();

    /// The defaults: unit 63, axis 0 at unit 1, the PLC line at 115.2 kbit/s without parity,
    /// every axis as [`AxisConfig::DEFAULT`], the watchdog at 1 s stopping every axis, no PIO
    /// axis (pattern 0, level start), the jog's factory values, the network's defaults.
    // A function, not only the constant: where it runs (the firmware's start), it writes the
    // fields in place, where the constant would be a 240-byte copy of itself in flash.
    pub const fn new() -> GatewaySettings {
        GatewaySettings {
            unit: UnitId::DEFAULT,
            axis_base: AxisBase::DEFAULT,
            plc: PlcLine::DEFAULT,
            axes: AxisMap::new(AxisConfig::DEFAULT),
            watchdog: WatchdogTime::DEFAULT,
            watchdog_action: WatchdogAction::StopAll,
            pio_axis: None,
            pio_pattern: Pattern::Positioning,
            pio_start: StartMode::Level,
            pio_jog: JogSpeed::DEFAULT,
            pio_inch: InchStep::DEFAULT,
            net: NetConfig::DEFAULT,
        }
    }
}

impl Default for GatewaySettings {
    fn default() -> GatewaySettings {
        GatewaySettings::DEFAULT
    }
}

/// Everything the gateway is set up with: what the PLC can set (and SAVE) and what the board
/// decides. Not what the firmware learns at a start, which [`Node::new`](crate::node::Node::new)
/// takes apart: who the gateway is ([`Identity`]) and how it started ([`Boot`](super::Boot)).
///
/// Start from [`GatewayConfig::new`] (or [`GatewayConfig::DEFAULT`]) and set fields: more may
/// come.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub struct GatewayConfig {
    /// What the PLC sets and SAVE stores, but for the bus' part (in `bus`).
    pub settings: GatewaySettings,
    /// The silence that ends a Modbus frame on the PLC line when it must be longer than t3.5 of
    /// `settings.plc.baud` (Modbus over Serial Line §2.5.1.1); `None` on a wire. Only where
    /// bytes do not arrive at the wire's pace: the emulator's PLC line is a socket, whose bytes
    /// the task can read in bursts further apart than t3.5, which would split a request in two.
    pub plc_frame_gap: Option<Duration>,
    /// The bus master's configuration; its `axes` are the axes the PLC can address. Its rate,
    /// RTIM, resends and axes are stored settings too.
    pub bus: Config,
    /// The PIO ports the board has: a pattern needing others is refused.
    pub pio_ports: Ports,
}

impl GatewayConfig {
    /// The defaults, with no axis on the bus: [`GatewaySettings::new`]'s, the bus as
    /// [`Config::DEFAULT`], every PIO port.
    pub const DEFAULT: GatewayConfig = GatewayConfig::new(AxisSet::EMPTY);

    /// A gateway for `axes` with defaults everywhere else.
    pub const fn new(axes: AxisSet) -> GatewayConfig {
        GatewayConfig {
            settings: GatewaySettings::new(),
            plc_frame_gap: None,
            bus: Config {
                axes,
                ..Config::DEFAULT
            },
            pio_ports: Ports::ALL,
        }
    }

    /// The axis addressed by a Modbus unit id, if the PLC may address it.
    pub fn axis_of_unit(&self, unit: u8) -> Option<Axis> {
        self.settings.axis_base.axis_of(unit, self.bus.axes)
    }
}

impl Default for GatewayConfig {
    fn default() -> GatewayConfig {
        GatewayConfig::DEFAULT
    }
}
