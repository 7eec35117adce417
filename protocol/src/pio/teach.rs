//! Pattern 1's teaching mode: MODE, the JOG inputs, PWRT, and MODES and WEND (PCON PIO pattern
//! 1, field-research §2).
//!
//! - **MODE** (IN6) ON enters teaching mode once the axis is at rest and the PIO waits for no
//!   move (a PCON does not change mode while it moves); MODES (OUT9) then turns ON. MODE OFF
//!   leaves it at once, and stops a jog under way.
//! - **JOG+ / JOG-** (IN8, IN9) while JISL (IN7) is OFF: held, the axis jogs toward the stroke's
//!   end (JOG+) or home (JOG-) at the jog speed (PIOJOG); released, it stops (`d`). Both ON
//!   stops it. With JISL ON, each rising edge moves one inching step (PIOINCH).
//! - **PWRT** (IN13, CSTR's port): its rising edge, once PC1-PC8 have settled as for a CSTR,
//!   stores the axis' present position into the point they select; the gateway reads the
//!   position (R4 PNOW) first, keeps the row's other fields, and stores it as every table write
//!   (compared first, V5 only if it differs, read back). **WEND** (OUT11, PEND's port, while
//!   teaching) turns ON when the store is done and OFF when PWRT turns OFF; a failed store
//!   leaves it OFF and shows in CMST.
//!
//! Moves to points (CSTR) are pattern 0's while MODE is OFF, and ignored while it is ON.

use crate::engine::JobKind;
use crate::{Acceleration, PositionNo, Pulses, Velocity};

/// Where and how fast the JOG inputs move the axis, in the controller's units: the gateway works
/// it out from the axis' configuration (stroke, scale) and PIOJOG, PIOINCH.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Jog {
    /// Where JOG+ goes: the stroke's end away from home.
    pub plus_end: Pulses,
    /// Where JOG- goes: home (0 mm).
    pub minus_end: Pulses,
    /// One inching step toward JOG+ (a relative move's distance).
    pub plus_step: Pulses,
    /// One inching step toward JOG- (not always `plus_step` negated: an axis in ones'
    /// complement encodes the distance back one pulse lower).
    pub minus_step: Pulses,
    /// The jog speed.
    pub velocity: Velocity,
    /// The jog's acceleration.
    pub acceleration: Acceleration,
}

/// What teaching mode keeps between samples.
#[derive(Clone, Copy, Debug)]
pub(super) struct Teach {
    /// Teaching mode in force (MODES).
    pub(super) active: bool,
    /// A jog held under way: toward JOG+ (`true`) or JOG- (`false`).
    jogging: Option<bool>,
    /// The jog's or the inching step's job, not returned yet.
    pending: Option<JobKind>,
    /// A PWRT for the gateway, not taken yet.
    request: Option<PositionNo>,
    /// The store is done: WEND until PWRT turns OFF.
    pub(super) wend: bool,
    /// Where and how fast to jog (`None`: not known, the JOG inputs do nothing).
    pub(super) jog: Option<Jog>,
}

/// The JOG inputs as recognised on one sample.
#[derive(Clone, Copy, Debug)]
pub(super) struct JogInputs {
    pub(super) plus: bool,
    pub(super) minus: bool,
    pub(super) plus_rose: bool,
    pub(super) minus_rose: bool,
    /// JISL: inching.
    pub(super) inch: bool,
}

impl Teach {
    pub(super) const fn new() -> Teach {
        Teach {
            active: false,
            jogging: None,
            pending: None,
            request: None,
            wend: false,
            jog: None,
        }
    }

    /// Leave teaching mode: whether a jog was under way (the caller stops the axis).
    pub(super) fn leave(&mut self) -> bool {
        self.active = false;
        self.wend = false;
        self.pending = None;
        self.jogging.take().is_some()
    }

    /// The JOG inputs of a sample on which the axis may run: whether the jog under way must
    /// stop.
    pub(super) fn jog_inputs(&mut self, inputs: JogInputs) -> bool {
        let Some(jog) = self.jog else {
            return self.jogging.take().is_some();
        };
        if let Some(plus) = self.jogging {
            let held = if plus { inputs.plus } else { inputs.minus };
            if !held || (inputs.plus && inputs.minus) {
                self.jogging = None;
                self.pending = None;
                return true;
            }
            return false;
        }
        let direction = match (inputs.plus_rose, inputs.minus_rose) {
            (true, false) if !inputs.minus => true,
            (false, true) if !inputs.plus => false,
            _ => return false,
        };
        let (velocity, acceleration) = (jog.velocity, jog.acceleration);
        self.pending = Some(if inputs.inch {
            JobKind::DirectMove {
                target: if direction {
                    jog.plus_step
                } else {
                    jog.minus_step
                },
                relative: true,
                velocity,
                acceleration,
            }
        } else {
            self.jogging = Some(direction);
            JobKind::Jog {
                end: if direction {
                    jog.plus_end
                } else {
                    jog.minus_end
                },
                velocity,
                acceleration,
            }
        });
        false
    }

    /// Whether a held jog is under way.
    pub(super) fn jogging(&self) -> bool {
        self.jogging.is_some()
    }

    /// A PWRT's point: asked of the gateway; WEND OFF until it is stored.
    pub(super) fn write(&mut self, point: PositionNo) {
        self.request = Some(point);
        self.wend = false;
    }

    /// The PWRT not yet handed to the gateway.
    pub(super) fn take_request(&mut self) -> Option<PositionNo> {
        self.request.take()
    }

    /// The jog's job, if one is due.
    pub(super) fn take_job(&mut self) -> Option<JobKind> {
        self.pending.take()
    }

    /// Nothing is kept for an axis that cannot be moved (link down, *STP OFF): no jog.
    pub(super) fn drop_motion(&mut self) {
        self.jogging = None;
        self.pending = None;
    }
}
