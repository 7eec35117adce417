//! The four bytes of the direct response (complete edition §4-2): Status, Alarm, IN, OUT.

use crate::alarm::AlarmCode;
use crate::bits::bit_flags;

bit_flags! {
    /// The "Status" byte: the controller's internal state (complete edition §4-2).
    ///
    /// The brief edition marks bits 4-6 "not used"; the complete edition defines them.
    Status(u8, raw) {
        /// Bit 0: control power is on (always 1 when the controller answers).
        0 => POWER, power, "power";
        /// Bit 1: servo is on.
        1 => SERVO, servo, "servo";
        /// Bit 2: RUN, servo on and no alarm; moves are rejected (0x70) while it is 0.
        2 => RUN, run, "run";
        /// Bit 3: HOME, homing complete (same as ZFIN); `a` and `m` are rejected (0x71) before it.
        3 => HOME, home, "home";
        /// Bit 4: a buffered (`h`) command waits for `t`.
        4 => BUFFERED, buffered, "buffered";
        /// Bit 5: + direction interlocked by the software stroke limit LIMM.
        5 => PLUS_INTERLOCK, plus_interlock, "plus_interlock";
        /// Bit 6: - direction interlocked by the software stroke limit LIML.
        6 => MINUS_INTERLOCK, minus_interlock, "minus_interlock";
        /// Bit 7: the command was rejected; the Alarm byte gives the reason (§4-3).
        7 => REJECTED, rejected, "rejected";
    }
}

bit_flags! {
    /// The "IN" byte: the controller's PIO inputs (complete edition §4-2, 1 = ON).
    Inputs(u8, raw) {
        /// Bit 0: position number bit 1 (PC1).
        0 => PC1, pc1, "PC1";
        /// Bit 1: position number bit 2 (PC2).
        1 => PC2, pc2, "PC2";
        /// Bit 2: position number bit 4 (PC4).
        2 => PC4, pc4, "PC4";
        /// Bit 3: position number bit 8 (PC8).
        3 => PC8, pc8, "PC8";
        /// Bit 4: Start (CSTR).
        4 => START, start, "START";
        /// Bit 7: Hold.
        7 => HOLD, hold, "HOLD";
    }
}

bit_flags! {
    /// The "OUT" byte: the controller's PIO outputs (complete edition §4-2, 1 = ON).
    Outputs(u8, raw) {
        /// Bit 0: PM1, completed position number bit 1 (or abbreviated alarm code bit 1).
        0 => PM1, pm1, "PM1";
        /// Bit 1: PM2.
        1 => PM2, pm2, "PM2";
        /// Bit 2: PM4.
        2 => PM4, pm4, "PM4";
        /// Bit 3: PM8.
        3 => PM8, pm8, "PM8";
        /// Bit 4: PFIN, positioning complete (within the band); off on a new move command.
        4 => PFIN, pfin, "PFIN";
        /// Bit 5: ZFIN, home complete; stays on until power is lost.
        5 => ZFIN, zfin, "ZFIN";
        /// Bit 6: ZONE, position between ZONL and ZONM (and ZFIN on).
        6 => ZONE, zone, "ZONE";
        /// Bit 7: *ALM, negative logic: ON in normal operation, OFF when an alarm is active.
        7 => ALM_N, alm_n, "*ALM";
    }
}

impl Outputs {
    /// PM8..PM1 as a number 0-15.
    pub const fn pm(self) -> u8 {
        self.0 & 0x0F
    }

    /// Whether an alarm is active (*ALM is off).
    pub const fn alarm_active(self) -> bool {
        !self.alm_n()
    }

    /// The completed position number on PM1-PM8, when no alarm is active and PFIN is on.
    pub fn completed_position(self) -> Option<crate::PositionNo> {
        if self.alarm_active() || !self.pfin() {
            return None;
        }
        crate::PositionNo::new(self.pm())
    }

    /// The abbreviated alarm code on PM1-PM8 while an alarm is active (complete edition §8-1-1).
    pub const fn abbreviated_alarm(self) -> Option<u8> {
        if self.alarm_active() {
            Some(self.pm())
        } else {
            None
        }
    }
}

impl Inputs {
    /// PC8..PC1 as a number 0-15.
    pub const fn pc(self) -> u8 {
        self.0 & 0x0F
    }
}

/// Status, Alarm, IN and OUT: the body of every direct response.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StatusReport {
    /// The "Status" byte.
    pub status: Status,
    /// The "Alarm" byte: 00 normal, 01-7F warning (reason for a rejection), 80-FF error.
    pub alarm: AlarmCode,
    /// The "IN" byte.
    pub inputs: Inputs,
    /// The "OUT" byte.
    pub outputs: Outputs,
}

impl StatusReport {
    /// Whether the command this answers was rejected; then [`alarm`](Self::alarm) says why.
    pub const fn rejected(&self) -> bool {
        self.status.rejected()
    }
}
