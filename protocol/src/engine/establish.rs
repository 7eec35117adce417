//! The communication establishment procedure (complete edition §6-1), as a sequence the engine
//! walks through before it polls: every axis back to 9.6 kbit/s and RTIM 255 ms by a break, then
//! for each axis `p` (RTIM), T4/W4 of BRSL and RTIM, then three communication-change
//! broadcasts, 150 ms, and the line switched to the new rate.

use super::{Engine, Origin, Output};
use crate::line::{
    Baud, LineAction, BAUD_AFTER_BREAK, BREAK_MS, COMM_CHANGE_REPEATS, COMM_CHANGE_SETTLE_MS,
};
use crate::memory::common;
use crate::time::{Duration, Instant};
use crate::{Axis, Command, Reply, Request, Rtim, RTIM_AFTER_BREAK};

/// Where the procedure is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub(crate) enum Phase {
    /// Switch the UART to 9.6 kbit/s.
    SlowBaud,
    /// Send the break.
    Break,
    /// Configure one axis; `step` indexes [`configure`].
    Configure { axis: Axis, step: u8 },
    /// Send the broadcast; `sent` so far.
    Broadcast { sent: u8 },
    /// Switch the UART to the new rate.
    FastBaud,
    /// Wait for the axes to take the new settings.
    Settle,
}

/// What the engine does next in the procedure.
pub(crate) enum Next {
    Line(LineAction),
    Send(Axis, Command),
}

/// How many frames configure one axis ([`configure`]).
pub(crate) const CONFIGURE_STEPS: u8 = 5;

/// The five frames that configure one axis (§6-1 steps 2-6).
pub(crate) fn configure(step: u8, baud: Baud, rtim: Rtim) -> Option<Command> {
    Some(match step {
        0 => Command::SetResponseDelay(rtim),
        1 => Command::SetWriteAddress {
            address: common::BRSL,
        },
        2 => Command::WriteMemory {
            value: baud.brsl().into(),
        },
        3 => Command::SetWriteAddress {
            address: common::RTIM,
        },
        4 => Command::WriteMemory {
            value: rtim.get().into(),
        },
        _ => return None,
    })
}

/// The action of a phase.
pub(crate) fn next(phase: Phase, baud: Baud, rtim: Rtim) -> Option<Next> {
    match phase {
        Phase::SlowBaud => Some(Next::Line(LineAction::SetBaud(BAUD_AFTER_BREAK))),
        Phase::Break => Some(Next::Line(LineAction::BreakStart)),
        Phase::Configure { axis, step } => configure(step, baud, rtim).map(|c| Next::Send(axis, c)),
        Phase::Broadcast { .. } => Some(Next::Line(LineAction::CommChange)),
        Phase::FastBaud => Some(Next::Line(LineAction::SetBaud(baud))),
        Phase::Settle => None,
    }
}

impl Engine {
    /// Run the communication establishment procedure (again). A resend left over from a
    /// procedure in progress is dropped: it belongs to the old one.
    pub fn establish(&mut self) {
        if matches!(self.retry, Some((_, Origin::Establish, _))) {
            self.retry = None;
        }
        self.phase = Some(Phase::SlowBaud);
    }

    pub(super) fn establish_step(&mut self, now: Instant) -> Option<Output> {
        let phase = self.phase?;
        if phase == Phase::Settle {
            if now < self.settle_until {
                return Some(Output::Idle(Some(self.settle_until)));
            }
            self.phase = None;
            let rtim = self.config.rtim;
            for axis in self.config.axes.iter() {
                self.axes[axis].rtim = rtim;
            }
            self.bus.establishments = self.bus.establishments.wrapping_add(1);
            // Polling starts now: no axis is overdue for the time establishment took.
            self.schedule.start_cycle(now);
            self.emit(super::Event::Established);
            return None;
        }
        if let Some((request, origin, attempt)) = self.retry.take() {
            return Some(self.start(now, request, origin, attempt));
        }
        match next(phase, self.config.baud, self.config.rtim) {
            Some(Next::Line(action)) => {
                self.phase = Some(self.after(phase));
                match action {
                    LineAction::SetBaud(baud) => {
                        self.line_baud = baud;
                        self.deframer.reset();
                    }
                    LineAction::BreakStart => {
                        let end = now + Duration::from_millis(u64::from(BREAK_MS));
                        self.break_until = Some(end);
                        self.free_at = end;
                        self.deframer.reset();
                        for state in self.axes.values_mut() {
                            state.rtim = RTIM_AFTER_BREAK;
                        }
                    }
                    LineAction::CommChange => {
                        self.free_at = now + super::timing::frame_time(self.line_baud);
                    }
                    LineAction::BreakEnd => {}
                }
                if self.phase == Some(Phase::Settle) {
                    self.settle_until =
                        now + Duration::from_millis(u64::from(COMM_CHANGE_SETTLE_MS));
                }
                Some(Output::Line(action))
            }
            Some(Next::Send(axis, command)) => {
                Some(self.start(now, Request::new(axis, command), Origin::Establish, 0))
            }
            None => None,
        }
    }

    /// The phase after a line action.
    fn after(&self, phase: Phase) -> Phase {
        match phase {
            Phase::SlowBaud => Phase::Break,
            Phase::Break => self.configure_from(0),
            Phase::Broadcast { sent } if sent.saturating_add(1) < COMM_CHANGE_REPEATS => {
                Phase::Broadcast { sent: sent + 1 }
            }
            Phase::Broadcast { .. } => Phase::FastBaud,
            Phase::FastBaud | Phase::Settle => Phase::Settle,
            Phase::Configure { .. } => phase,
        }
    }

    /// Configure the first configured axis numbered `from` or above, or broadcast if none is
    /// left.
    fn configure_from(&self, from: u8) -> Phase {
        self.config.axes.iter().find(|a| a.get() >= from).map_or(
            Phase::Broadcast { sent: 0 },
            |axis| Phase::Configure { axis, step: 0 },
        )
    }

    pub(super) fn establish_next_axis(&mut self, axis: Axis) {
        self.phase = Some(if axis.get() == 15 {
            Phase::Broadcast { sent: 0 }
        } else {
            self.configure_from(axis.get() + 1)
        });
    }

    /// A W4 of the procedure timed out: back to its T4 (§5 (1)).
    pub(super) fn establish_rewind(&mut self) {
        if let Some(Phase::Configure { axis, step }) = self.phase {
            self.phase = Some(Phase::Configure {
                axis,
                step: step.saturating_sub(1),
            });
        }
    }

    pub(super) fn establish_reply(&mut self, axis: Axis, request: &Request, reply: &Reply) {
        let Some(Phase::Configure { step, .. }) = self.phase else {
            return;
        };
        if reply.rejection().is_some() {
            // A refused step (e.g. `p` during motor initialisation, warning 74): the axis keeps
            // its power-up settings; it will be offline at the new rate and rejoin later.
            self.axes[axis].rtim = RTIM_AFTER_BREAK;
            self.establish_next_axis(axis);
            return;
        }
        if let Command::SetResponseDelay(rtim) = request.command {
            // §6-1 step 2: the new delay is in force from this reply on.
            self.axes[axis].rtim = rtim;
        }
        if step.saturating_add(1) < CONFIGURE_STEPS {
            self.phase = Some(Phase::Configure {
                axis,
                step: step + 1,
            });
        } else {
            self.establish_next_axis(axis);
        }
    }
}
