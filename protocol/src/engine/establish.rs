//! The communication establishment procedure (complete edition §6-1), as a sequence the engine
//! walks through before it polls: every axis back to 9.6 kbit/s and RTIM 255 ms by a break, then
//! for each axis `p` (RTIM), T4/W4 of BRSL and RTIM, then three communication-change
//! broadcasts, 150 ms, and the line switched to the new rate.

use crate::line::{Baud, LineAction, BAUD_AFTER_BREAK};
use crate::memory::common;
use crate::{Axis, Command, Rtim};

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
        Phase::Break => Some(Next::Line(LineAction::Break)),
        Phase::Configure { axis, step } => configure(step, baud, rtim).map(|c| Next::Send(axis, c)),
        Phase::Broadcast { .. } => Some(Next::Line(LineAction::CommChange)),
        Phase::FastBaud => Some(Next::Line(LineAction::SetBaud(baud))),
        Phase::Settle => None,
    }
}
