//! The Modbus register map, as data: every address the gateway answers, with its unit, range,
//! access and meaning, and for a setting its allowed values as data, its default and whether
//! it is taken on APPLY. The register table in docs/plc.md is generated from [`MAP`], so the
//! document and the code cannot drift apart; `rcgw` takes from it which settings wait for
//! APPLY; tests hold the write parser (`write`) and a new gateway's settings to each
//! setting's values and default.
//!
//! Each axis is its own Modbus unit, id = axis + 1 (as IAI's SIO-through mode does), laid out
//! like IAI's PCON Modbus registers where the RC protocol can supply them. The gateway itself
//! is one more unit ([`GatewaySettings::unit`](super::GatewaySettings::unit), 63 by default, like
//! IAI's RGW-SIO) for its configuration, diagnostics, synchronized start and command channel.

/// Which unit an entry belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Unit {
    /// Every axis unit (id = axis + 1).
    Axis,
    /// The gateway unit.
    Gateway,
}

/// Which Modbus table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Table {
    /// Coils: FC01 read, FC05/FC0F write.
    Coil,
    /// Registers readable with FC03 and FC04 (read-only).
    Status,
    /// Holding registers: FC03 read, FC06/FC10 write.
    Holding,
}

/// How completely the gateway supplies an IAI register.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Support {
    /// As on a PCON.
    Full,
    /// Supplied in part; the text says how.
    Partial(&'static str),
    /// The gateway's own register (no PCON equivalent).
    Gateway,
}

/// One entry of the map.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Entry {
    /// Unit.
    pub unit: Unit,
    /// Table.
    pub table: Table,
    /// First address.
    pub address: u16,
    /// Number of registers or coils.
    pub count: u16,
    /// Name (IAI's where it has one).
    pub name: &'static str,
    /// Unit of measure.
    pub units: &'static str,
    /// Allowed values, in words (for a setting with [`allowed`](Self::allowed) values, "": its
    /// spans say it).
    pub range: &'static str,
    /// A setting's allowed register values as inclusive spans (`(96, 96)` one value,
    /// `(3, 255)` a range); empty where [`range`](Self::range) says it in words.
    pub allowed: &'static [(u16, u16)],
    /// A setting's value unless set (factory default).
    pub default: Option<u16>,
    /// A setting taken on APPLY (or at the next start), not at once.
    pub on_apply: bool,
    /// Whether it can be written.
    pub writable: bool,
    /// What it means.
    pub meaning: &'static str,
    /// How completely it is supplied.
    pub support: Support,
}

// ---------------------------------------------------------------- axis units

/// PNOW: present position, int32 in 0.01 mm, high word first.
pub const PNOW: u16 = 0x9000;
/// ALMC: the alarm code while the axis is in alarm, else 0.
pub const ALMC: u16 = 0x9002;
/// DIPM: the controller's PIO inputs, in PCON pattern-0 bit positions.
pub const DIPM: u16 = 0x9003;
/// DOPM: the controller's PIO outputs, in PCON pattern-0 bit positions.
pub const DOPM: u16 = 0x9004;
/// DSS1: device status 1.
pub const DSS1: u16 = 0x9005;
/// DSS2: device status 2 (no RC equivalent: always 0).
pub const DSS2: u16 = 0x9006;
/// DSSE: expanded device status.
pub const DSSE: u16 = 0x9007;

// The status bits, defined beside the code that sets them (`registers`), public here.
pub use super::registers::{
    DSS1_ALMH, DSS1_ALML, DSS1_HEND, DSS1_PEND, DSS1_PWR, DSS1_STP, DSS1_SV, DSSE_GHMS, DSSE_MOVE,
};
/// Gateway extension: command status of the last command (0 idle, 1 taken, 2 done, 3 failed).
pub const CMST: u16 = 0x9F00;
/// Gateway extension: why the last command failed ([`super::Reason`]).
pub const CMER: u16 = 0x9F01;
/// Gateway extension: link to the axis (0 unknown, 1 online, 2 offline).
pub const LINK: u16 = 0x9F02;
/// Gateway extension: commands taken so far (wrapping), to see that a new one was taken.
pub const CMCT: u16 = 0x9F03;
/// DRG1: device control register 1.
pub const DRG1: u16 = 0x0D00;
/// POSR: position number for CSTR.
pub const POSR: u16 = 0x0D03;
/// Direct numeric move: PCMD(2) INP(2) VCMD(2) ACMD PPOW CTLF; writing it starts the move.
pub const DIRECT: u16 = 0x9900;
/// Registers of a direct move: 7 (up to ACMD) to 9 (with PPOW and CTLF).
pub const DIRECT_MIN: u16 = 7;
/// See [`DIRECT_MIN`].
pub const DIRECT_MAX: u16 = 9;
/// Coil SON: servo on (level).
pub const COIL_SON: u16 = 0x0403;
/// Coil ALRS: alarm reset (rising edge).
pub const COIL_ALRS: u16 = 0x0407;
/// Coil STP: pause (level; the RC cannot resume, see docs/plc.md).
pub const COIL_STP: u16 = 0x040A;
/// Coil HOME: home (rising edge).
pub const COIL_HOME: u16 = 0x040B;
/// Coil STOP: decelerating stop (each write of ON; reads 0).
pub const COIL_STOP: u16 = 0x042C;

/// DRG1 bits (PCON): servo on.
pub const DRG1_SON: u16 = 1 << 12;
/// DRG1: alarm reset (rising edge).
pub const DRG1_ALRS: u16 = 1 << 8;
/// DRG1: pause (level).
pub const DRG1_STP: u16 = 1 << 5;
/// DRG1: home (rising edge).
pub const DRG1_HOME: u16 = 1 << 4;
/// DRG1: start: move to POSR (rising edge).
pub const DRG1_CSTR: u16 = 1 << 3;
/// DRG1: emergency stop (level): treated like STP.
pub const DRG1_EMG: u16 = 1 << 15;
/// Bits the gateway accepts in DRG1; others (SFTY, BKRL, ...) are refused with exception 03.
pub const DRG1_SUPPORTED: u16 = DRG1_SON | DRG1_ALRS | DRG1_STP | DRG1_HOME | DRG1_CSTR | DRG1_EMG;

// ---------------------------------------------------------------- gateway unit

/// Firmware version: major << 8 | minor.
pub const G_VERSION: u16 = 0x0000;
/// Uptime in seconds, u32 high word first.
pub const G_UPTIME: u16 = 0x0002;
/// Fail-safe latch: bit 0 PLC watchdog tripped, bit 1 stop input; write 0 to clear.
pub const G_FAILSAFE: u16 = 0x0004;
/// Fail-safe trips so far.
pub const G_FAILSAFE_COUNT: u16 = 0x0005;
/// PLC watchdog time in ms (0 = off).
pub const G_WATCHDOG: u16 = 0x0006;
/// Bus line rate in 100 bit/s (96, 144, 192, 288, 384, 576, 768, 1152); taken on APPLY.
pub const G_BUS_BAUD: u16 = 0x0007;
/// Controllers' minimum response delay RTIM in ms (3-255); taken on APPLY.
pub const G_BUS_RTIM: u16 = 0x0008;
/// Resends after a time-out (0-3); in force at once.
pub const G_RETRIES: u16 = 0x0009;
/// Write 1: run the communication establishment with BUSBAUD and BUSRTIM (every axis).
pub const G_APPLY: u16 = 0x000A;
/// Watchdog action: 0 stop every axis, 1 latch only.
pub const G_WD_ACTION: u16 = 0x000E;
/// The axis the discrete I/O drives (0-15; 0xFFFF none).
pub const G_PIO_AXIS: u16 = 0x000F;
/// PLC line rate in 100 bit/s (12 24 48 96 192 384 576 1152); taken on APPLY or at the next start.
pub const G_PLC_BAUD: u16 = 0x0010;
/// PLC line parity: 0 none, 1 odd, 2 even; taken on APPLY or at the next start.
pub const G_PLC_PARITY: u16 = 0x0011;
/// The gateway's own unit id (1-247, not an axis' unit); taken on APPLY or at the next start.
pub const G_UNIT_ID: u16 = 0x0012;
/// Write 1: store the settings in flash.
pub const G_SAVE: u16 = 0x0013;
/// The last save: 0 none, 1 saving, 2 saved, 3 failed.
pub const G_SAVE_STATUS: u16 = 0x0014;
/// Saves so far, u32.
pub const G_SAVE_COUNT: u16 = 0x0015;
/// Write 0xFAC7: erase the stored settings and restart with the defaults.
pub const G_FACTORY: u16 = 0x0017;
/// Where the running settings came from: 0 defaults, 1 flash, 2 defaults (stored ones unreadable).
pub const G_CONFIG_SOURCE: u16 = 0x0018;
/// Stored settings found unreadable at a start, so far.
pub const G_CONFIG_ERRORS: u16 = 0x0019;
/// Why the board last started: 0 power-on, 1 watchdog, 2 software, 3 reset pin, 4 other.
pub const G_RESET_CAUSE: u16 = 0x001A;
/// Write 1: restart the gateway (the saved settings take effect).
pub const G_RESTART: u16 = 0x001B;
/// PIOPAT: the PIO's pattern, IAI's number (0, 1, 4, 5).
pub const G_PIO_PATTERN: u16 = 0x001C;
/// PIOSTART: how the solenoid patterns' ST inputs start a move (0 level, 1 edge).
pub const G_PIO_START: u16 = 0x001D;
/// PIOJOG: pattern 1's jog speed, 0.01 mm/s.
pub const G_PIO_JOG: u16 = 0x001E;
/// PIOINCH: pattern 1's inching step, 0.01 mm.
pub const G_PIO_INCH: u16 = 0x001F;
/// AXISBASE: the unit id of axis 0 (axis n is unit AXISBASE + n); taken on APPLY.
pub const G_AXIS_BASE: u16 = 0x0020;
/// The network block (feature `tcp`): IPADDR, IPPREFIX, IPROUTER, TCPMAX, TCPIDLE, TCPCONN,
/// TCPALLOW; offsets in [`crate::net::registers`].
pub const G_NET: u16 = 0x0600;
/// Registers of the network block.
pub const G_NET_LEN: u16 = crate::net::registers::LEN;
/// TCPLINK: the Modbus TCP server's counters (6 x u32; feature `tcp`).
pub const G_TCP: u16 = 0x0610;
/// Registers of TCPLINK.
pub const G_TCP_LEN: u16 = 12;
/// The value G_FACTORY wants, so that no stray write erases the settings.
pub const FACTORY_KEY: u16 = 0xFAC7;

/// Synchronized start: axis mask (bit n = axis n).
pub const G_SYNC_MASK: u16 = 0x000B;
/// Synchronized start: write 1 to move every axis of the mask to its POSR together.
pub const G_SYNC_START: u16 = 0x000C;
/// Synchronized start status (0 idle, 1 running, 2 done, 3 failed).
pub const G_SYNC_STATUS: u16 = 0x000D;
/// Per-axis configuration: 8 registers per axis from here.
pub const G_AXIS_CONFIG: u16 = 0x0100;
/// Registers per axis in the configuration block.
pub const G_AXIS_CONFIG_LEN: u16 = 8;
/// Command channel request ([`G_REQUEST_LEN`] registers), ROBONET-style handshake.
pub const G_REQUEST: u16 = 0x0200;
/// Registers of the command channel's request block.
pub const G_REQUEST_LEN: u16 = 6;
/// Command channel response ([`G_RESPONSE_LEN`] registers).
pub const G_RESPONSE: u16 = 0x0210;
/// Registers of the command channel's response block.
pub const G_RESPONSE_LEN: u16 = 5;
/// Whether this build has the command channel (protocol feature `channel`; the F103's has
/// not, for flash): without it the request and response blocks do not exist (02).
pub const CHANNEL: bool = cfg!(feature = "channel");
/// Per-axis diagnostics: 16 registers per axis from here.
pub const G_DIAG: u16 = 0x0400;
/// Registers per axis in the diagnostics block.
pub const G_DIAG_LEN: u16 = 16;
/// Bus counters (6 x u32).
pub const G_BUS: u16 = 0x0500;
/// Registers of the bus counters.
pub const G_BUS_LEN: u16 = 12;
/// PLC-link (Modbus) counters (7 x u32).
pub const G_PLC: u16 = 0x0510;
/// Registers of the PLC-link counters.
pub const G_PLC_LEN: u16 = 14;

/// Firmware update (feature `update`, [`super::update`]): UPDCTL, BEGIN (with the image's size,
/// CRC-32 and board id), FINISH, ABORT.
pub const G_UPDATE: u16 = 0x0700;
/// Registers of UPDCTL: the command and BEGIN's arguments.
pub const G_UPDATE_LEN: u16 = 6;
/// Firmware update: BOOTSTAT, what the bootloader did at this start (confirmed, on trial,
/// rolled back) and the version of the image marked for the next start.
pub const G_BOOT_STATUS: u16 = 0x0708;
/// Registers of BOOTSTAT: the state and a u32 version.
pub const G_BOOT_STATUS_LEN: u16 = 3;
/// Firmware update: UPDSTAT, the transfer's state, progress and last error.
pub const G_UPDATE_STATUS: u16 = 0x0710;
/// Registers of UPDSTAT.
pub const G_UPDATE_STATUS_LEN: u16 = 16;
/// Firmware update: UPDCHUNK, one chunk of the image (header and up to 232 bytes).
pub const G_UPDATE_CHUNK: u16 = 0x0720;
/// Registers of UPDCHUNK: a 4-register header and 116 of data.
pub const G_UPDATE_CHUNK_LEN: u16 = 120;

use Support::{Full, Gateway, Partial};

/// Axes, for the per-axis blocks' sizes.
const AXES: u16 = crate::axes::AXES as u16;
use Table::{Coil, Holding, Status};
use Taken::{AtOnce, OnApply};

// One row of the table: positional like the document's columns, so the table reads as a table.
#[allow(clippy::too_many_arguments)]
const fn e(
    unit: Unit,
    table: Table,
    address: u16,
    count: u16,
    name: &'static str,
    units: &'static str,
    range: &'static str,
    writable: bool,
    meaning: &'static str,
    support: Support,
) -> Entry {
    Entry {
        unit,
        table,
        address,
        count,
        name,
        units,
        range,
        writable,
        meaning,
        support,
        allowed: &[],
        default: None,
        on_apply: false,
    }
}

/// When a setting takes effect: at once, or on APPLY (or at the next start).
#[derive(Clone, Copy)]
enum Taken {
    AtOnce,
    OnApply,
}

impl Entry {
    /// A setting's row: its allowed values as spans, its default, when it is taken.
    const fn setting(self, allowed: &'static [(u16, u16)], default: u16, taken: Taken) -> Entry {
        Entry {
            allowed,
            default: Some(default),
            on_apply: matches!(taken, Taken::OnApply),
            ..self
        }
    }

    /// Whether `value` is one of [`allowed`](Self::allowed)'s (false when there are none).
    pub fn allows(&self, value: u16) -> bool {
        self.allowed
            .iter()
            .any(|&(low, high)| (low..=high).contains(&value))
    }
}

/// How many entries of [`MAP`] are the gateway unit's, and how many of those are writable.
#[allow(clippy::indexing_slicing)]
const GATEWAY_ENTRIES: (usize, usize) = {
    let (mut n, mut writable) = (0, 0);
    let mut i = 0;
    while i < MAP.len() {
        if matches!(MAP[i].unit, Unit::Gateway) {
            n += 1;
            if MAP[i].writable {
                writable += 1;
            }
        }
        i += 1;
    }
    (n, writable)
};

/// The gateway unit's entries of [`MAP`] as (first address, count), the writable ones first,
/// computed at compile time (an index out of range here would be a build error, never a
/// run-time panic). All the gateway needs of the map at run time: the texts stay out of the
/// firmware, and so do the axis units' entries, whose addresses their own code checks.
#[allow(clippy::indexing_slicing)]
const ACCESS: [(u16, u16); GATEWAY_ENTRIES.0] = {
    let mut out = [(0, 0); GATEWAY_ENTRIES.0];
    let mut n = 0;
    let mut writable = true;
    loop {
        let mut i = 0;
        while i < MAP.len() {
            let e = &MAP[i];
            if matches!(e.unit, Unit::Gateway) && e.writable == writable {
                out[n] = (e.address, e.count);
                n += 1;
            }
            i += 1;
        }
        if !writable {
            break;
        }
        writable = false;
    }
    out
};

/// Whether `address` of the gateway unit can be written, if it is in the map at all.
pub fn gateway_writable(address: u16) -> Option<bool> {
    ACCESS
        .iter()
        .position(|&(first, count)| {
            address
                .checked_sub(first)
                .is_some_and(|offset| offset < count)
        })
        .map(|i| i < GATEWAY_ENTRIES.1)
}

/// Every address the gateway answers. Anything else is exception 02.
pub const MAP: &[Entry] = &[
    e(Unit::Axis, Status, PNOW, 2, "PNOW", "0.01 mm", "int32", false,
      "Present position from home (R4 PNOW: read when the axis comes online, every cycle or two while it moves, at the end of every move and of homing (before the command's status says done), then again until two reads agree: PFIN comes when the axis enters its position band, before it rests)", Partial("not continuous: exception 04 until the axis has answered")),
    e(Unit::Axis, Status, ALMC, 1, "ALMC", "code", "0x00-0xFF", false,
      "Alarm code (RC error 0x80-0xFF) while *ALM is off, else 0", Partial("RC codes, not PCON codes")),
    e(Unit::Axis, Status, DIPM, 1, "DIPM", "bits", "", false,
      "Controller inputs: b0-b3 PC1-PC8, b12 HOLD, b13 CSTR", Partial("the 6 inputs the RC reports")),
    e(Unit::Axis, Status, DOPM, 1, "DOPM", "bits", "", false,
      "Controller outputs: b0-b3 PM1-PM8, b6 MOVE, b7 ZONE1, b10 HEND, b11 PEND, b12 SV, b14 *ALM", Partial("no ZONE2/RMDS/EMGS/LOAD")),
    e(Unit::Axis, Status, DSS1, 1, "DSS1", "bits", "", false,
      "b13 PWR, b12 SV, b10 ALMH, b9 ALML (last command rejected), b5 STP, b4 HEND, b3 PEND", Partial("EMGS SFTY PSFL ABER BKRL CEND CLBS always 0")),
    e(Unit::Axis, Status, DSS2, 1, "DSS2", "bits", "0", false,
      "Always 0: the RC has no teaching, jog or load-cell functions", Partial("constant 0")),
    e(Unit::Axis, Status, DSSE, 1, "DSSE", "bits", "", false,
      "b5 MOVE, b11 GHMS (a homing command runs and the axis is not homed yet)", Partial("other bits 0")),
    e(Unit::Axis, Status, CMST, 1, "CMST", "", "0-3", false,
      "Last command: 0 idle, 1 taken, 2 done, 3 failed", Gateway),
    e(Unit::Axis, Status, CMER, 1, "CMER", "code", "", false,
      "Why the last command failed: high byte reason, low byte RC warning/alarm code", Gateway),
    e(Unit::Axis, Status, LINK, 1, "LINK", "", "0-3", false,
      "Link to the axis: 0 unknown, 1 online, 2 offline, 3 offline and owed a stop (its stop got no answer: the first frame it answers will be the stop)", Gateway),
    e(Unit::Axis, Status, CMCT, 1, "CMCT", "count", "", false,
      "Commands taken so far (wrapping)", Gateway),
    e(Unit::Axis, Holding, DRG1, 1, "DRG1", "bits", "", true,
      "b12 SON (level), b8 ALRS (edge), b5 STP (level: stop, no motion), b4 HOME (edge), b3 CSTR (edge: move to POSR), b15 EMG (level, as STP)", Partial("SFTY, BKRL and other bits refused (exception 03)")),
    e(Unit::Axis, Holding, POSR, 1, "POSR", "position", "0-15", true,
      "Position number CSTR moves to", Full),
    e(Unit::Axis, Holding, DIRECT, 9, "PCMD INP VCMD ACMD PPOW CTLF", "0.01 mm, 0.01 mm, 0.01 mm/s, 0.01 G, %, bits", "PCMD 0..stroke", true,
      "Direct numeric move, FC10 of 7 to 9 registers: writing it starts the move (CTLF b3 = incremental)", Partial("INP validated but the RC uses its execution-area band; PPOW and CTLF push bits refused (exception 03)")),
    e(Unit::Axis, Holding, super::table::BASE, super::table::ROW_LEN * super::table::ROWS, "POSITION TABLE", "0.01 mm, 0.01 mm/s, 0.01 G", "rows 0-15", true,
      "Row n at 0x1000+16n: PCMD(2) INP(2) VCMD(2) ZNMP(2) ZNLP(2) ACMD DCMD PPOW LPOW CTLF -; a whole row per write (FC10 of 15 or 16 registers), compared with the controller's row and only then stored, with read-back verify (the row reads 04 until stored)", Partial("a row not cached (the gateway keeps the 18 rows used last) answers 04 while it is fetched (about 70 ms); DCMD = ACMD; zones, PPOW, LPOW, CTLF read 0 and must be written 0")),
    e(Unit::Axis, Coil, COIL_SON, 1, "SON", "", "", true, "Servo on (level; same as DRG1 b12)", Full),
    e(Unit::Axis, Coil, COIL_ALRS, 1, "ALRS", "", "", true, "Alarm reset on the rising edge (servo turned off first, as the RC requires)", Full),
    e(Unit::Axis, Coil, COIL_STP, 1, "STP", "", "", true, "Pause: stop, and no motion while on; the move does not resume when released", Partial("RC has no resume")),
    e(Unit::Axis, Coil, COIL_HOME, 1, "HOME", "", "", true, "Home on the rising edge", Full),
    e(Unit::Axis, Coil, COIL_STOP, 1, "STOP", "", "", true, "Decelerating stop on each write of ON; reads 0", Full),
    e(Unit::Gateway, Status, G_VERSION, 2, "VERSION", "", "", false, "Firmware version: major<<8|minor, patch", Gateway),
    e(Unit::Gateway, Status, G_UPTIME, 2, "UPTIME", "s", "uint32", false, "Time since start", Gateway),
    e(Unit::Gateway, Holding, G_FAILSAFE, 1, "FAILSAFE", "bits", "write 0", true, "Latched fail-safe: b0 PLC watchdog, b1 stop input; write 0 to acknowledge (03 while the stop input is open)", Gateway),
    e(Unit::Gateway, Status, G_FAILSAFE_COUNT, 1, "FSCOUNT", "count", "", false, "Fail-safe trips", Gateway),
    e(Unit::Gateway, Holding, G_WATCHDOG, 1, "WATCHDOG", "ms", "", true, "PLC silence that stops every moving axis (0 = off)", Gateway)
        .setting(&[(0, 0), (50, 60_000)], 1000, AtOnce),
    e(Unit::Gateway, Holding, G_BUS_BAUD, 1, "BUSBAUD", "100 bit/s", "", true, "RS485 line rate, taken on APPLY or at the next start", Gateway)
        .setting(&[(96, 96), (144, 144), (192, 192), (288, 288), (384, 384), (576, 576), (768, 768), (1152, 1152)], 1152, OnApply),
    e(Unit::Gateway, Holding, G_BUS_RTIM, 1, "BUSRTIM", "ms", "", true, "Controllers' minimum response delay, taken on APPLY or at the next start", Gateway)
        .setting(&[(3, 255)], 3, OnApply),
    e(Unit::Gateway, Holding, G_RETRIES, 1, "RETRIES", "", "", true, "Resends after a time-out (complete edition §5 Nrt), in force at once", Gateway)
        .setting(&[(0, 3)], 2, AtOnce),
    e(Unit::Gateway, Holding, G_APPLY, 1, "APPLY", "", "1", true, "Write 1: the pending settings take effect: PLCBAUD/PLCPARITY/UNITID after the reply, then a break and communication establishment with BUSBAUD/BUSRTIM and the enabled axes (all axes stop answering for about 1 s per axis); refused (03) unless nothing moves, runs or waits", Gateway),
    e(Unit::Gateway, Holding, G_WD_ACTION, 1, "WDACTION", "", "", true, "Watchdog action: 0 stop every axis, 1 latch only", Gateway)
        .setting(&[(0, 1)], 0, AtOnce),
    e(Unit::Gateway, Holding, G_PIO_AXIS, 1, "PIOAXIS", "axis", "", true, "The axis the discrete I/O drives (0xFFFF: none)", Gateway)
        .setting(&[(0, 15), (0xFFFF, 0xFFFF)], 0xFFFF, AtOnce),
    e(Unit::Gateway, Holding, G_PIO_PATTERN, 1, "PIOPAT", "", "", true, "The discrete I/O's pattern, IAI's number: 0 positioning (PC1-PC8, CSTR), 1 teaching (0 plus MODE, JISL, JOG+, JOG-, PWRT; MODES, WEND), 4 solenoid valve 1 (ST0-ST6, PE0-PE6), 5 solenoid valve 2 (ST0-ST2, LS0-LS2); in force at once (every input must then go OFF and ON again); refused (03) if the board lacks one of its ports", Gateway)
        .setting(&[(0, 0), (1, 1), (4, 4), (5, 5)], 0, AtOnce),
    e(Unit::Gateway, Holding, G_PIO_START, 1, "PIOSTART", "", "", true, "Patterns 4 and 5: 0 level (releasing STn stops the move), 1 edge (STn's rising edge starts it); PCON parameter No. 27", Gateway)
        .setting(&[(0, 1)], 0, AtOnce),
    e(Unit::Gateway, Holding, G_PIO_JOG, 1, "PIOJOG", "0.01 mm/s", "", true, "Pattern 1: jog speed (JOG+/JOG- held; and the speed a PWRT gives a point that held nothing); PCON parameter No. 26, default 100 mm/s", Gateway)
        .setting(&[(1, 65_535)], 10_000, AtOnce),
    e(Unit::Gateway, Holding, G_PIO_INCH, 1, "PIOINCH", "0.01 mm", "", true, "Pattern 1: inching step (JISL ON, one per JOG edge); PCON parameter No. 48, default 0.10 mm", Gateway)
        .setting(&[(1, 100)], 10, AtOnce),
    e(Unit::Gateway, Holding, G_PLC_BAUD, 1, "PLCBAUD", "100 bit/s", "", true, "PLC line rate, taken on APPLY or at the next start", Gateway)
        .setting(&[(12, 12), (24, 24), (48, 48), (96, 96), (192, 192), (384, 384), (576, 576), (1152, 1152)], 1152, OnApply),
    e(Unit::Gateway, Holding, G_PLC_PARITY, 1, "PLCPARITY", "", "", true, "PLC line parity: 0 none, 1 odd, 2 even (8 data bits, 1 stop bit), taken on APPLY or at the next start", Gateway)
        .setting(&[(0, 2)], 0, OnApply),
    e(Unit::Gateway, Holding, G_UNIT_ID, 1, "UNITID", "unit", "", true, "The gateway's own unit id (not an enabled axis' unit), taken on APPLY or at the next start", Gateway)
        .setting(&[(1, 247)], 63, OnApply),
    e(Unit::Gateway, Holding, G_AXIS_BASE, 1, "AXISBASE", "unit", "", true, "The unit id of axis 0: axis n is unit AXISBASE + n (default 1; several gateways on one PLC line take ranges of their own); not to include UNITID; taken on APPLY or at the next start", Gateway)
        .setting(&[(1, 232)], 1, OnApply),
    e(Unit::Gateway, Holding, G_SAVE, 1, "SAVE", "", "1", true, "Write 1: store every setting (with the pending ones) in flash; SAVESTAT says when it is done", Gateway),
    e(Unit::Gateway, Status, G_SAVE_STATUS, 1, "SAVESTAT", "", "0-3", false, "The last save: 0 none, 1 saving, 2 saved, 3 failed", Gateway),
    e(Unit::Gateway, Status, G_SAVE_COUNT, 2, "SAVECOUNT", "count", "uint32", false, "Saves so far (flash wear: about 10,000 erases per page, spread over the settings pages)", Gateway),
    e(Unit::Gateway, Holding, G_FACTORY, 1, "FACTORY", "", "0xFAC7", true, "Write 0xFAC7: erase the stored settings and restart with the defaults", Gateway),
    e(Unit::Gateway, Status, G_CONFIG_SOURCE, 1, "CFGSOURCE", "", "0-2", false, "The running settings came from: 0 the defaults (nothing stored), 1 flash, 2 the defaults because the stored ones were unreadable", Gateway),
    e(Unit::Gateway, Status, G_CONFIG_ERRORS, 1, "CFGERRORS", "count", "", false, "Starts that found the stored settings unreadable", Gateway),
    e(Unit::Gateway, Status, G_RESET_CAUSE, 1, "RESETCAUSE", "", "0-4", false, "Why the board last started: 0 power-on, 1 hardware watchdog, 2 software (RESTART, factory reset, a fault), 3 reset pin, 4 other", Gateway),
    e(Unit::Gateway, Holding, G_RESTART, 1, "RESTART", "", "1", true, "Write 1: restart after the reply (the saved settings take effect)", Gateway),
    e(Unit::Gateway, Holding, G_SYNC_MASK, 1, "SYNCMASK", "bits", "", true, "Axes of the synchronized start (bit n = axis n)", Gateway),
    e(Unit::Gateway, Holding, G_SYNC_START, 1, "SYNCSTART", "", "1", true, "Write 1: every axis of SYNCMASK moves to its POSR at the same instant (h, then one t)", Gateway),
    e(Unit::Gateway, Status, G_SYNC_STATUS, 1, "SYNCSTAT", "", "0-3", false, "0 idle, 1 running, 2 done (every axis started; each axis' CMST follows its move to the end), 3 failed", Gateway),
    e(Unit::Gateway, Holding, G_AXIS_CONFIG, G_AXIS_CONFIG_LEN * AXES, "AXISCFG", "", "", true, "Per axis n at 0x0100+8n: enabled (taken on APPLY or at the next start), lead (0.01 mm), home (7 motor/8 far end), pulses/rev, stroke (2, 0.01 mm), complement (1/2)", Gateway),
    e(Unit::Gateway, Holding, G_REQUEST, G_REQUEST_LEN, "REQ", "0.01 mm, 0.01 mm/s, 0.01 G", "PCMD 0..stroke", true, "Command channel request (not on the F103: exception 02 there; its position-table rows hold the same data): code (1 read field, 2 write field, 3 read as the controller stores it), axis, point, field (offset from 0x400), value high, value low; a value out of range is refused (exception 03)", Gateway),
    e(Unit::Gateway, Status, G_RESPONSE, G_RESPONSE_LEN, "RESP", "", "", false, "Command channel response (not on the F103): code (|0x8000 on error), error (as CMER), value high, value low (as the controller now holds it), V5 write count (0xFFFF: value already stored, nothing written)", Gateway),
    e(Unit::Gateway, Status, G_DIAG, G_DIAG_LEN * AXES, "DIAG", "count", "", false, "Per axis n at 0x0400+16n: frames sent, replies, time-outs, BCC errors, bad replies, retries, rejections (u32 each), link, last error", Gateway),
    e(Unit::Gateway, Status, G_BUS, G_BUS_LEN, "BUS", "count", "", false, "Unsolicited frames, events lost, queue full, establishments, stops owed (a stop got no answer), broadcast refusals (u32 each)", Gateway),
    e(Unit::Gateway, Status, G_PLC, G_PLC_LEN, "PLCLINK", "count", "", false, "Modbus frames, CRC errors, exceptions, replies, other units, broadcasts, malformed (u32 each; RTU and TCP together)", Gateway),
    #[cfg(feature = "update")]
    e(Unit::Gateway, Holding, G_UPDATE, G_UPDATE_LEN, "UPDCTL", "", "1, 2, 3", true, "Firmware update (not on the F103): write 1 BEGIN with the image's size (u32, bytes), CRC-32 (u32) and board id in one FC10 of 6; 2 FINISH; 3 ABORT. Refused (04) while an axis moves or a SAVE is pending; 03 for another board or an image larger than the DFU partition", Gateway),
    #[cfg(feature = "update")]
    e(Unit::Gateway, Status, G_BOOT_STATUS, G_BOOT_STATUS_LEN, "BOOTSTAT", "", "", false, "Firmware update: what the bootloader did at this start (0 no bootloader, 1 confirmed, 2 a new image on trial, 3 a new image rolled back), the version of the signed image checked and marked for the next start (u32 major<<24|minor<<16|patch, 0 none)", Gateway),
    e(Unit::Gateway, Status, G_UPDATE_STATUS, G_UPDATE_STATUS_LEN, "UPDSTAT", "", "", false, "Firmware update: state (0 idle, 1 erasing, 2 receiving, 3 writing, 4 finishing, 5 ready, 6 failed), last error, bytes received, next offset, image size, image CRC-32, board id, DFU partition size, refusals (u32 each but the board id), largest chunk", Gateway),
    #[cfg(feature = "update")]
    e(Unit::Gateway, Holding, G_UPDATE_CHUNK, G_UPDATE_CHUNK_LEN, "UPDCHUNK", "bytes", "", true, "Firmware update: one chunk in one FC10: offset (u32, the next offset UPDSTAT shows), length (1-232, a multiple of 8 but for the last), CRC-16/MODBUS of its bytes, the bytes (two per register, high byte first)", Gateway),
    #[cfg(feature = "tcp")]
    e(Unit::Gateway, Holding, G_NET, 2, "IPADDR", "IPv4", "a.b, c.d", true, "Ethernet board: its address, high byte first (default 192.168.1.100); taken at the next start (SAVE, RESTART)", Gateway),
    #[cfg(feature = "tcp")]
    e(Unit::Gateway, Holding, G_NET + 2, 1, "IPPREFIX", "bits", "", true, "Ethernet board: subnet prefix length (default 24 = 255.255.255.0); taken at the next start", Gateway)
        .setting(&[(1, 32)], 24, AtOnce),
    #[cfg(feature = "tcp")]
    e(Unit::Gateway, Holding, G_NET + 3, 2, "IPROUTER", "IPv4", "a.b, c.d", true, "Ethernet board: default router, 0.0.0.0 none (the default); taken at the next start", Gateway),
    #[cfg(feature = "tcp")]
    e(Unit::Gateway, Holding, G_NET + 5, 1, "TCPMAX", "count", "", true, "Modbus TCP connections at once (default 4); a new client beyond it replaces the connection idle the longest; in force at once", Gateway)
        .setting(&[(1, 4)], 4, AtOnce),
    #[cfg(feature = "tcp")]
    e(Unit::Gateway, Holding, G_NET + 6, 1, "TCPIDLE", "s", "", true, "A Modbus TCP connection with no request for this long is closed (default 60; 0 never); in force at once", Gateway)
        .setting(&[(0, 3600)], 60, AtOnce),
    #[cfg(feature = "tcp")]
    e(Unit::Gateway, Status, G_NET + 7, 1, "TCPCONN", "count", "0-4", false, "Modbus TCP connections open now", Gateway),
    #[cfg(feature = "tcp")]
    e(Unit::Gateway, Holding, G_NET + 8, 8, "TCPALLOW", "IPv4", "4 x (a.b, c.d)", true, "The clients allowed to connect, 0.0.0.0 an empty slot; all empty: anyone (the default). Checked when a client connects; write each address in one FC10", Gateway),
    #[cfg(feature = "tcp")]
    e(Unit::Gateway, Status, G_TCP, G_TCP_LEN, "TCPLINK", "count", "", false, "Modbus TCP: connections accepted, refused (not allowed), replaced (limit), closed idle, MBAP errors, frames (u32 each)", Gateway),
];

#[cfg(test)]
mod tests {
    use super::*;
    use crate::axes::AxisSet;
    use crate::modbus::{DataModel, RegisterTable, SlaveCounters};
    use crate::plc::write::GatewayWrite;
    use crate::plc::{Gateway, GatewayConfig};
    use crate::time::Instant;

    fn settings() -> impl Iterator<Item = &'static Entry> {
        MAP.iter().filter(|e| e.default.is_some())
    }

    /// Every setting's default is one of its own allowed values, and its row says its range
    /// only as data.
    #[test]
    fn every_default_is_within_its_own_range() {
        assert!(settings().count() >= 14);
        for e in settings() {
            let default = e.default.unwrap();
            assert!(e.allows(default), "{}: default {default}", e.name);
            assert!(
                e.writable && e.range.is_empty() && e.count == 1,
                "{}",
                e.name
            );
        }
    }

    /// The defaults are what a gateway with nothing set reads.
    #[test]
    fn every_default_is_what_a_new_gateway_reads() {
        let mut gateway = Gateway::new(
            GatewayConfig::new(AxisSet(0)),
            &crate::plc::IDENTITY,
            crate::plc::Boot::DEFAULT,
        );
        let mut registers = gateway.registers(Instant::ZERO, SlaveCounters::default());
        for e in settings() {
            let mut out = [0];
            let unit = crate::plc::DEFAULT_GATEWAY_UNIT;
            registers
                .read_registers(unit, RegisterTable::Holding, e.address, &mut out)
                .unwrap();
            assert_eq!(Some(out[0]), e.default, "{}", e.name);
        }
    }

    /// The write parser takes exactly the values a setting's row allows (PIOPAT's pattern 1
    /// only in a build with it, feature `teaching`).
    #[test]
    fn the_parser_takes_exactly_the_allowed_values() {
        for e in settings() {
            for value in 0..=u16::MAX {
                let allowed = e.allows(value)
                    && !(e.address == G_PIO_PATTERN && value == 1 && !cfg!(feature = "teaching"));
                assert_eq!(
                    GatewayWrite::parse(e.address, value).is_ok(),
                    allowed,
                    "{} = {value}",
                    e.name
                );
            }
        }
    }

    /// The compact run-time table says of every address what the map itself says.
    #[test]
    fn gateway_writable_is_the_maps_word() {
        for address in 0..=u16::MAX {
            let entry = MAP.iter().find(|e| {
                e.unit == Unit::Gateway
                    && address
                        .checked_sub(e.address)
                        .is_some_and(|offset| offset < e.count)
            });
            assert_eq!(
                gateway_writable(address),
                entry.map(|e| e.writable),
                "{address:#06x}"
            );
        }
    }
}
