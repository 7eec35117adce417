//! The wire as the test sees it: the replies controllers prepared and put on the line, the
//! bytes the host received and which reply slot each one filled.

use protocol::nb;
use protocol::time::Instant;
use protocol::{Axis, Error, Frame, Packet};
use rc_tools::sim::wire::transmit_time;

use crate::driver::Soak;
use crate::{axis, BAUD, FRAME_LEN, S};

/// A reply a controller prepared (not yet on the line).
#[derive(Clone, Copy)]
pub(crate) struct Pending {
    at: u64,
    bytes: [u8; FRAME_LEN],
    /// The transaction in flight when it was scheduled: the command it answers.
    txn: Option<u64>,
}

/// A reply a controller put on the line, and how it arrived.
pub(crate) struct SentReply {
    pub(crate) axis: Axis,
    pub(crate) start: u64,
    pub(crate) end: u64,
    /// As sent, before the bus corrupted anything.
    pub(crate) bytes: [u8; FRAME_LEN],
    pub(crate) txn: Option<u64>,
    /// Bytes the host received in this reply's slots.
    pub(crate) got: [u8; FRAME_LEN],
    pub(crate) got_mask: u32,
    /// Two bytes arrived in one slot (another talker at the same microsecond).
    pub(crate) clash: bool,
    /// A candidate frame (good or bad) ended while this reply was on the line.
    pub(crate) noticed: bool,
    /// The engine reset its deframer while this reply was on the line.
    pub(crate) reset_during: bool,
    pub(crate) finished: bool,
    pub(crate) altered: bool,
}

impl SentReply {
    fn intact_so_far(&self, k: usize) -> bool {
        !self.clash && self.got.get(k) == self.bytes.get(k) && self.got_mask & (1 << k) != 0
    }
}

/// A byte the host received, and which reply slot it filled.
#[derive(Clone, Copy, Default)]
pub(crate) struct Rx {
    pub(crate) byte: u8,
    /// (reply id, byte index)
    tag: Option<(u64, usize)>,
}

impl Soak {
    /// Read every controller's prepared reply: record those that went on the line, and tag new
    /// ones with the transaction in flight.
    pub(crate) fn scan_controllers(&mut self, now: u64) {
        let txn = self.cur.as_ref().map(|c| c.seq);
        for n in 0..16 {
            let Some(c) = self.h.bus.controller(axis(n)) else {
                continue;
            };
            let (sched, sent) = (c.stats().replies_scheduled, c.stats().replies_sent);
            let pending = c.pending_reply().copied();
            if sent != self.sent_seen[n] {
                match self.pending[n].take() {
                    Some(p) if sent == self.sent_seen[n] + 1 && p.at <= now => {
                        self.next_reply_id += 1;
                        self.replies.push_back(SentReply {
                            axis: axis(n),
                            start: p.at,
                            end: p.at + transmit_time(FRAME_LEN, BAUD),
                            bytes: p.bytes,
                            txn: p.txn,
                            got: [0; FRAME_LEN],
                            got_mask: 0,
                            clash: false,
                            noticed: false,
                            reset_during: false,
                            finished: false,
                            altered: false,
                        });
                        self.tally.replies_on_wire += 1;
                    }
                    other => {
                        let detail = format!(
                            "axis {n}: mirror {:?}, pending now {:?}, sent {sent} seen {}, sched {sched} seen {}, host busy until {}",
                            other.map(|p| (p.at, p.txn)),
                            pending.map(|p| p.at),
                            self.sent_seen[n],
                            self.sched_seen[n],
                            self.h.bus.host_busy_until()
                        );
                        self.violation("reply sent that was not pending", detail)
                    }
                }
                self.sent_seen[n] = sent;
            }
            if sched != self.sched_seen[n] {
                self.sched_seen[n] = sched;
                self.pending[n] = pending.map(|p| Pending {
                    at: p.at,
                    bytes: p.bytes,
                    txn,
                });
            } else if pending.map(|p| (p.at, p.bytes)) != self.pending[n].map(|p| (p.at, p.bytes)) {
                // Cancelled (a break or power loss; neither happens here) or sent (handled).
                self.pending[n] = pending.map(|p| Pending {
                    at: p.at,
                    bytes: p.bytes,
                    txn: None,
                });
            }
        }
        // Forget replies long gone (kept for a second for byte attribution).
        while self
            .replies
            .front()
            .is_some_and(|r| r.finished && r.end + S < now)
        {
            self.replies.pop_front();
            self.open_from -= 1;
        }
    }

    fn reply_index(&self, id: u64) -> Option<usize> {
        let front = self.next_reply_id - self.replies.len() as u64;
        id.checked_sub(front).map(|i| i as usize)
    }

    pub(crate) fn on_byte(&mut self, at: u64, byte: u8) {
        self.finish_replies(at, false);
        // Which reply slot does it fill? (Only replies still on the line can.)
        let mut tag = None;
        let front = self.next_reply_id - self.replies.len() as u64;
        for i in self.open_from..self.replies.len() {
            let r = &mut self.replies[i];
            if at <= r.start || at > r.end {
                continue;
            }
            let offset = at - r.start;
            if let Some(k) = self.offsets.iter().position(|&o| o == offset) {
                if r.got_mask & (1 << k) != 0 {
                    r.clash = true;
                }
                r.got_mask |= 1 << k;
                r.got[k] = byte;
                tag = Some((front + i as u64, k));
                break;
            }
        }
        self.ring[self.ring_pos] = Rx { byte, tag };
        self.ring_pos = (self.ring_pos + 1) % FRAME_LEN;

        let outcome = self.mirror.push(byte);
        self.h.engine.receive(Instant(at), &[byte]);
        if self.h.engine.deframer().counters() != self.mirror.counters() {
            let (e, m) = (self.h.engine.deframer().counters(), self.mirror.counters());
            self.violation("deframer diverged", format!("engine {e:?} mirror {m:?}"));
            self.mirror = self.h.engine.deframer().clone();
        }
        match outcome {
            Err(nb::Error::WouldBlock) | Ok(Packet::CommChange) => {
                if let Some(a) = self.cur.as_ref().map(|c| c.axis) {
                    let i = usize::from(a.get());
                    if self.h.engine.axis(a).counters != self.snaps[i].counters {
                        self.violation("counters changed without a candidate", format!("{a:?}"));
                        self.snaps[i].counters = self.h.engine.axis(a).counters;
                    }
                }
            }
            Ok(Packet::Frame(frame)) => self.on_candidate(at, Ok(frame)),
            Err(nb::Error::Other(error)) => self.on_candidate(at, Err(error)),
        }
    }

    /// The last `len` bytes received (oldest first).
    pub(crate) fn window(&self, len: usize) -> Vec<Rx> {
        (0..len)
            .map(|j| self.ring[(self.ring_pos + FRAME_LEN - len + j) % FRAME_LEN])
            .collect()
    }

    /// The reply a window of bytes is, intact, if it is one.
    pub(crate) fn intact_source(&self, window: &[Rx]) -> Option<usize> {
        let (id, _) = window.first()?.tag?;
        let index = self.reply_index(id)?;
        let r = self.replies.get(index)?;
        let whole = window.len() == FRAME_LEN
            && window
                .iter()
                .enumerate()
                .all(|(k, rx)| rx.tag == Some((id, k)) && r.bytes[k] == rx.byte);
        whole.then_some(index)
    }

    pub(crate) fn describe(&self, window: &[Rx], outcome: &Result<Frame, Error>) -> String {
        let parts: Vec<String> = window
            .iter()
            .map(|rx| match rx.tag {
                Some((id, k)) => {
                    let r = self.reply_index(id).and_then(|i| self.replies.get(i));
                    format!(
                        "{:02X}@{id}.{k}{}",
                        rx.byte,
                        if r.is_some_and(|r| r.intact_so_far(k)) {
                            ""
                        } else {
                            "!"
                        }
                    )
                }
                None => format!("{:02X}@-", rx.byte),
            })
            .collect();
        format!("{outcome:?} [{}]", parts.join(" "))
    }

    /// What a candidate that is not a valid answer is made of.
    pub(crate) fn trace(&self, window: &[Rx]) -> &'static str {
        let mut any_reply = false;
        for rx in window {
            if let Some((id, k)) = rx.tag {
                any_reply = true;
                let altered = self
                    .reply_index(id)
                    .and_then(|i| self.replies.get(i))
                    .is_none_or(|r| !r.intact_so_far(k));
                if altered {
                    return "altered reply";
                }
            }
        }
        if any_reply {
            if self.intact_source(window).is_some() {
                "intact frame answering something else"
            } else {
                "pieces of intact replies"
            }
        } else {
            "noise or collision debris"
        }
    }
}
