//! IAI's PIO patterns: which port carries which signal, by the pattern's number (PCON parameter
//! No. 25; field-research §2, "Controller PIO patterns").
//!
//! The project's notes name each pattern's signals, not their ports; the ports below are our
//! reading of PCON's port-assignment tables, where the signals of pattern 0 keep their ports
//! (HOME IN11, *STP IN12, RES IN14, SON IN15; ZONE1 OUT7, HEND OUT10, PEND OUT11, SV OUT12,
//! *EMGS OUT13, *ALM OUT14) and the pattern's own signals take the position number's ports
//! from IN0/OUT0 up.

use super::{PioInputs, PioOutputs};

/// Whether this build has pattern 1 (teaching): the protocol crate's `teaching` feature, on by
/// default and on the boards with room for it. Pattern 1 takes about 2 KB of flash, which the
/// F103 does not have to spare (nor the ports: IN6-IN9, OUT9); without it, PIOPAT 1 is refused
/// and its code is not linked (every use is behind this constant).
pub const TEACHING: bool = cfg!(feature = "teaching");

/// The PIO pattern, by IAI's number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Pattern {
    /// 0, positioning: PC1-PC8 select a point, CSTR starts the move, PM1-PM8 show the point
    /// reached.
    Positioning = 0,
    /// 1, teaching: pattern 0 while MODE (IN6) is OFF; while it is ON, JOG+/JOG- (IN8, IN9)
    /// jog the axis (JISL, IN7: OFF while held, ON one inching step per edge) and PWRT (IN13,
    /// CSTR's port) stores the axis' position into the point PC1-PC8 select; MODES (OUT9) shows
    /// teaching mode, WEND (OUT11, PEND's port) the store done.
    Teaching = 1,
    /// 4, solenoid valve mode 1: STn (IN0-IN6) moves to point n, PEn (OUT0-OUT6) is ON when
    /// point n is complete. An actuator replaces a seven-position air cylinder and its valve.
    Solenoid7 = 4,
    /// 5, solenoid valve mode 2: ST0 (IN0) to the rear end (point 0), ST1 (IN1) to the front
    /// end (point 1), ST2 (IN2) to the intermediate point (point 2); LSn (OUT0-OUT2) is ON while
    /// the axis is within point n's band, as a cylinder's reed switches.
    Solenoid3 = 5,
}

/// How a solenoid pattern's ST inputs start a move (PCON parameter No. 27).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StartMode {
    /// 0, level: the axis moves while STn is ON; releasing it before the point is reached
    /// decelerates the axis to a stop, as releasing an air cylinder's valve stops it.
    Level = 0,
    /// 1, edge: STn's rising edge starts the move, which goes on when it is released.
    Edge = 1,
}

/// The PIO ports a board has (bit n = INn / OUTn): the patterns it can run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Ports {
    /// Input ports.
    pub inputs: u16,
    /// Output ports.
    pub outputs: u16,
}

impl Ports {
    /// Every port (a host without pins).
    pub const ALL: Ports = Ports {
        inputs: u16::MAX,
        outputs: u16::MAX,
    };

    /// Whether these ports carry every signal of `pattern`.
    pub const fn run(self, pattern: Pattern) -> bool {
        pattern.inputs() & !self.inputs == 0 && pattern.outputs() & !self.outputs == 0
    }
}

/// PCON pattern 0's inputs, every one of which the other patterns keep but the position number
/// and CSTR.
const COMMON_INPUTS: u16 = PioInputs::HOME.bits()
    | PioInputs::STP_N.bits()
    | PioInputs::RES.bits()
    | PioInputs::SON.bits();

/// Pattern 0's outputs that every pattern keeps.
const COMMON_OUTPUTS: u16 = PioOutputs::ZONE1.bits()
    | PioOutputs::HEND.bits()
    | PioOutputs::PEND.bits()
    | PioOutputs::SV.bits()
    | PioOutputs::LINK.bits()
    | PioOutputs::ALM_N.bits();

/// Pattern 0's inputs: PC1-PC32, HOME, *STP, CSTR, RES, SON.
const POSITIONING_INPUTS: u16 = COMMON_INPUTS | 0x3F | PioInputs::CSTR.bits();

/// Pattern 0's outputs: PM1-PM8, MOVE and the common ones.
const POSITIONING_OUTPUTS: u16 = COMMON_OUTPUTS | 0x0F | PioOutputs::MOVE.bits();

impl StartMode {
    /// The mode of PCON parameter No. 27's value `code`.
    pub const fn from_code(code: u16) -> Option<StartMode> {
        match code {
            0 => Some(StartMode::Level),
            1 => Some(StartMode::Edge),
            _ => None,
        }
    }
}

impl Pattern {
    /// Every pattern the gateway has.
    pub const ALL: [Pattern; 4] = [
        Pattern::Positioning,
        Pattern::Teaching,
        Pattern::Solenoid7,
        Pattern::Solenoid3,
    ];

    /// IAI's number.
    pub const fn code(self) -> u16 {
        self as u16
    }

    /// The pattern of IAI's number `code`, if the gateway has it.
    pub const fn from_code(code: u16) -> Option<Pattern> {
        match code {
            0 => Some(Pattern::Positioning),
            1 if TEACHING => Some(Pattern::Teaching),
            4 => Some(Pattern::Solenoid7),
            5 => Some(Pattern::Solenoid3),
            _ => None,
        }
    }

    /// The ST inputs (bit n = STn on INn); none for positioning.
    pub const fn st_inputs(self) -> u16 {
        match self {
            Pattern::Positioning | Pattern::Teaching => 0,
            Pattern::Solenoid7 => 0x7F,
            Pattern::Solenoid3 => 0x07,
        }
    }

    /// Whether the ST inputs start the moves (a solenoid pattern), not CSTR.
    pub const fn solenoid(self) -> bool {
        self.st_inputs() != 0
    }

    /// The input ports the pattern reads (bit n = INn): a board must have them all to run it.
    pub const fn inputs(self) -> u16 {
        match self {
            Pattern::Positioning => POSITIONING_INPUTS,
            Pattern::Teaching => PioInputs::MASK,
            _ => COMMON_INPUTS | self.st_inputs(),
        }
    }

    /// The output ports the pattern drives (bit n = OUTn): a board must have them all to run
    /// it.
    pub const fn outputs(self) -> u16 {
        match self {
            Pattern::Positioning => POSITIONING_OUTPUTS,
            Pattern::Teaching => POSITIONING_OUTPUTS | PioOutputs::MODES.bits(),
            // OUT6 is PE6: no MOVE.
            Pattern::Solenoid7 => COMMON_OUTPUTS | 0x7F,
            Pattern::Solenoid3 => COMMON_OUTPUTS | 0x07 | PioOutputs::MOVE.bits(),
        }
    }
}

/// What the outputs show of a latched fail-safe depends on the pattern's outputs.
impl PioOutputs {
    /// The outputs with the gateway's latched fail-safe (`failsafe`, the FAILSAFE register)
    /// shown, so that a machine wired by 24 V only sees what its RES pulse is to acknowledge:
    /// *ALM OFF and PM1-PM8 = FAILSAFE (PM1 the PLC watchdog, PM2 the stop input). These codes
    /// (1-3) are none of the controller's abbreviated alarm codes (complete edition §8-1-1: 6
    /// and up), and the axis' own alarm, or a link down, is shown first.
    ///
    /// In the solenoid patterns, whose OUT0-OUT3 are no position number, *ALM alone shows it:
    /// pattern 4's PE outputs go OFF with it (as with any alarm), pattern 5's reed switches
    /// keep showing where the axis is.
    #[must_use]
    pub const fn with_failsafe(self, failsafe: u16, pattern: Pattern) -> PioOutputs {
        if failsafe == 0 || self.alarm() {
            return self;
        }
        let alarmed = self.with(PioOutputs::ALM_N, false);
        match pattern {
            // FAILSAFE's two causes are bits 0 and 1: the cast keeps them.
            Pattern::Positioning | Pattern::Teaching => alarmed.with_pm((failsafe & 0x3) as u8),
            Pattern::Solenoid7 => PioOutputs::from_bits(alarmed.bits() & !pattern.st_inputs()),
            Pattern::Solenoid3 => alarmed,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pattern 1 is taken only by a build that has it (PIOPAT and the stored settings both read
    /// the number through `from_code`).
    #[test]
    fn pattern_1_only_where_built() {
        assert_eq!(Pattern::from_code(1).is_some(), TEACHING);
        assert_eq!(TEACHING, cfg!(feature = "teaching"));
    }
}
