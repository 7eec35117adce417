//! The rejoin of one axis: a controller that was power-cycled or replaced comes back at its
//! stored settings (9.6 kbit/s and RTIM 255 ms after a factory reset), not at the bus'. Every
//! [`Config::rejoin_interval`](super::Config::rejoin_interval) an offline axis is tried there
//! instead of probed, and if it answers it is configured like §6-1 for that axis alone: the
//! five frames of §6-1 steps 2-6 at the power-up rate, the communication-change broadcast
//! three times (only that axis listens at that rate), and 150 ms later it is at ours.
//!
//! A rejoin frame goes every other turn with polling, so that live axes keep being polled.

use super::establish;
use super::{Engine, Next, Origin, Output};
use crate::axes::AxisMap;
use crate::line::{LineAction, BAUD_AFTER_BREAK, COMM_CHANGE_REPEATS, COMM_CHANGE_SETTLE_MS};
use crate::time::{Duration, Instant};
use crate::{Axis, Command, Reply, Request, RTIM_AFTER_BREAK};

/// The rejoin state: the axis being reconfigured and its step, when each axis may be tried
/// next, and whose turn it is.
#[derive(Clone, Copy, Debug)]
pub(super) struct Rejoin {
    current: Option<(Axis, u8)>,
    due: AxisMap<Instant>,
    turn: bool,
}

impl Rejoin {
    pub(super) const fn new() -> Rejoin {
        Rejoin {
            current: None,
            due: AxisMap::new(Instant::ZERO),
            turn: false,
        }
    }

    /// Whether this turn is the rejoin's (every other call).
    pub(super) fn take_turn(&mut self) -> bool {
        self.turn = !self.turn;
        self.turn
    }
}

impl Engine {
    /// Whether `axis` is being reconfigured at the power-up rate.
    pub(super) fn rejoining(&self, axis: Axis) -> bool {
        self.rejoin.current.is_some_and(|(a, _)| a == axis)
    }

    /// Begin reconfiguring `axis` at the power-up settings, if it is time to try.
    pub(super) fn start_rejoin(&mut self, now: Instant, axis: Axis) -> bool {
        if !self.config.establish || self.rejoin.current.is_some() || now < self.rejoin.due[axis] {
            return false;
        }
        self.rejoin.due[axis] = now + self.config.rejoin_interval;
        self.axes[axis].rtim = RTIM_AFTER_BREAK;
        self.rejoin.current = Some((axis, 0));
        true
    }

    /// Give up the rejoin in progress: the axis is probed at the bus' settings again.
    pub(super) fn abort_rejoin(&mut self) {
        if let Some((axis, _)) = self.rejoin.current.take() {
            self.axes[axis].rtim = self.config.rtim;
        }
    }

    /// Steps 0-4 are the frames of §6-1 steps 2-6 for the axis.
    pub(super) fn next_rejoin_frame(&mut self) -> Option<Next> {
        let (axis, step) = self.rejoin.current?;
        let command = establish::configure(step, self.config.baud, self.config.rtim)?;
        Some((Request::new(axis, command), Origin::Rejoin, 0))
    }

    pub(super) fn rejoin_reply(&mut self, axis: Axis, request: &Request, reply: &Reply) {
        if reply.rejection().is_some() {
            self.abort_rejoin();
            return;
        }
        if let Command::SetResponseDelay(rtim) = request.command {
            self.axes[axis].rtim = rtim;
        }
        if let Some((a, step)) = self.rejoin.current {
            self.rejoin.current = Some((a, step.saturating_add(1)));
        }
    }

    /// After the five frames: the broadcast (three times, at the power-up rate, where only the
    /// rejoining axis listens), then the axis takes the new settings 150 ms later.
    pub(super) fn rejoin_line_action(&mut self, now: Instant) -> Option<Output> {
        let (axis, step) = self.rejoin.current?;
        if establish::configure(step, self.config.baud, self.config.rtim).is_some() {
            return None;
        }
        let sent = step.saturating_sub(establish::CONFIGURE_STEPS);
        if sent < COMM_CHANGE_REPEATS {
            if self.line_baud != BAUD_AFTER_BREAK {
                self.line_baud = BAUD_AFTER_BREAK;
                self.deframer.reset();
                return Some(Output::Line(LineAction::SetBaud(self.line_baud)));
            }
            self.rejoin.current = Some((axis, step.saturating_add(1)));
            self.free_at = now + super::timing::frame_time(self.line_baud);
            return Some(Output::Line(LineAction::CommChange));
        }
        self.rejoin.current = None;
        self.axes[axis].rtim = self.config.rtim;
        let settle = Duration::from_millis(u64::from(COMM_CHANGE_SETTLE_MS) + 10);
        self.schedule.probe_at(axis, now + settle);
        None
    }
}
