//! The per-axis status registers, computed from the engine's picture of the axis.
//! Bit positions follow IAI's PCON Modbus layout; see [`map`](super::map).

use super::config::AxisConfig;
use crate::engine::{AxisState, LinkError};
use crate::StatusReport;

/// DOPM/DIPM bit positions (PCON pattern 0 ports).
mod port {
    pub const PM_MASK: u16 = 0x000F;
    pub const MOVE: u16 = 1 << 6;
    pub const ZONE1: u16 = 1 << 7;
    pub const HEND: u16 = 1 << 10;
    pub const PEND: u16 = 1 << 11;
    pub const SV: u16 = 1 << 12;
    pub const ALM_N: u16 = 1 << 14;
    pub const HOLD: u16 = 1 << 12;
    pub const CSTR: u16 = 1 << 13;
}

// DSS1 / DSSE bit positions (PCON), public as the map's (`map::DSS1_SV`, ...).

/// DSS1 bit (PCON): PWR, the controller is powered (its status says so).
pub const DSS1_PWR: u16 = 1 << 13;
/// DSS1 bit (PCON): SV, the servo is on.
pub const DSS1_SV: u16 = 1 << 12;
/// DSS1 bit (PCON): ALMH, the axis is in alarm (ALMC holds the code).
pub const DSS1_ALMH: u16 = 1 << 10;
/// DSS1 bit (PCON): ALML, the controller rejected the last command.
pub const DSS1_ALML: u16 = 1 << 9;
/// DSS1 bit (PCON): STP, paused (STP or EMG held, or the controller's HOLD input).
pub const DSS1_STP: u16 = 1 << 5;
/// DSS1 bit (PCON): HEND, homing complete (the axis is homed).
pub const DSS1_HEND: u16 = 1 << 4;
/// DSS1 bit (PCON): PEND, positioning complete (in position, no command starting).
pub const DSS1_PEND: u16 = 1 << 3;
/// DSSE bit (PCON): MOVE, the axis moves.
pub const DSSE_MOVE: u16 = 1 << 5;
/// DSSE bit (PCON): GHMS, a homing command runs and the axis is not homed yet.
pub const DSSE_GHMS: u16 = 1 << 11;

/// The bits by their short names, for [`status_block`].
mod dss {
    pub use super::{
        DSS1_ALMH as ALMH, DSS1_ALML as ALML, DSS1_HEND as HEND, DSS1_PEND as PEND,
        DSS1_PWR as PWR, DSS1_STP as STP, DSS1_SV as SV, DSSE_GHMS as GHMS, DSSE_MOVE as MOVE,
    };
}

fn bit(set: bool, mask: u16) -> u16 {
    if set {
        mask
    } else {
        0
    }
}

/// The registers 0x9000..=0x9007, or `None` while the axis has not reported its status yet
/// (the gateway then answers exception 04 rather than invent values). While `starting` (a
/// motion command is taken and not finished), PEND and PM are off whatever the last status
/// said, as on a PCON, which drops PEND when it accepts a start. GHMS shows `homing`: the
/// gateway's homing command runs and the axis is not homed yet (the RC's status has no homing
/// bit, and "servo on, not in position" is also the motor initialisation after servo-on).
pub(crate) fn status_block(
    state: &AxisState,
    config: &AxisConfig,
    paused: bool,
    starting: bool,
    homing: bool,
) -> Option<[u16; 8]> {
    let report: StatusReport = state.report?;
    let position = state
        .position
        .map(|p| config.scale.position_from_wire(p).0)?;
    let (status, outputs, inputs) = (report.status, report.outputs, report.inputs);
    let moving = state.moving();
    let alarm = outputs.alarm_active();
    let almc = if alarm { u16::from(report.alarm.0) } else { 0 };
    let dipm =
        u16::from(inputs.pc()) | bit(inputs.hold(), port::HOLD) | bit(inputs.start(), port::CSTR);
    let pend = outputs.pfin() && !starting;
    let pm = if starting && !alarm {
        0
    } else {
        u16::from(outputs.pm())
    };
    let dopm = pm & port::PM_MASK
        | bit(moving, port::MOVE)
        | bit(outputs.zone(), port::ZONE1)
        | bit(outputs.zfin(), port::HEND)
        | bit(pend, port::PEND)
        | bit(status.servo(), port::SV)
        | bit(outputs.alm_n(), port::ALM_N);
    let rejected = matches!(state.last_error, Some(LinkError::Rejected(_)));
    let dss1 = bit(status.power(), dss::PWR)
        | bit(status.servo(), dss::SV)
        | bit(alarm, dss::ALMH)
        | bit(rejected, dss::ALML)
        | bit(paused || inputs.hold(), dss::STP)
        | bit(outputs.zfin(), dss::HEND)
        | bit(pend, dss::PEND);
    let dsse = bit(moving, dss::MOVE) | bit(homing && !outputs.zfin(), dss::GHMS);
    let [hi, lo] = split(position as u32);
    Some([hi, lo, almc, dipm, dopm, dss1, 0, dsse])
}

/// A 32-bit value as two registers, high word first (IAI's order).
pub(crate) fn split(value: u32) -> [u16; 2] {
    [(value >> 16) as u16, (value & 0xFFFF) as u16]
}

/// Two registers, high word first, as a 32-bit value.
pub(crate) fn join(hi: u16, lo: u16) -> u32 {
    u32::from(hi) << 16 | u32::from(lo)
}
