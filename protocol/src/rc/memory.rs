//! The controller's virtual memory (complete edition §7-2), read with R4 and written with T4/W4.
//!
//! Addresses in the edit area; the execution area mirrors common parameters at +0x7800 and the
//! position data at +0x7800 as well (0x400 -> 0x7C00, §7-3-2). Writing an undocumented address
//! "may cause unanticipated and potentially dangerous operations" (§4-4-3): only the constants
//! here are meant to be written.

use crate::types::Address;

/// Common parameters (§7-2-1), edit area.
pub mod common {
    use super::Address;
    /// LIMM: software stroke limit, + side (pulses).
    pub const LIMM: Address = Address(0x002);
    /// LIML: software stroke limit, - side (pulses).
    pub const LIML: Address = Address(0x003);
    /// ZONM: zone boundary, + side (pulses).
    pub const ZONM: Address = Address(0x004);
    /// ZONL: zone boundary, - side (pulses).
    pub const ZONL: Address = Address(0x005);
    /// BRSL: SIO baud-rate selection code (see [`Baud`](crate::line::Baud)).
    pub const BRSL: Address = Address(0x009);
    /// OVCM: home return velocity (0.2 rpm).
    pub const OVCM: Address = Address(0x00A);
    /// OACC: home return acceleration (0.1 rpm/ms).
    pub const OACC: Address = Address(0x00B);
    /// RTIM: minimum response delay (ms, 3-255).
    pub const RTIM: Address = Address(0x00C);
    /// INP: default position band (pulses).
    pub const INP: Address = Address(0x00D);
    /// VCMD: default velocity (0.2 rpm).
    pub const VCMD: Address = Address(0x00E);
    /// ACMD: default acceleration (0.1 rpm/ms).
    pub const ACMD: Address = Address(0x00F);
    /// SPOW: default current limit while stopped (0-0xB4 of 0xFF).
    pub const SPOW: Address = Address(0x010);
    /// DPOW: default current limit while moving (of 0xFF).
    pub const DPOW: Address = Address(0x011);
    /// PLG0: default servo gain number (0-15).
    pub const PLG0: Address = Address(0x012);
    /// MXAC: default maximum-acceleration flag.
    pub const MXAC: Address = Address(0x013);
    /// PSWT: push recognition time (ms, 0-255).
    pub const PSWT: Address = Address(0x015);
    /// REG1: lead type, bits 0-3 (see [`units::Lead::from_lead_type`](crate::units::Lead::from_lead_type)).
    pub const REG1: Address = Address(0x017);
    /// ODPW: current limit during homing.
    pub const ODPW: Address = Address(0x019);
    /// OTIM: homing time-out (16 ms units).
    pub const OTIM: Address = Address(0x01A);

    /// Every common parameter with its code in §7-2-1.
    pub const NAMED: [(Address, &str); 19] = [
        (LIMM, "LIMM"),
        (LIML, "LIML"),
        (ZONM, "ZONM"),
        (ZONL, "ZONL"),
        (BRSL, "BRSL"),
        (OVCM, "OVCM"),
        (OACC, "OACC"),
        (RTIM, "RTIM"),
        (INP, "INP"),
        (VCMD, "VCMD"),
        (ACMD, "ACMD"),
        (SPOW, "SPOW"),
        (DPOW, "DPOW"),
        (PLG0, "PLG0"),
        (MXAC, "MXAC"),
        (PSWT, "PSWT"),
        (REG1, "REG1"),
        (ODPW, "ODPW"),
        (OTIM, "OTIM"),
    ];
}

/// The point-table row in the edit area (§7-2-2; brief edition §4-3 4). Q1 loads a row here,
/// V5 stores it back to a position number.
///
/// The editions name two of the fields differently: brief 0x406 "push %" = complete SPOW
/// (current limit while stopped, which is the push current for a push move, §7-2-3), and brief
/// 0x407 "push recognition time" = complete DPOW (current limit while moving; the complete
/// edition keeps the push time in the common parameter PSWT). Both names are given; the field
/// is the same address either way.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PointField {
    /// 0x400 PCMD: target position (pulses, C0000000-3FFFFFFF).
    Position,
    /// 0x401 FLGP: which fields of the row override the common defaults (bits 4-7).
    Flags,
    /// 0x403 INP: position band (pulses), the push range for a push move.
    Band,
    /// 0x404 VCMD: velocity (0.2 rpm).
    Velocity,
    /// 0x405 ACMD: acceleration (0.1 rpm/ms).
    Acceleration,
    /// 0x406 SPOW (complete) / push % x lead (brief).
    PushCurrent,
    /// 0x407 DPOW (complete) / push recognition time in ms (brief).
    MovingCurrent,
    /// 0x408 PLG0: servo gain number (complete edition only).
    ServoGain,
    /// 0x409 MXAC: bit 0 max acceleration, bit 1 push move, bit 2 push reversed.
    MaxAcceleration,
}

impl PointField {
    /// Every documented field, in address order: what a read-back covers.
    pub const ALL: [PointField; 9] = [
        PointField::Position,
        PointField::Flags,
        PointField::Band,
        PointField::Velocity,
        PointField::Acceleration,
        PointField::PushCurrent,
        PointField::MovingCurrent,
        PointField::ServoGain,
        PointField::MaxAcceleration,
    ];

    /// The edit-area address.
    pub const fn address(self) -> Address {
        Address(match self {
            PointField::Position => 0x400,
            PointField::Flags => 0x401,
            PointField::Band => 0x403,
            PointField::Velocity => 0x404,
            PointField::Acceleration => 0x405,
            PointField::PushCurrent => 0x406,
            PointField::MovingCurrent => 0x407,
            PointField::ServoGain => 0x408,
            PointField::MaxAcceleration => 0x409,
        })
    }

    /// The field's code in the complete edition's memory map (§7-2-2).
    pub const fn code(self) -> &'static str {
        match self {
            PointField::Position => "PCMD",
            PointField::Flags => "FLGP",
            PointField::Band => "INP",
            PointField::Velocity => "VCMD",
            PointField::Acceleration => "ACMD",
            PointField::PushCurrent => "SPOW",
            PointField::MovingCurrent => "DPOW",
            PointField::ServoGain => "PLG0",
            PointField::MaxAcceleration => "MXAC",
        }
    }

    /// The field at an edit-area address.
    pub fn from_address(address: Address) -> Option<PointField> {
        PointField::ALL
            .into_iter()
            .find(|field| field.address() == address)
    }
}

/// FLGP bits (§7-2-2): 1 = take the value from the row, 0 = from the common defaults.
pub mod flgp {
    /// Bit 4: servo gain (0x408).
    pub const SERVO_GAIN: u32 = 1 << 4;
    /// Bit 5: current limits (0x406, 0x407).
    pub const CURRENT: u32 = 1 << 5;
    /// Bit 6: velocity, acceleration, max-acceleration flag (0x404, 0x405, 0x409).
    pub const MOTION: u32 = 1 << 6;
    /// Bit 7: position band (0x403).
    pub const BAND: u32 = 1 << 7;
}

/// MXAC bits (§7-2-3; brief edition §4-3 4 writes 0/1 without push, 6/7 with push).
pub mod mxac {
    /// Bit 0: accelerate at the maximum the load allows.
    pub const MAX_ACCELERATION: u32 = 1 << 0;
    /// Bit 1: the row is a push move.
    pub const PUSH: u32 = 1 << 1;
    /// Bit 2: push in the reverse direction after the approach.
    pub const PUSH_REVERSED: u32 = 1 << 2;
}

/// PNOW: present position, pulses (internal state monitor, §7-2-5).
pub const PNOW: Address = Address(0x7400);
/// VNOW: present velocity, 0.2 rpm (§7-2-5).
pub const VNOW: Address = Address(0x7401);
/// ROM: driver CPU firmware version (§7-2-4).
pub const ROM_VERSION: Address = Address(0x6800);
/// Offset from an edit-area address to its execution-area mirror (§7-3-2).
pub const EXECUTION_OFFSET: u32 = 0x7800;

/// Where a documented address is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Area {
    /// Common parameters (§7-2-1).
    Common,
    /// The point-table row (§7-2-2).
    Point,
    /// The execution-area mirror of a common parameter or point field (§7-3-2).
    Execution,
    /// Read-only monitors (§7-2-4, §7-2-5).
    Monitor,
}

/// The code and area of a documented address, e.g. `0x7400` -> `("PNOW", Monitor)`.
pub fn name(address: Address) -> Option<(&'static str, Area)> {
    const MONITORS: [(Address, &str); 3] = [(PNOW, "PNOW"), (VNOW, "VNOW"), (ROM_VERSION, "ROM")];
    let edit = |address: Address| {
        common::NAMED
            .iter()
            .find(|(a, _)| *a == address)
            .map(|(_, n)| (*n, Area::Common))
            .or_else(|| PointField::from_address(address).map(|f| (f.code(), Area::Point)))
    };
    MONITORS
        .iter()
        .find(|(a, _)| *a == address)
        .map(|(_, n)| (*n, Area::Monitor))
        .or_else(|| edit(address))
        .or_else(|| {
            let mirrored = Address(address.0.checked_sub(EXECUTION_OFFSET)?);
            edit(mirrored).map(|(n, _)| (n, Area::Execution))
        })
}
