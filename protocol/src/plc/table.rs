//! IAI's position table at 0x1000 + 16 x n, in the PLC's units, from and to a Robo Cylinder
//! point-table row.
//!
//! PCON row layout (16 registers): PCMD (2, 0.01 mm), INP (2, 0.01 mm), VCMD (2, 0.01 mm/s),
//! ZNMP (2), ZNLP (2), ACMD (0.01 G), DCMD (0.01 G), PPOW (%), LPOW (%), CTLF, reserved.
//! A Robo Cylinder row has a position, band, velocity and one acceleration (used for both
//! acceleration and deceleration), so DCMD reads as ACMD; it has no per-point zones, load
//! threshold or control flags, so those read 0 and must be written 0. Push points (PPOW) are
//! not exposed here (the command channel writes any field).

use super::config::AxisConfig;
use super::refused::Refused;
use super::registers::{join, split};
use crate::jobs::{PointData, PointReadback};
use crate::memory::PointField;
use crate::units::{Accel, Length, Speed};
use crate::{Acceleration, Pulses, Velocity};

/// First register of the table.
pub const BASE: u16 = 0x1000;
/// Registers per row.
pub const ROW_LEN: u16 = 16;
/// Rows (the RC's 16 positions).
pub const ROWS: u16 = 16;

/// The row and register offset of a table address, if it is one.
pub(crate) fn locate(address: u16) -> Option<(u16, u16)> {
    let offset = address.checked_sub(BASE)?;
    let row = offset / ROW_LEN;
    (row < ROWS).then_some((row, offset % ROW_LEN))
}

/// The 16 registers of a row read back from the controller.
pub(crate) fn registers(readback: &PointReadback, config: &AxisConfig) -> [u16; 16] {
    let scale = config.scale;
    let pcmd = scale.position_from_wire(Pulses::from_wire(readback.get(PointField::Position)));
    let band = i64::from(readback.get(PointField::Band));
    let inp = scale.length(band).0;
    let vcmd = u16::try_from(readback.get(PointField::Velocity))
        .ok()
        .and_then(Velocity::new)
        .map_or(0, |v| scale.speed(v).0);
    let acmd = u16::try_from(readback.get(PointField::Acceleration))
        .ok()
        .and_then(Acceleration::new)
        .map_or(0, |a| scale.accel(a).0);
    let acmd = u16::try_from(acmd).unwrap_or(u16::MAX);
    let [p0, p1] = split(pcmd.0 as u32);
    let [i0, i1] = split(inp.max(0) as u32);
    let [v0, v1] = split(vcmd);
    [p0, p1, i0, i1, v0, v1, 0, 0, 0, 0, acmd, acmd, 0, 0, 0, 0]
}

/// A whole row written by the PLC, checked, as the point to store.
pub(crate) fn point(values: &[u16], config: &AxisConfig) -> Result<PointData, Refused> {
    let reg = |i: usize| values.get(i).copied().unwrap_or(0);
    let bad = Refused::OutOfRange;
    let pcmd = join(reg(0), reg(1)) as i32;
    if pcmd < 0 || pcmd > config.stroke.0 {
        return Err(bad);
    }
    let inp = i32::try_from(join(reg(2), reg(3))).map_err(|_| bad)?;
    let vcmd = join(reg(4), reg(5));
    let (acmd, dcmd) = (reg(10), reg(11));
    // Zones, push, load threshold, control flags, reserved: not in a Robo Cylinder row.
    let unsupported = [6, 7, 8, 9, 12, 13, 14, 15].iter().any(|&i| reg(i) != 0);
    if unsupported || vcmd == 0 || (dcmd != 0 && dcmd != acmd) {
        return Err(bad);
    }
    let scale = config.scale;
    Ok(PointData {
        position: scale.position_to_wire(Length(pcmd)).map_err(|_| bad)?,
        velocity: scale.velocity(Speed(vcmd)).map_err(|_| bad)?,
        acceleration: scale
            .acceleration(Accel(u32::from(acmd)))
            .map_err(|_| bad)?,
        flags: PointData::FLAGS_MOTION_AND_BAND,
        band: scale.band_to_wire(Length(inp)).map_err(|_| bad)?,
        max_acceleration: 0,
    })
}
