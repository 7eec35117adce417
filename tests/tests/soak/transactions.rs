//! Transactions: how each one ended, what the engine knew about an axis, and the checks when
//! a transaction ends or an axis goes offline.

use protocol::engine::{Counters, Engine, Link};
use protocol::time::Instant;
use protocol::{Axis, Command, Pulses, Request, StatusReport};

use crate::driver::Soak;
use crate::RETRIES;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Acceptance {
    /// The answer to this very command, intact.
    Fresh,
    /// An intact late answer of the same controller to an earlier command.
    Stale,
    /// A frame altered on the wire that still has a valid BCC (undetectable).
    Altered,
}

/// How a transaction ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum End {
    Accepted(Acceptance),
    /// No valid answer within Trt.
    Timeout,
    /// Ended before Trt by a corrupted answer (or, a violation, by nothing).
    Corrupted,
}

pub(crate) struct Txn {
    pub(crate) seq: u64,
    pub(crate) axis: Axis,
    pub(crate) request: Request,
    pub(crate) start: u64,
    pub(crate) deadline: u64,
    pub(crate) earliest: u64,
    pub(crate) host_corrupted: bool,
    pub(crate) sched0: u64,
    pub(crate) drop0: u64,
    pub(crate) delay0: u64,
    pub(crate) coll0: u64,
    /// A bad-BCC candidate ended at or after `earliest` while in flight: the engine may end the
    /// attempt there ("a corrupted response ends the attempt at once").
    pub(crate) bcc_end_at: Option<u64>,
    /// The engine no longer has it in flight (it counted the next candidate as unsolicited).
    pub(crate) engine_ended: bool,
}

/// What the test knows the engine knew about an axis.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) struct Snap {
    pub(crate) counters: Counters,
    pub(crate) report: Option<StatusReport>,
    pub(crate) report_at: Option<Instant>,
    pub(crate) position: Option<Pulses>,
    pub(crate) position_at: Option<Instant>,
    pub(crate) link: Link,
}

pub(crate) fn snap(engine: &Engine, a: Axis) -> Snap {
    let s = engine.axis(a);
    Snap {
        counters: s.counters,
        report: s.report,
        report_at: s.report_at,
        position: s.position,
        position_at: s.position_at,
        link: s.link,
    }
}

impl Soak {
    /// The transaction in flight is over: accepted (with how), or failed.
    pub(crate) fn resolve(&mut self, end: End) {
        let Some(cur) = self.cur.take() else {
            return;
        };
        let a = cur.axis;
        let i = usize::from(a.get());
        let stats = self.h.bus.stats();
        let dropped = stats.replies_dropped - cur.drop0;
        let delayed = stats.replies_delayed - cur.delay0;
        let collided = stats.collisions > cur.coll0;
        let got_cmd = self
            .h
            .bus
            .controller(a)
            .is_some_and(|c| c.stats().replies_scheduled > cur.sched0);
        self.tally.drops_in_flight += dropped;
        self.tally.delays_in_flight += delayed;
        self.tally.cmd_received += u64::from(got_cmd);
        self.tally.corrupted_commands_taken += u64::from(got_cmd && cur.host_corrupted);
        // How the fresh answer (this command's) arrived, if it was sent.
        let fresh = self
            .replies
            .iter()
            .rev()
            .take(8)
            .find(|r| r.txn == Some(cur.seq) && r.axis == a)
            .map(|r| (r.start, r.end, r.finished, r.altered));
        let fresh_altered = fresh.is_some_and(|(_, _, finished, altered)| finished && altered);
        // Why the controller's answer did not make it back intact and in time (a V5 answer
        // delayed by 21-45 ms still comes within its 200 ms Trt: no fault).
        let cause = if end == End::Accepted(Acceptance::Fresh) {
            None
        } else if end == End::Accepted(Acceptance::Altered) {
            Some("reply altered into another valid frame")
        } else if !got_cmd {
            Some(if cur.host_corrupted {
                "command corrupted"
            } else if collided {
                "command collided with a late reply"
            } else {
                "command lost without corruption or collision"
            })
        } else if cur.host_corrupted {
            // Corrupted into another valid frame for this axis: it answered something else.
            Some("command corrupted into another valid command")
        } else if dropped > 0 {
            Some("reply dropped")
        } else if delayed > 0 {
            Some("reply late")
        } else if fresh_altered {
            Some(if collided {
                "reply collided"
            } else {
                "reply corrupted"
            })
        } else if end == End::Corrupted && fresh.is_none_or(|(_, end, ..)| end > self.h.now) {
            // Its answer was still to come (a V5 answers after its store time): the corrupted
            // frame that ended the attempt was someone else's.
            Some("ended by another talker's corrupted frame before the answer")
        } else {
            None
        };
        if cause == Some("ended by another talker's corrupted frame before the answer") {
            let (r, t) = (cur.request, cur.bcc_end_at);
            self.violation(
                "attempt ended by another talker's corrupted frame while its answer was coming",
                format!("{r:?} sent at {}, bad frame at {t:?}", cur.start),
            );
        }
        if cause.is_some() {
            self.tally.faulted_txns += 1;
        }
        match end {
            End::Accepted(kind) => {
                self.per_axis[i][0] += 1;
                if cause.is_some() {
                    self.tally.faulted_but_accepted += 1;
                } else if kind != Acceptance::Fresh {
                    let r = cur.request;
                    self.violation(
                        "stale or altered answer without a fault",
                        format!("{r:?}: got_cmd {got_cmd} dropped {dropped} delayed {delayed}"),
                    );
                }
            }
            End::Timeout | End::Corrupted => {
                if end == End::Timeout {
                    self.per_axis[i][1] += 1;
                    self.tally.timeouts += 1;
                } else {
                    self.per_axis[i][2] += 1;
                    self.tally.early_ends += 1;
                }
                match cause {
                    Some("command lost without corruption or collision") | None => {
                        let r = cur.request;
                        let f = fresh;
                        let c = self.h.bus.controller(a).map(|c| c.stats().clone());
                        self.violation(
                            "unexplained failed transaction",
                            format!(
                                "{r:?} sent at {}, {end:?} at {}, earliest {}, bcc end {:?}, \
                                 fresh {f:?}, controller {c:?}",
                                cur.start, self.h.now, cur.earliest, cur.bcc_end_at
                            ),
                        );
                    }
                    Some(c) => *self.tally.causes.entry(c).or_default() += 1,
                }
            }
        }
        let history = &mut self.history[i];
        history.push_back((cur.request, !matches!(end, End::Accepted(_))));
        if history.len() > 16 {
            history.pop_front();
        }
    }

    /// An axis went offline: its last 1 + Nrt attempts must have failed (a poll and its resends,
    /// a resendable job frame and its resends, a stop and its resends), never after a single
    /// lost answer. Answered frames that may legitimately come between the attempts of one
    /// request do not break the run: a W4 is resent after its T4 (and counts its attempts across
    /// both), and a newer stop's `d` goes before an older stop's resend.
    pub(crate) fn check_offline(&mut self, a: Axis) {
        let history = &self.history[usize::from(a.get())];
        let mut run = 0;
        for (request, failed) in history.iter().rev() {
            if *failed {
                run += 1;
            } else if !matches!(
                request.command,
                Command::SetWriteAddress { .. } | Command::CancelMotion
            ) {
                break;
            }
        }
        if run < 1 + usize::from(RETRIES) {
            let last = history.back().map(|(r, _)| *r);
            let kind = match last.and_then(|r| self.cancelled_owner(&r)) {
                Some(_) => "offline after one lost answer to a cancelled job's frame",
                None => "offline after fewer than 1 + Nrt failed attempts",
            };
            let recent: Vec<String> = history
                .iter()
                .rev()
                .take(5)
                .map(|(r, f)| {
                    format!(
                        "{}{}",
                        r.command.mnemonic(),
                        if *f { " failed" } else { "" }
                    )
                })
                .collect();
            self.violation(
                kind,
                format!("{a:?}: {run} failed attempt(s) in a row, the last {last:?}; newest first: {recent:?}"),
            );
        }
    }
}
