//! IAI's position table at 0x1000 + 16 x n, in the PLC's units, from and to a Robo Cylinder
//! point-table row.
//!
//! PCON row layout (16 registers): PCMD (2, 0.01 mm), INP (2, 0.01 mm), VCMD (2, 0.01 mm/s),
//! ZNMP (2), ZNLP (2), ACMD (0.01 G), DCMD (0.01 G), PPOW (%), LPOW (%), CTLF, reserved.
//! A Robo Cylinder row has a position, band, velocity and one acceleration (used for both
//! acceleration and deceleration), so DCMD reads as ACMD; it has no per-point zones, load
//! threshold or control flags, so those read 0 and must be written 0. Push points (PPOW) are
//! not exposed here (the command channel writes any field; it converts and checks a field with
//! a unit as this table does: `field_to_plc`, `field_from_plc`).

use core::num::NonZeroU16;

use super::config::{complement_of, home_of, stroke_of, AxisConfig};
use super::refused::Refused;
use super::registers::{join, split};
use crate::engine::point_jobs::{PointData, PointReadback};
use crate::memory::PointField;
use crate::units::{Accel, Lead, Length, Scale, Speed};
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

/// A point field as the PLC reads it: the position from home and the band in 0.01 mm, the
/// velocity in 0.01 mm/s, the acceleration in 0.01 G (a velocity or acceleration the controller
/// could not hold reads 0); a field without a unit as stored.
pub(crate) fn field_to_plc(field: PointField, stored: u32, config: &AxisConfig) -> u32 {
    let scale = config.scale;
    match field {
        PointField::Position => scale.position_from_wire(Pulses::from_wire(stored)).0 as u32,
        PointField::Band => scale.length(i64::from(stored)).0.max(0) as u32,
        PointField::Velocity => u16::try_from(stored)
            .ok()
            .and_then(Velocity::new)
            .map_or(0, |v| scale.speed(v).0),
        PointField::Acceleration => u16::try_from(stored)
            .ok()
            .and_then(Acceleration::new)
            .map_or(0, |a| scale.accel(a).0),
        _ => stored,
    }
}

/// A point field written by the PLC in its units ([`field_to_plc`]), checked as the table's
/// registers are: the value to store. A field without a unit is stored as written.
pub(crate) fn field_from_plc(
    field: PointField,
    value: u32,
    config: &AxisConfig,
) -> Result<u32, Refused> {
    let scale = &config.scale;
    Ok(match field {
        PointField::Position => position(value, config)?.to_wire(),
        PointField::Band => band(value, scale)?,
        PointField::Velocity => velocity(value, scale)?.get().into(),
        PointField::Acceleration => acceleration(value, scale)?.get().into(),
        _ => value,
    })
}

/// PCMD: a position from home within 0..=stroke.
fn position(pcmd: u32, config: &AxisConfig) -> Result<Pulses, Refused> {
    let pcmd = pcmd as i32;
    if pcmd < 0 || pcmd > config.stroke.0 {
        return Err(Refused::OutOfRange);
    }
    Ok(config.scale.position_to_wire(Length(pcmd))?)
}

/// INP: a band width (within i32, not negative).
fn band(inp: u32, scale: &Scale) -> Result<u32, Refused> {
    let inp = i32::try_from(inp).map_err(|_| Refused::OutOfRange)?;
    Ok(scale.band_to_wire(Length(inp))?)
}

/// VCMD: a speed, not 0.
fn velocity(vcmd: u32, scale: &Scale) -> Result<Velocity, Refused> {
    if vcmd == 0 {
        return Err(Refused::OutOfRange);
    }
    Ok(scale.velocity(Speed(vcmd))?)
}

/// ACMD: an acceleration the controller can hold (not 0 once converted).
fn acceleration(acmd: u32, scale: &Scale) -> Result<Acceleration, Refused> {
    Ok(scale.acceleration(Accel(acmd))?)
}

/// The 16 registers of a row read back from the controller.
pub(crate) fn registers(readback: &PointReadback, config: &AxisConfig) -> [u16; 16] {
    let get = |field| field_to_plc(field, readback.get(field), config);
    let acmd = u16::try_from(get(PointField::Acceleration)).unwrap_or(u16::MAX);
    let [p0, p1] = split(get(PointField::Position));
    let [i0, i1] = split(get(PointField::Band));
    let [v0, v1] = split(get(PointField::Velocity));
    [p0, p1, i0, i1, v0, v1, 0, 0, 0, 0, acmd, acmd, 0, 0, 0, 0]
}

/// A whole row written by the PLC, checked, as the point to store.
pub(crate) fn point(values: &[u16], config: &AxisConfig) -> Result<PointData, Refused> {
    let reg = |i: usize| values.get(i).copied().unwrap_or(0);
    let (acmd, dcmd) = (reg(10), reg(11));
    // Zones, push, load threshold, control flags, reserved: not in a Robo Cylinder row.
    let unsupported = [6, 7, 8, 9, 12, 13, 14, 15].iter().any(|&i| reg(i) != 0);
    if unsupported || (dcmd != 0 && dcmd != acmd) {
        return Err(Refused::OutOfRange);
    }
    let scale = &config.scale;
    Ok(PointData {
        position: position(join(reg(0), reg(1)), config)?,
        velocity: velocity(join(reg(4), reg(5)), scale)?,
        acceleration: acceleration(u32::from(acmd), scale)?,
        flags: PointData::FLAGS_MOTION_AND_BAND,
        band: band(join(reg(2), reg(3)), scale)?,
        max_acceleration: 0,
    })
}

/// An axis' configuration from its AXISCFG block (unit 63, 0x0100 + 8 n: enabled, lead,
/// home, pulses/rev, stroke high, stroke low, complement), if every field is one the gateway
/// takes.
pub fn axis_config(axis_cfg: &[u16]) -> Option<AxisConfig> {
    let reg = |i: usize| axis_cfg.get(i).copied();
    let stroke = stroke_of(join(reg(4)?, reg(5)?))?;
    Some(AxisConfig {
        scale: Scale {
            lead: Lead::from_hundredths(reg(1)?)?,
            pulses_per_rev: NonZeroU16::new(reg(3)?)?,
            home: home_of(reg(2)?)?,
            complement: complement_of(reg(6)?)?,
        },
        stroke,
    })
}

/// Whether the position table takes `row` (a whole row, 16 registers, in the PLC's units) for
/// an axis configured as `config`: the check a PLC's write of the row gets (position within
/// 0..=stroke, a speed and an acceleration the controller can hold, a band within range, the
/// fields a Robo Cylinder row does not have 0), without writing anything.
pub fn check_row(row: &[u16], config: &AxisConfig) -> Result<(), Refused> {
    if row.len() != usize::from(ROW_LEN) {
        return Err(Refused::OutOfRange);
    }
    point(row, config).map(|_| ())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(position: u32, speed: u32, accel: u16) -> [u16; 16] {
        let [p0, p1] = split(position);
        let [v0, v1] = split(speed);
        [p0, p1, 0, 10, v0, v1, 0, 0, 0, 0, accel, accel, 0, 0, 0, 0]
    }

    #[test]
    fn check_row_takes_what_the_table_takes() {
        // The defaults: 6 mm lead, 800 pulses/rev, motor end, 100 mm stroke, two's complement.
        let config = axis_config(&[1, 600, 7, 800, 0, 10_000, 2]);
        assert_eq!(config, Some(AxisConfig::DEFAULT));
        let config = AxisConfig::DEFAULT;
        assert_eq!(check_row(&row(3350, 12_000, 30), &config), Ok(()));
        assert_eq!(check_row(&row(10_000, 100, 30), &config), Ok(()));
        // Beyond the stroke, negative, a speed or acceleration the controller cannot hold.
        assert!(check_row(&row(10_001, 100, 30), &config).is_err());
        assert!(check_row(&row((-1i32) as u32, 100, 30), &config).is_err());
        assert!(check_row(&row(0, 0, 30), &config).is_err());
        assert!(check_row(&row(0, 9_999_900, 30), &config).is_err());
        assert!(check_row(&row(0, 100, 0), &config).is_err());
        assert!(check_row(&row(0, 100, 500), &config).is_err());
        // Not a whole row.
        assert!(check_row(&[0; 8], &config).is_err());
        // A configuration the gateway would refuse: lead 0, home 3.
        assert_eq!(axis_config(&[1, 0, 7, 800, 0, 10_000, 2]), None);
        assert_eq!(axis_config(&[1, 600, 3, 800, 0, 10_000, 2]), None);
    }
}
