//! The controller's three memory areas (complete edition §7).
//!
//! - **Non-volatile** (§7-1): the common parameters (0x000-0x01F, §7-2-1) and 16 point-table rows
//!   (0x400-0x409 each, §7-2-2). V5 writes it from the edit area and counts its writes per data
//!   area (§4-4-7: "Total # times written is incremented for each V5 command execution").
//! - **Edit** (§7-1): one copy of the common parameters and one point row. Q1 loads it from
//!   non-volatile memory, W4 writes it at the T4 address (which then increments, §4-4-3), R4 reads
//!   it.
//! - **Execution** (§7-3-2 figure): what the drive runs with, mirrored at +0x7800. Q2/Q3 forward
//!   the edit row here with the FLGP rules; `a`, `m`, `v`, `d` write PCMD/VCMD/ACMD directly.
//!   The default axis-operation parameters INP..MXAC (0x00D-0x013) "do not exist in the common
//!   parameters in the execution data area" (§7-2-1), nor FLGP in its position data (§7-3-2
//!   figure), so those execution addresses are illegal.
//!
//! Other readable addresses: PNOW 0x7400, VNOW 0x7401 (§7-2-5), ROM 0x6800 (§7-2-4).
//! Anything else is an illegal memory address: warning 0x61 (§8-1-5).

use protocol::memory::{common, flgp, PointField, EXECUTION_OFFSET, PNOW, ROM_VERSION, VNOW};
use protocol::{Acceleration, Address, Velocity};

/// Words of common parameters (0x000-0x01F).
pub const COMMON_LEN: usize = 0x20;
/// Words of a point-table row (0x400-0x409).
pub const POINT_LEN: usize = 0x0A;
/// Rows in the point table.
pub const POINTS: usize = 16;
/// First address of the point row in the edit area.
pub const POINT_BASE: u32 = 0x400;

/// Index of a common parameter in [`CommonParams`].
pub const fn ci(address: Address) -> usize {
    address.0 as usize
}

/// Index of a field in a [`PointRow`].
pub const fn pi(field: PointField) -> usize {
    (field.address().0 - POINT_BASE) as usize
}

/// The 32 words of common parameters.
pub type CommonParams = [u32; COMMON_LEN];
/// The 10 words of a point-table row.
pub type PointRow = [u32; POINT_LEN];

/// Where an address lands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cell {
    /// Edit area, common parameter at this index.
    EditCommon(usize),
    /// Edit area, point row word at this index.
    EditPoint(usize),
    /// Execution area (0x7800 + index), common parameter.
    ExecCommon(usize),
    /// Execution area (0x7C00 + index), position data.
    ExecPoint(usize),
    /// PNOW (0x7400), read only.
    Pnow,
    /// VNOW (0x7401), read only.
    Vnow,
    /// ROM version (0x6800), read only.
    Rom,
}

/// Whether a common-parameter index exists in the execution area (§7-2-1: INP..MXAC do not).
fn exec_common_exists(index: usize) -> bool {
    !(ci(common::INP)..=ci(common::MXAC)).contains(&index)
}

/// The cell of an address, or `None` for an illegal address (warning 0x61).
pub fn locate(address: Address) -> Option<Cell> {
    let a = address.0;
    let point = |base: u32| {
        let offset = a.checked_sub(base)?;
        let field = PointField::from_address(Address(POINT_BASE + offset))?;
        Some(pi(field))
    };
    match a {
        0x000..=0x01F => Some(Cell::EditCommon(a as usize)),
        0x400..=0x409 => point(POINT_BASE).map(Cell::EditPoint),
        _ if a == PNOW.0 => Some(Cell::Pnow),
        _ if a == VNOW.0 => Some(Cell::Vnow),
        _ if a == ROM_VERSION.0 => Some(Cell::Rom),
        _ if (EXECUTION_OFFSET..EXECUTION_OFFSET + COMMON_LEN as u32).contains(&a) => {
            let index = (a - EXECUTION_OFFSET) as usize;
            exec_common_exists(index).then_some(Cell::ExecCommon(index))
        }
        _ => point(POINT_BASE + EXECUTION_OFFSET)
            .filter(|&index| index != pi(PointField::Flags))
            .map(Cell::ExecPoint),
    }
}

/// The physical actuator and its factory settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Actuator {
    /// Stroke between the mechanical ends, pulses (default 10_000: 100 mm with an 8 mm lead).
    pub stroke: u32,
    /// REG1 lead type (§7-2-1 table; default 5 = 8 mm).
    pub lead_type: u32,
}

impl Default for Actuator {
    fn default() -> Self {
        Actuator {
            stroke: 10_000,
            lead_type: 5,
        }
    }
}

/// Factory common parameters for an 8 mm lead (values per brief edition §4-3 5 formulas):
/// VCMD 100 mm/s = 0x0EA6, ACMD 0.3 G = 220, homing at 20 mm/s (OVCM 750) and 0.1 G (OACC 73),
/// INP 0.1 mm = 10 pulses, OTIM 10 x 16 ms, software limits and zone wide enough for either home
/// direction. BRSL 0 is no rate code: the line runs in the default state (9.6 kbit/s, 255 ms,
/// §7-2-1 note) until a BRSL is stored.
pub fn factory_common(actuator: &Actuator) -> CommonParams {
    let stroke = i32::try_from(actuator.stroke).unwrap_or(i32::MAX);
    let mut p = [0u32; COMMON_LEN];
    let set = |p: &mut CommonParams, address: Address, value: u32| p[ci(address)] = value;
    set(&mut p, common::LIMM, stroke as u32);
    set(&mut p, common::LIML, stroke.wrapping_neg() as u32);
    set(&mut p, common::ZONM, 0);
    set(&mut p, common::ZONL, (stroke / 2).wrapping_neg() as u32);
    set(&mut p, common::BRSL, 0);
    set(&mut p, common::OVCM, 750);
    set(&mut p, common::OACC, 73);
    set(&mut p, common::RTIM, 0xFF);
    set(&mut p, common::INP, 10);
    set(&mut p, common::VCMD, 0x0EA6);
    set(&mut p, common::ACMD, 220);
    set(&mut p, common::SPOW, 0x46);
    set(&mut p, common::DPOW, 0xFF);
    set(&mut p, common::PLG0, 6);
    set(&mut p, common::MXAC, 0);
    set(&mut p, common::PSWT, 0xFF);
    set(&mut p, common::REG1, actuator.lead_type);
    set(&mut p, common::ODPW, 0x80);
    set(&mut p, common::OTIM, 10);
    p
}

/// A point row built from the default axis-operation parameters of `common` (INP..MXAC), with
/// PCMD and FLGP 0: the execution row at power-up (§7-3-1).
pub fn default_row(common: &CommonParams) -> PointRow {
    let mut row = [0u32; POINT_LEN];
    row[pi(PointField::Band)] = common[ci(common::INP)];
    row[pi(PointField::Velocity)] = common[ci(common::VCMD)];
    row[pi(PointField::Acceleration)] = common[ci(common::ACMD)];
    row[pi(PointField::PushCurrent)] = common[ci(common::SPOW)];
    row[pi(PointField::MovingCurrent)] = common[ci(common::DPOW)];
    row[pi(PointField::ServoGain)] = common[ci(common::PLG0)];
    row[pi(PointField::MaxAcceleration)] = common[ci(common::MXAC)];
    row
}

/// The execution row Q2/Q3 make from an edit row (§7-3-2): PCMD always from the row; each
/// FLGP bit chooses the row's value (1) or the edit area's common default (0).
pub fn forward_row(row: &PointRow, common: &CommonParams) -> PointRow {
    let flags = row[pi(PointField::Flags)];
    let defaults = default_row(common);
    let pick = |bit: u32, field: PointField| {
        if flags & bit != 0 {
            row[pi(field)]
        } else {
            defaults[pi(field)]
        }
    };
    let mut out = defaults;
    out[pi(PointField::Position)] = row[pi(PointField::Position)];
    out[pi(PointField::Flags)] = 0;
    out[pi(PointField::Band)] = pick(flgp::BAND, PointField::Band);
    out[pi(PointField::Velocity)] = pick(flgp::MOTION, PointField::Velocity);
    out[pi(PointField::Acceleration)] = pick(flgp::MOTION, PointField::Acceleration);
    out[pi(PointField::MaxAcceleration)] = pick(flgp::MOTION, PointField::MaxAcceleration);
    out[pi(PointField::PushCurrent)] = pick(flgp::CURRENT, PointField::PushCurrent);
    out[pi(PointField::MovingCurrent)] = pick(flgp::CURRENT, PointField::MovingCurrent);
    out[pi(PointField::ServoGain)] = pick(flgp::SERVO_GAIN, PointField::ServoGain);
    out
}

/// Whether a position is in the PCMD range C0000000H-3FFFFFFFH (§7-2-2).
pub fn position_in_range(position: i64) -> bool {
    (-0x4000_0000..=0x3FFF_FFFF).contains(&position)
}

/// Check a value written to a point-row word (PCMD range, VCMD 0-57E4H, ACMD 1-7FFH, §7-2-2).
pub fn row_value_valid(index: usize, value: u32) -> bool {
    if index == pi(PointField::Position) {
        position_in_range(i64::from(value as i32))
    } else if index == pi(PointField::Velocity) {
        value <= 0x57E4
    } else if index == pi(PointField::Acceleration) {
        (1..=0x7FF).contains(&value)
    } else {
        true
    }
}

/// Non-volatile memory: common parameters and the point table, with V5 write counters.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct NonVolatile {
    /// Common parameters.
    pub common: CommonParams,
    /// The point table.
    pub points: [PointRow; POINTS],
    /// Whether a row holds data (stored by V5 or preloaded). Q3 to an empty row raises alarm B1
    /// ("may also occur if the user attempts to move to a point ... that has no data", §8-1-4).
    pub written: [bool; POINTS],
    /// V5 executions on the common-parameter area.
    pub common_writes: u32,
    /// V5 executions on each point row.
    pub point_writes: [u32; POINTS],
}

impl NonVolatile {
    /// Factory contents: default common parameters, an empty point table, no writes.
    pub fn factory(actuator: &Actuator) -> NonVolatile {
        NonVolatile {
            common: factory_common(actuator),
            points: [[0; POINT_LEN]; POINTS],
            written: [false; POINTS],
            common_writes: 0,
            point_writes: [0; POINTS],
        }
    }
}

/// The edit area and the T4/W4 write address.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EditArea {
    /// Common parameters.
    pub common: CommonParams,
    /// The point row.
    pub point: PointRow,
    /// Where the next W4 writes (set by T4).
    pub write_address: Option<u32>,
}

/// The execution data area (BRSL and RTIM are the controller's line state, not stored here).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ExecutionArea {
    /// Common parameters (0x7800..).
    pub common: CommonParams,
    /// Position data (0x7C00..).
    pub point: PointRow,
}

/// The three areas together.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Memory {
    /// Non-volatile memory.
    pub nv: NonVolatile,
    /// Edit area.
    pub edit: EditArea,
    /// Execution area.
    pub exec: ExecutionArea,
}

impl Memory {
    /// The areas at power-up (§7-3-1): non-volatile common parameters into the edit and
    /// execution areas; the edit row with PCMD and FLGP 0; the execution row from the defaults.
    pub fn power_up(nv: NonVolatile) -> Memory {
        let common = nv.common;
        let mut edit_point = default_row(&common);
        edit_point[pi(PointField::Position)] = 0;
        Memory {
            nv,
            edit: EditArea {
                common,
                point: edit_point,
                write_address: None,
            },
            exec: ExecutionArea {
                common,
                point: default_row(&common),
            },
        }
    }

    /// Q2 `00`: edit common parameters to the execution area, except the SIO parameters (only
    /// the communication-change command moves those, §7-3-2) and INP..MXAC (absent there).
    pub fn forward_common(&mut self) {
        for (index, (exec, edit)) in self
            .exec
            .common
            .iter_mut()
            .zip(self.edit.common.iter())
            .enumerate()
        {
            let sio = index == ci(common::BRSL) || index == ci(common::RTIM);
            if !sio && exec_common_exists(index) {
                *exec = *edit;
            }
        }
    }

    /// A value of the execution common parameters as a signed position.
    pub fn exec_position(&self, address: Address) -> i64 {
        i64::from(self.exec.common[ci(address)] as i32)
    }

    /// The execution row word of `field`.
    pub fn exec_field(&self, field: PointField) -> u32 {
        self.exec.point[pi(field)]
    }

    /// Set the execution row word of `field`.
    pub fn set_exec_field(&mut self, field: PointField, value: u32) {
        self.exec.point[pi(field)] = value;
    }

    /// The execution row's velocity and acceleration (VCMD, ACMD) as a `v` would give them, if
    /// they are in the command's range: the motion the axis moves at now.
    pub fn exec_motion(&self) -> Option<(Velocity, Acceleration)> {
        let units = |field| u16::try_from(self.exec_field(field)).ok();
        Some((
            Velocity::new(units(PointField::Velocity)?)?,
            Acceleration::new(units(PointField::Acceleration)?)?,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses() {
        assert_eq!(locate(Address(0x00C)), Some(Cell::EditCommon(0x0C)));
        assert_eq!(locate(Address(0x409)), Some(Cell::EditPoint(9)));
        assert_eq!(locate(Address(0x402)), None);
        assert_eq!(locate(Address(0x40A)), None);
        assert_eq!(locate(Address(0x780C)), Some(Cell::ExecCommon(0x0C)));
        assert_eq!(locate(Address(0x780E)), None);
        assert_eq!(locate(Address(0x7C00)), Some(Cell::ExecPoint(0)));
        assert_eq!(locate(Address(0x7C01)), None);
        assert_eq!(locate(Address(0x7400)), Some(Cell::Pnow));
        assert_eq!(locate(Address(0x6800)), Some(Cell::Rom));
        assert_eq!(locate(Address(0x1234)), None);
    }

    #[test]
    fn flgp_selects_row_or_defaults() {
        let common = factory_common(&Actuator::default());
        let mut row = [0u32; POINT_LEN];
        row[pi(PointField::Position)] = 123;
        row[pi(PointField::Velocity)] = 1000;
        row[pi(PointField::Band)] = 3;
        row[pi(PointField::Flags)] = flgp::MOTION;
        let out = forward_row(&row, &common);
        assert_eq!(out[pi(PointField::Position)], 123);
        assert_eq!(out[pi(PointField::Velocity)], 1000);
        assert_eq!(out[pi(PointField::Band)], common[ci(common::INP)]);
    }
}
