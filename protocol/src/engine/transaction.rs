//! One transaction at a time: starting it (time-out and earliest answer), matching what comes
//! back, and what a failed attempt leads to (§5: resend, or give up).

use super::{
    job::{program, Op},
    Engine, Failure, InFlight, JobError, Link, LinkError, Origin, Output,
};
use crate::time::{Duration, Instant};
use crate::{Command, Error, Frame, Reply, Request};

use super::timing;

impl Engine {
    /// Whether a frame ending at `now` may be the answer to `flight` (see
    /// [`Config::wire_timing`](super::Config::wire_timing)).
    fn in_time(&self, flight: &InFlight, now: Instant) -> bool {
        !self.config.wire_timing || now >= flight.earliest_reply
    }

    pub(super) fn on_bad_candidate(&mut self, now: Instant, error: Error) {
        let Some(flight) = self.in_flight else {
            self.bus.unsolicited = self.bus.unsolicited.wrapping_add(1);
            return;
        };
        let bad_bcc = matches!(error, Error::BadBcc { .. });
        let c = &mut self.axes[flight.request.axis].counters;
        if bad_bcc {
            c.bcc_errors = c.bcc_errors.wrapping_add(1);
        } else {
            c.bad_replies = c.bad_replies.wrapping_add(1);
        }
        let ours = self.deframer.rejected().get(2) == Some(&flight.request.axis.to_char());
        if bad_bcc && ours && self.in_time(&flight, now) {
            // A whole frame ended: whoever sent it is done and the line is free.
            self.attempt_failed(now, flight, Failure::Corrupted);
        }
    }

    pub(super) fn on_frame(&mut self, now: Instant, frame: &Frame) {
        let Some(flight) = self.in_flight else {
            self.bus.unsolicited = self.bus.unsolicited.wrapping_add(1);
            return;
        };
        let reply = match Reply::parse(frame) {
            Ok(reply) if reply.answers(&flight.request).is_ok() && self.in_time(&flight, now) => {
                reply
            }
            _ => {
                // Malformed, another axis, another command, or too early: never accepted.
                let c = &mut self.axes[flight.request.axis].counters;
                c.bad_replies = c.bad_replies.wrapping_add(1);
                return;
            }
        };
        self.in_flight = None;
        self.free_at = now + timing::HOST_GAP;
        // A V5's answer waits for the memory write, and a rejoin or the establishment talks at
        // another rate: not what a poll takes.
        let typical = !matches!(flight.request.command, Command::StoreFromEdit(_))
            && !matches!(flight.origin, Origin::Rejoin | Origin::Establish);
        if typical {
            let took = now.since(flight.sent).plus(timing::HOST_GAP);
            let on = (self.config.baud, self.config.rtim);
            self.schedule.transaction_measured(on, took);
        }
        self.complete(now, flight, reply);
    }

    pub(super) fn start(
        &mut self,
        now: Instant,
        request: Request,
        origin: Origin,
        attempt: u8,
    ) -> Output {
        // An axis owed a stop hears nothing else first.
        let stands_in =
            self.owed.contains(request.axis) && !matches!(request.command, Command::CancelMotion);
        let request = if stands_in {
            Request::new(request.axis, Command::CancelMotion)
        } else {
            request
        };
        let baud = self.line_baud;
        let state = &mut self.axes[request.axis];
        state.counters.frames_sent = state.counters.frames_sent.wrapping_add(1);
        if attempt > 0 {
            state.counters.retries = state.counters.retries.wrapping_add(1);
        }
        let is_v5 = matches!(request.command, Command::StoreFromEdit(_));
        let deadline = now
            + timing::frame_time(baud)
                .plus(timing::response_timeout(baud, state.rtim, is_v5))
                .plus(self.config.reply_slack);
        // §6-1 step 2: `p`'s own answer may already come after the new delay.
        let fastest = match request.command {
            Command::SetResponseDelay(new) => new.min(state.rtim),
            _ => state.rtim,
        };
        let rtim = Duration::from_millis(u64::from(fastest.get()));
        let earliest_reply = now
            + timing::frame_time(baud)
                .plus(rtim)
                .plus(timing::frame_time(baud));
        let frame = request.emit();
        if self.config.echo {
            self.deframer.expect_echo(&frame.to_bytes());
        }
        self.in_flight = Some(InFlight {
            request,
            origin,
            deadline,
            earliest_reply,
            sent: now,
            attempt,
            stands_in,
        });
        Output::Transmit(frame)
    }

    pub(super) fn attempt_failed(&mut self, now: Instant, flight: InFlight, failure: Failure) {
        self.in_flight = None;
        let axis = flight.request.axis;
        match failure {
            Failure::Timeout => {
                self.free_at = now;
                self.deframer.reset();
                let c = &mut self.axes[axis].counters;
                c.timeouts = c.timeouts.wrapping_add(1);
            }
            Failure::Corrupted => self.free_at = now + timing::HOST_GAP,
        }
        // A move whose answer is lost may have started, resent or not: a stop may cancel its
        // job before the resend goes.
        if matches!(flight.origin, Origin::Job | Origin::Cancelled) {
            self.may_have_moved(&flight.request);
        }
        // (A stand-in for an owed stop is not resent: the owed axis is offline, and its next
        // probe is the next try.)
        let may_retry = flight.attempt < self.config.retries
            && !flight.stands_in
            && flight.request.command.resendable()
            && !matches!(
                flight.origin,
                Origin::Probe | Origin::Rejoin | Origin::Cancelled
            );
        if may_retry {
            self.resend(flight);
            return;
        }
        self.axes[axis].last_error = Some(LinkError::Timeout);
        match flight.origin {
            Origin::Probe => self
                .schedule
                .probe_failed(now, axis, self.config.probe_interval),
            Origin::Cancelled => {}
            Origin::Poll | Origin::Position => {
                self.set_link(now, axis, Link::Offline);
            }
            Origin::Job => {
                let error = if matches!(flight.request.command, Command::MoveRelative(_)) {
                    // It may have moved: never resend; the job reads where it is
                    // (`fail_job`).
                    JobError::OutcomeUnknown
                } else {
                    JobError::Timeout
                };
                self.fail_job(axis, error);
                if flight.request.command.resendable() {
                    // 1 + Nrt time-outs in a row: the axis is gone. (After one lost answer to a
                    // command that may not be resent, the next poll decides.)
                    self.set_link(now, axis, Link::Offline);
                }
            }
            Origin::Stop(id) => {
                self.job_failed(id, axis, JobError::Timeout);
                self.set_link(now, axis, Link::Offline);
                // Not given up: owed until the axis answers one (counted once per debt).
                if !self.owed.contains(axis) {
                    self.bus.stops_owed = self.bus.stops_owed.wrapping_add(1);
                }
                self.owed = self.owed.with(axis);
            }
            Origin::Establish => {
                self.set_link(now, axis, Link::Offline);
                self.establish_next_axis(axis);
            }
            Origin::Rejoin => self.abort_rejoin(),
        }
    }

    /// Send a failed attempt again, by the rules of §5: a W4 goes back to its T4 first (the
    /// write address may have moved on), a stop keeps its own slot.
    fn resend(&mut self, flight: InFlight) {
        let axis = flight.request.axis;
        let attempt = flight.attempt.saturating_add(1);
        let is_w4 = matches!(flight.request.command, Command::WriteMemory { .. });
        match flight.origin {
            Origin::Job => {
                let Some(active) = self.active[axis].as_mut() else {
                    return;
                };
                active.attempt = attempt;
                if is_w4 {
                    // A W4 whose T4 is not the op before it cannot be resent.
                    let t4_before = active
                        .cursor
                        .checked_sub(1)
                        .and_then(|c| program(&active.job, usize::from(c)))
                        .is_some_and(|op| {
                            matches!(op, Op::Send(step) if matches!(step.request.command, Command::SetWriteAddress { .. }))
                        });
                    if !t4_before {
                        self.fail_job(axis, JobError::Timeout);
                        return;
                    }
                    active.cursor = active.cursor.saturating_sub(1);
                }
            }
            Origin::Establish if is_w4 => self.establish_rewind(),
            // Stops keep their own resend: the shared slot may hold another one.
            Origin::Stop(id) => self.requeue_stop(axis, id, attempt),
            _ => self.retry = Some((flight.request, flight.origin, attempt)),
        }
    }
}
