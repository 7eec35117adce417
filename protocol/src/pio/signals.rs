//! The signal words: what each bit of the PLC's inputs and of the outputs means (the
//! [module documentation](super) has the table, by PCON pattern 0 port).

use crate::bits::bit_flags;
use crate::PositionNo;

bit_flags! {
    /// The PLC's signals to the gateway, bit n = PCON pattern 0 port INn (1 = ON, the voltage on
    /// the pin; *STP is negative logic, so its bit is 1 when the axis may run).
    PioInputs(u16, masked) {
        /// IN0: position number bit 0.
        0 => PC1, pc1, "PC1";
        /// IN1: position number bit 1.
        1 => PC2, pc2, "PC2";
        /// IN2: position number bit 2.
        2 => PC4, pc4, "PC4";
        /// IN3: position number bit 3.
        3 => PC8, pc8, "PC8";
        /// IN4: PCON's position number bit 4; the RC has none, so a strobe with it ON is refused.
        4 => PC16, pc16, "PC16";
        /// IN5: PCON's position number bit 5; the RC has none, so a strobe with it ON is refused.
        5 => PC32, pc32, "PC32";
        /// IN6: ST6 of pattern 4, MODE of pattern 1 (unused in pattern 0: PCON's IN6 is PC64
        /// there).
        6 => ST6, st6, "ST6";
        /// IN7: JISL of pattern 1: OFF jog while JOG+/JOG- is held, ON inch one step per edge.
        7 => JISL, jisl, "JISL";
        /// IN8: JOG+ of pattern 1.
        8 => JOG_PLUS, jog_plus, "JOG+";
        /// IN9: JOG- of pattern 1.
        9 => JOG_MINUS, jog_minus, "JOG-";
        /// IN11: home, on the rising edge.
        11 => HOME, home, "HOME";
        /// IN12: *STP, negative logic: ON = may run, OFF = stop.
        12 => STP_N, stp_n, "*STP";
        /// IN13: CSTR, start on the rising edge.
        13 => CSTR, cstr, "CSTR";
        /// IN14: RES, alarm reset on the rising edge.
        14 => RES, res, "RES";
        /// IN15: SON, servo on (level).
        15 => SON, son, "SON";
    }
}

bit_flags! {
    /// The gateway's signals to the PLC, bit n = PCON pattern 0 port OUTn (1 = ON; *ALM is
    /// negative logic, so its bit is 1 when there is no alarm).
    PioOutputs(u16, masked) {
        /// OUT0: PM1, completed position number bit 0 (or abbreviated alarm code bit 0).
        0 => PM1, pm1, "PM1";
        /// OUT1: PM2.
        1 => PM2, pm2, "PM2";
        /// OUT2: PM4.
        2 => PM4, pm4, "PM4";
        /// OUT3: PM8.
        3 => PM8, pm8, "PM8";
        /// OUT4: PE4 of pattern 4 (pattern 0's PM16: always OFF, the RC has 16 positions).
        4 => PE4, pe4, "PE4";
        /// OUT5: PE5 of pattern 4 (pattern 0's PM32: always OFF).
        5 => PE5, pe5, "PE5";
        /// OUT6: MOVE, the axis is moving.
        6 => MOVE, moving, "MOVE";
        /// OUT7: ZONE1, the controller's ZONE output.
        7 => ZONE1, zone1, "ZONE1";
        /// OUT9: MODES of pattern 1, teaching mode in force.
        9 => MODES, modes, "MODES";
        /// OUT10: HEND, home complete (ZFIN).
        10 => HEND, hend, "HEND";
        /// OUT11: PEND, positioning complete (PFIN).
        11 => PEND, pend, "PEND";
        /// OUT12: SV, servo on.
        12 => SV, sv, "SV";
        /// OUT13: LINK, the gateway hears the axis (PCON: *EMGS, also ON = able to run).
        13 => LINK, link, "LINK";
        /// OUT14: *ALM, negative logic: ON = no alarm, OFF = alarm (or link down).
        14 => ALM_N, alm_n, "*ALM";
    }
}

impl PioInputs {
    /// PC8..PC1 as a number 0-15.
    pub const fn pc(self) -> u8 {
        // The mask keeps 4 bits, so the cast is exact.
        (self.0 & 0x0F) as u8
    }

    /// The position number PC1-PC8 select, `None` if PC16 or PC32 is ON (beyond the RC's 16).
    pub fn position(self) -> Option<PositionNo> {
        if self.pc16() || self.pc32() {
            None
        } else {
            PositionNo::new(self.pc())
        }
    }

    /// The inputs with PC1-PC8 set to `point` (PC16, PC32 off).
    #[must_use]
    pub fn with_position(self, point: PositionNo) -> PioInputs {
        PioInputs((self.0 & !0x3F) | u16::from(point.get()))
    }
}

impl PioOutputs {
    /// Every output OFF: what the PLC sees while the link is down (*ALM OFF = alarm, LINK OFF).
    pub const SAFE: PioOutputs = PioOutputs(0);

    /// PM8..PM1 as a number 0-15.
    pub const fn pm(self) -> u8 {
        // The mask keeps 4 bits, so the cast is exact.
        (self.0 & 0x0F) as u8
    }

    /// Whether an alarm is shown (*ALM is OFF).
    pub const fn alarm(self) -> bool {
        !self.alm_n()
    }

    /// The value with PM8..PM1 set to `pm` (its low 4 bits).
    #[must_use]
    pub const fn with_pm(self, pm: u8) -> PioOutputs {
        PioOutputs((self.0 & !0x0F) | (pm & 0x0F) as u16)
    }
}
