//! Alarm and warning codes of both editions (brief edition §4-3 2; complete edition §8-1).
//!
//! Codes 01-7F are warnings: the controller rejected a command and carries on. Codes 80-FF are
//! errors (alarms): the controller stops, turns *ALM off and shows an abbreviated code on PM1-PM8.
//! Where the editions word a code differently both texts are kept; codes only one edition lists
//! say which.

/// The "Alarm" byte of a direct response.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AlarmCode(pub u8);

/// How serious a code is (complete edition §8-1-2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Level {
    /// 00: no alarm.
    Normal,
    /// 01-7F: a command was rejected; the controller keeps running.
    Warning,
    /// 80-FF: the controller is in alarm; `r03` with the servo off resets it.
    Error,
}

/// Which vendor document lists a code.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Source {
    /// Both editions.
    Both,
    /// Only the brief edition (§4-3 2).
    Brief,
    /// Only the complete edition (§8-1-3).
    Complete,
}

/// One row of the table: a code or a range of codes with one meaning.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AlarmInfo {
    /// First code of the row.
    pub first: u8,
    /// Last code of the row (equal to `first` for a single code).
    pub last: u8,
    /// The description (the complete edition's wording where it has one).
    pub text: &'static str,
    /// The brief edition's wording, where it differs.
    pub brief_text: Option<&'static str>,
    /// Abbreviated code shown on PM1-PM8 while the alarm is active (complete edition §8-1-1).
    pub abbreviated: Option<u8>,
    /// Which document lists it.
    pub source: Source,
}

const fn row(
    first: u8,
    last: u8,
    text: &'static str,
    brief_text: Option<&'static str>,
    abbreviated: Option<u8>,
    source: Source,
) -> AlarmInfo {
    AlarmInfo {
        first,
        last,
        text,
        brief_text,
        abbreviated,
        source,
    }
}

use Source::{Both, Brief, Complete};

/// Every documented code, ascending.
pub const TABLE: &[AlarmInfo] = &[
    row(0x00, 0x00, "Normal", Some("No alarm"), None, Both),
    row(0x5A, 0x5A, "Receive buffer overflow", None, None, Brief),
    row(
        0x5B,
        0x5B,
        "Receive buffer framing error",
        None,
        None,
        Brief,
    ),
    row(0x5D, 0x5D, "Header abnormal character", None, None, Brief),
    row(
        0x5E,
        0x5E,
        "Delimiter abnormal character",
        None,
        None,
        Brief,
    ),
    row(0x5F, 0x5F, "BCC error", None, None, Brief),
    row(
        0x61,
        0x61,
        "Illegal serial character or illegal memory address",
        Some("Received bad character"),
        None,
        Both,
    ),
    row(
        0x62,
        0x62,
        "First operand in the serial string is not correct",
        Some("Incorrect operand"),
        None,
        Both,
    ),
    row(
        0x63,
        0x63,
        "Second operand in the serial string is not correct",
        Some("Incorrect operand"),
        None,
        Both,
    ),
    row(
        0x64,
        0x64,
        "Third operand in the serial string is not correct",
        Some("Incorrect operand"),
        None,
        Both,
    ),
    row(
        0x70,
        0x70,
        "Attempted to move while the RUN state bit is OFF",
        Some("Tried to move while run status was off"),
        None,
        Both,
    ),
    row(
        0x71,
        0x71,
        "Attempted a PTP operation before homing is completed",
        None,
        None,
        Complete,
    ),
    row(
        0x73,
        0x73,
        "Attempted to reset alarm while servo ON instruction state bit ON",
        None,
        None,
        Complete,
    ),
    row(
        0x74,
        0x74,
        "Attempted to move during motor initialization process",
        Some("Tried to move during motor commutation"),
        None,
        Both,
    ),
    row(
        0x75,
        0x75,
        "Movement command while homing",
        Some("Tried to move while homing"),
        None,
        Both,
    ),
    row(
        0xB0,
        0xB0,
        "Abnormal parameter data",
        None,
        Some(0x06),
        Complete,
    ),
    row(
        0xB1,
        0xB1,
        "Abnormal position data",
        Some("Position data error"),
        Some(0x06),
        Both,
    ),
    row(
        0xB8,
        0xB8,
        "Motor commutation error 1",
        Some("Motor commutation error"),
        Some(0x07),
        Both,
    ),
    row(
        0xB9,
        0xB9,
        "Motor commutation error 2",
        Some("Motor commutation error"),
        Some(0x07),
        Both,
    ),
    row(
        0xBB,
        0xBB,
        "Bad encoder feedback while homing",
        None,
        None,
        Brief,
    ),
    row(
        0xBC,
        0xBC,
        "Encoder error: A and B phases not functioning properly",
        Some("Bad encoder feedback while homing"),
        Some(0x07),
        Both,
    ),
    row(
        0xBD,
        0xBE,
        "Bad encoder feedback while homing",
        None,
        None,
        Brief,
    ),
    row(
        0xC0,
        0xC0,
        "Overspeed",
        Some("Excess speed / servo error"),
        Some(0x08),
        Both,
    ),
    row(
        0xC1,
        0xC1,
        "Servo error",
        Some("Excess speed / servo error"),
        Some(0x08),
        Both,
    ),
    row(
        0xC8,
        0xC8,
        "Overcurrent",
        Some("Excess current"),
        Some(0x09),
        Both,
    ),
    row(
        0xD0,
        0xD0,
        "Incoming power supply is out of range",
        Some("Excess main power voltage"),
        Some(0x0A),
        Both,
    ),
    row(
        0xD1,
        0xD1,
        "Regeneration power is excessive",
        Some("Over-regeneration"),
        Some(0x0A),
        Both,
    ),
    row(
        0xD8,
        0xD8,
        "Positional deflection is excessive",
        Some("Deviation error"),
        Some(0x0B),
        Both,
    ),
    row(0xE0, 0xE0, "Overload", None, None, Brief),
    row(
        0xE8,
        0xE8,
        "Encoder A and B phase disconnection",
        Some("Encoder disconnect"),
        Some(0x0D),
        Both,
    ),
    row(
        0xE9,
        0xE9,
        "Encoder A phase disconnection",
        Some("Encoder disconnect"),
        Some(0x0D),
        Both,
    ),
    row(
        0xEA,
        0xEA,
        "Encoder B phase disconnection",
        Some("Encoder disconnect"),
        Some(0x0D),
        Both,
    ),
    row(0xEB, 0xEC, "Encoder disconnect", None, None, Brief),
    row(0xED, 0xEE, "Encoder error", None, None, Brief),
    row(
        0xF8,
        0xF8,
        "Nonvolatile memory data error",
        Some("Corrupt memory"),
        Some(0x0F),
        Both,
    ),
];

/// Meaning of the abbreviated codes on PM8..PM1 while *ALM is off (complete edition §8-1-1).
pub const ABBREVIATED: &[(u8, &str)] = &[
    (0x06, "Nonvolatile memory data setting error"),
    (0x07, "Homing or motor excitation error"),
    (0x08, "Servo error"),
    (0x09, "Overcurrent in power conversion"),
    (0x0A, "Other power conversion error"),
    (0x0B, "Deviation error"),
    (0x0D, "Encoder breakage"),
    (0x0F, "Nonvolatile memory data corrupt"),
];

impl AlarmCode {
    /// No alarm.
    pub const NONE: AlarmCode = AlarmCode(0);

    /// The level, from the code's range (complete edition §8-1-2).
    pub const fn level(self) -> Level {
        match self.0 {
            0x00 => Level::Normal,
            0x01..=0x7F => Level::Warning,
            _ => Level::Error,
        }
    }

    /// The table row, if the code is documented.
    pub fn info(self) -> Option<&'static AlarmInfo> {
        TABLE
            .iter()
            .find(|row| (row.first..=row.last).contains(&self.0))
    }

    /// A description for people: the documented text, or the level for an undocumented code.
    pub fn text(self) -> &'static str {
        match (self.info(), self.level()) {
            (Some(row), _) => row.text,
            (None, Level::Normal) => "Normal",
            (None, Level::Warning) => "Undocumented warning (command rejected)",
            (None, Level::Error) => "Undocumented error",
        }
    }
}

/// The meaning of an abbreviated code shown on PM1-PM8.
pub fn abbreviated_text(code: u8) -> Option<&'static str> {
    ABBREVIATED
        .iter()
        .find(|(c, _)| *c == code)
        .map(|(_, text)| *text)
}
