//! Every candidate frame the engine's deframer produced: the counter it must change, and for
//! an accepted answer, where on the wire it came from.

use protocol::memory::PNOW;
use protocol::time::Instant;
use protocol::{Command, Error, Frame, Reply};

use crate::driver::Soak;
use crate::transactions::{snap, Acceptance, End};
use crate::wire::Rx;
use crate::FRAME_LEN;

impl Soak {
    pub(crate) fn on_candidate(&mut self, at: u64, outcome: Result<Frame, Error>) {
        for r in self.replies.iter_mut().skip(self.open_from) {
            if r.start < at && at <= r.end {
                r.noticed = true;
            }
        }
        let (len, what) = match &outcome {
            Ok(_) => (FRAME_LEN, "valid frame"),
            Err(Error::Truncated { len }) => (usize::from(*len) + 1, "truncated"),
            Err(Error::BadBcc { .. }) => (FRAME_LEN, "bad BCC"),
            Err(_) => (FRAME_LEN, "malformed"),
        };
        let window = self.window(len.min(FRAME_LEN));
        // (A truncated candidate is traced with the STX that cut it.)
        let traced = &window[..];
        let reply = outcome.as_ref().ok().map(Reply::parse);

        // The engine's view: in flight (per the model) and the counters.
        let in_flight = self.cur.as_ref().is_some_and(|c| !c.engine_ended);
        let unsolicited = self.h.engine.bus_counters().unsolicited;
        let d_unsol = unsolicited.wrapping_sub(self.unsolicited);
        self.unsolicited = unsolicited;
        if !in_flight {
            if d_unsol != 1 {
                self.violation(
                    "candidate without transaction not counted unsolicited",
                    what.into(),
                );
            }
            *self
                .tally
                .candidates
                .entry(if outcome.is_ok() {
                    "unsolicited: valid frame"
                } else {
                    "unsolicited: broken candidate"
                })
                .or_default() += 1;
            if outcome.is_err() && self.trace(traced) == "pieces of intact replies" {
                let d = self.describe(traced, &outcome);
                self.violation(
                    "broken candidate without a fault",
                    format!("unsolicited: {d}"),
                );
            }
            self.check_all_axes("unsolicited candidate");
            return;
        }
        let (a, request, seq, earliest, deadline) = {
            let c = self.cur.as_ref().unwrap();
            (c.axis, c.request, c.seq, c.earliest, c.deadline)
        };
        let i = usize::from(a.get());
        let before = self.snaps[i].counters;
        let after = self.h.engine.axis(a).counters;
        if d_unsol == 1 {
            // The engine had already ended the attempt: legitimate only after a corrupted answer.
            if self.cur.as_ref().unwrap().bcc_end_at.is_none() {
                self.violation(
                    "attempt ended without reply, time-out or corrupted answer",
                    format!("{request:?}: a later {what} counted unsolicited"),
                );
            }
            self.cur.as_mut().unwrap().engine_ended = true;
            self.check_all_axes("candidate after end");
            return;
        }
        let answers = matches!(&reply, Some(Ok(r)) if r.answers(&request).is_ok());
        // A frame complete before `earliest` (command, RTIM, answer on the wire) cannot be the
        // answer, valid as it may be: it is a late answer to an earlier command. The engine may
        // reject it (as bad_replies); accepting it is a violation.
        let impossible = at < earliest;
        if answers && !(impossible && after.replies == before.replies) {
            if impossible {
                self.violation(
                    "accepted an answer complete before the command could be answered",
                    format!("{request:?}: ended at {at}, earliest possible {earliest}"),
                );
            }
            if after.replies != before.replies.wrapping_add(1) {
                self.violation(
                    "valid answer in time not accepted",
                    format!("{request:?} at {at}"),
                );
                self.check_all_axes("answer not accepted");
                return;
            }
            if at > deadline {
                self.violation("accepted after Trt", format!("{request:?} at {at}"));
            }
            let Some(Ok(reply)) = reply else {
                unreachable!()
            };
            self.accept(at, &reply, &window, seq, earliest);
            return;
        }
        if after.replies != before.replies {
            // The engine took a frame that is not a valid answer to the request in flight.
            let why = match &reply {
                Some(Ok(r)) if r.axis() != request.axis => "from another axis",
                Some(Ok(_)) => "echoing another command",
                Some(Err(_)) => "that does not parse",
                None => "that failed validation",
            };
            self.violation(
                "accepted a frame that does not answer the request",
                format!("{what} {why} while {request:?} in flight"),
            );
            if let Some(Ok(reply)) = reply {
                self.accept(at, &reply, &window, seq, earliest);
            } else {
                self.snaps[i] = snap(&self.h.engine, a);
                self.resolve(End::Accepted(Acceptance::Altered));
            }
            return;
        }
        let bcc = matches!(outcome, Err(Error::BadBcc { .. }));
        let (counted, name) = if bcc {
            (
                after.bcc_errors == before.bcc_errors.wrapping_add(1),
                "bcc_errors",
            )
        } else {
            (
                after.bad_replies == before.bad_replies.wrapping_add(1),
                "bad_replies",
            )
        };
        if !counted {
            self.violation(
                "candidate not counted as the rules say",
                format!("{what} while {request:?} in flight: expected {name} + 1"),
            );
        }
        let cause = self.trace(traced);
        if outcome.is_err() && cause == "pieces of intact replies" {
            let d = self.describe(traced, &outcome);
            self.violation(
                "broken candidate without a fault",
                format!("{request:?}: {d}"),
            );
        }
        let key = match (bcc, outcome.is_ok(), cause) {
            (true, _, "altered reply") => "bcc_errors: altered reply",
            (true, _, _) => "bcc_errors: noise or collision debris",
            (false, true, "intact frame answering something else") => {
                "bad_replies: intact late/foreign reply"
            }
            (false, true, _) => "bad_replies: altered frame with a valid BCC",
            (false, false, "altered reply") => "bad_replies: altered reply",
            (false, false, _) => "bad_replies: noise or collision debris",
        };
        *self.tally.candidates.entry(key).or_default() += 1;
        if outcome.is_ok() && self.intact_source(&window).is_none() {
            self.tally.altered_valid_on_wire += 1;
        }
        self.snaps[i].counters.bcc_errors = after.bcc_errors;
        self.snaps[i].counters.bad_replies = after.bad_replies;
        if bcc && at >= earliest {
            if let Some(c) = self.cur.as_mut() {
                c.bcc_end_at.get_or_insert(at);
            }
        }
        self.check_all_axes("rejected candidate");
    }

    /// The engine accepted `reply` (completed at `at`) for the transaction in flight.
    fn accept(&mut self, at: u64, reply: &Reply, window: &[Rx], seq: u64, earliest: u64) {
        let cur = self.cur.as_ref().unwrap();
        let (a, request) = (cur.axis, cur.request);
        let i = usize::from(a.get());
        let kind = match self.intact_source(window) {
            Some(index) => {
                let (from, txn) = (self.replies[index].axis, self.replies[index].txn);
                if from != a {
                    self.violation(
                        "frame accepted for the wrong axis",
                        format!("{request:?} answered by {from:?}'s intact reply"),
                    );
                }
                if txn == Some(seq) {
                    Acceptance::Fresh
                } else {
                    Acceptance::Stale
                }
            }
            None => {
                self.tally.altered_valid_on_wire += 1;
                if self.details.len() < 40 {
                    self.details.push(format!(
                        "note t={at}: accepted an altered frame with a valid BCC for {request:?}: \
                         {:02X?}",
                        window.iter().map(|rx| rx.byte).collect::<Vec<_>>()
                    ));
                }
                Acceptance::Altered
            }
        };
        self.tally.accepted[kind as usize] += 1;
        if kind == Acceptance::Stale {
            *self
                .tally
                .stale_by_command
                .entry(request.command.mnemonic())
                .or_default() += 1;
            if at < earliest {
                self.tally.accepted_early += 1;
            }
        }
        // The engine's new knowledge must be the frame's, and only for this axis.
        let new = snap(&self.h.engine, a);
        let old = self.snaps[i];
        if new.report_at != old.report_at || new.report != old.report {
            if reply.report().copied() != new.report || new.report_at != Some(Instant(at)) {
                self.violation(
                    "status not from the accepted frame",
                    format!(
                        "{request:?}: {:?} vs frame {:?}",
                        new.report,
                        reply.report()
                    ),
                );
            }
        } else if reply.report().is_some() {
            self.violation("accepted status not recorded", format!("{request:?}"));
        }
        if new.position_at != old.position_at || new.position != old.position {
            let pnow = request.command == Command::ReadMemory { address: PNOW };
            if !pnow || reply.position() != new.position || new.position_at != Some(Instant(at)) {
                self.violation(
                    "position not from the accepted frame",
                    format!(
                        "{request:?}: {:?} vs frame {:?}",
                        new.position,
                        reply.position()
                    ),
                );
            }
        }
        let mut expected = old.counters;
        expected.replies = expected.replies.wrapping_add(1);
        if let Some(code) = reply.rejection() {
            let _ = code;
            expected.rejections = new.counters.rejections;
        }
        if new.counters != expected {
            self.violation(
                "counters beyond replies changed on acceptance",
                format!("{:?} -> {:?}", old.counters, new.counters),
            );
        }
        self.snaps[i] = new;
        self.check_all_axes("acceptance");
        self.resolve(End::Accepted(kind));
    }
}
