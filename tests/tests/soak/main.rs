//! Soak: a million transactions on a faulty 16-axis bus, in virtual time, checked frame by
//! frame against what the simulated controllers really sent.
//!
//! Set-up: 16 controllers already at 115.2 kbit/s and RTIM 3 ms (stored in their non-volatile
//! memory, `ControllerConfig::stored_line`), an engine that assumes so (`Config::establish`
//! false, Nrt = 2). Faults: 1 % of the bytes corrupted in both directions, 0.5 % of the replies
//! dropped, 0.5 % sent late (21-45 ms late, changed every 250 ms: after Trt = 20 ms + RTIM +
//! one frame, so they land in a later transaction, cleanly or colliding; only a V5, with its
//! 200 ms Trt, still gets them in time), and a little line noise. A seeded PLC workload keeps
//! every axis busy: homing first, then relative moves (most of them, often two or three queued,
//! some as DirectMove), absolute moves, SetMotion, servo off/on, point writes followed by a move
//! to the point, single-field writes, point reads, stops (some of them 0-30 ms after a move, so
//! while its frame is on the wire), and alarm resets when a move to an empty point raised alarm
//! B1. After 1,000,000 frames it stops submitting and drains. `SOAK_SEED` and
//! `SOAK_TRANSACTIONS` change the seed and the length. Run with `--nocapture` for the counts.
//!
//! # The oracle
//!
//! The test drives the engine and the bus itself (the loop of `Harness::step`, byte by byte),
//! so that it sees everything between two bytes:
//!
//! * **What each controller really sent.** A controller's prepared reply
//!   (`Controller::pending_reply`: 16 bytes and the instant they go out) is read whenever a
//!   controller may have prepared or sent one (`replies_scheduled`/`replies_sent` moved). When
//!   `replies_sent` moves, the reply that was pending is the one put on the line, as it was
//!   *before* the bus corrupted it (`Bus::start_reply` corrupts a copy). The transaction in
//!   flight when it was prepared is the command it answers. So for every reply on the wire the
//!   test knows the sender, the intact bytes, start and end, and the command it answers.
//! * **What the host received.** Each byte given to `Engine::receive` is attributed to the reply
//!   whose byte slot falls on exactly that microsecond (byte k of a transmission starting at t0
//!   arrives at t0 + byte_offset(k + 1)); bytes that fit no reply are noise or collision
//!   debris. A reply arrived *intact* iff each of its 16 slots got exactly one byte, the byte
//!   sent.
//! * **What the engine saw.** A mirror `Deframer` gets the same bytes; after every byte its
//!   counters must equal the engine's (`Engine::deframer`), so its candidates are the engine's.
//!   (The engine resets its deframer at a time-out: after `poll` the difference is exactly the
//!   dropped partial candidate, and the mirror resets too.)
//!
//! Then every candidate frame must change exactly the counter the rules say, and nothing else:
//! a valid answer to the request in flight `replies`; another valid frame or a broken candidate
//! `bad_replies`/`bcc_errors` of the axis in flight; anything while nothing is in flight
//! `unsolicited`. **(1)** is checked where the engine may change what it knows about an axis:
//!
//! * `report`/`report_at`/`position`/`position_at` of an axis change only on the byte that
//!   completes a frame that passed validation (good BCC, parses, answers the request in flight:
//!   same axis, same command character), only for the axis in flight, and to the frame's values
//!   (a position only from an R4 of PNOW); a valid answer in time is always accepted;
//! * the accepted frame is traced back to the wire: it must be byte for byte a reply that
//!   controller A, the axis updated, sent intact and that ended at that very microsecond:
//!   the answer to this command (*fresh*), or an intact late answer of A to an earlier command
//!   with the same command character (*stale*: A never got the new command, so its late reply
//!   was not superseded; the protocol has no sequence numbers, so this is legitimate, counted
//!   and printed by command). The only other possibility is a frame altered on the wire into
//!   another valid frame (the BCC is an 8-bit sum: compensating errors pass it); no receiver
//!   can tell, so those are counted and printed. A frame from another controller, or one that
//!   failed validation, is a violation; so is a frame complete before the command could have
//!   been answered (command, RTIM, answer: `earliest`), which is always an earlier answer.
//!
//! **(2)** Every JobId comes back exactly once, on its axis, jobs of an axis finish in the
//! order they were submitted (a stop's cancellation finishes them all at once), none is left
//! after the drain. **(3)** Every frame the engine sends is attributed: `n` and R4 PNOW are
//! polls, `d` belongs to an outstanding stop, anything else must be a frame of the axis' active
//! job (its oldest unfinished one); every `m` transmission is counted for that job and, by its
//! exact request (distances are unique per axis among outstanding jobs), for every job it could
//! belong to. An `m` job must see exactly one `m` when its outcome says it went out (done,
//! OutcomeUnknown, a rejection, an alarm or wait time-out after it) and at most one otherwise.
//! An axis may only go offline after 1 + Nrt failed attempts in a row.
//!
//! **(4)** Counters. Each transaction ends exactly once: answered, timed out, or (engine rule)
//! ended at once by a corrupted answer. So per axis, exactly, frames_sent = replies + timeouts
//! plus the corrupted-answer ends (plus 1 if in flight at the end), and replies and timeouts
//! equal the test's own counts. Each resend follows a failed attempt of its axis: retries is at
//! most timeouts plus corrupted-answer ends, and equals the resends the test saw. Σ frames_sent
//! is the sim's host transmissions. Every injected drop, delay and host-frame corruption
//! happens inside one transaction's window (between its command and its end), so the
//! per-transaction counts add up to the sim's totals exactly. Each failed transaction is
//! explained by a fault, checked one by one: the command never reached the controller valid
//! (corrupted, or collided with a late reply) or was corrupted into another valid command, the
//! reply was dropped, late, corrupted or collided. Conversely a transaction with a fault fails
//! unless a stale or altered frame answered it. Hence failures = faulted transactions less
//! those answered anyway, and in particular Σ failures is at least the dropped replies of
//! in-flight commands less those answered anyway. Every rejected candidate is traced to an
//! altered reply, noise or collision debris, or an intact frame answering something else (a
//! late reply), never to an intact answer; every altered reply whose STX arrived is noticed (a
//! candidate ends within it); Σ (bcc_errors + bad_replies) and unsolicited equal the
//! candidates the mirror saw.
//!
//! Violations are collected and asserted after the counts are printed.

mod candidates;
mod driver;
mod job_records;
mod plc;
mod reproduce;
mod transactions;
mod wire;

use std::collections::BTreeMap;

use protocol::engine::{Counters, Event, Job, JobError, JobKind};
use protocol::line::Baud;
use protocol::{Axis, Command, Pulses};

use crate::driver::Soak;
use crate::job_records::{kind_name, result_name};
use crate::reproduce::{done, quiet, run_until_sent, stop_while_unanswered};

const MS: u64 = 1_000;
const S: u64 = 1_000_000;
const FRAME_LEN: usize = 16;
const STX: u8 = 0x02;
const BAUD: Baud = Baud::B115200;

/// Frames the engine sends before the workload stops and the run drains.
const TRANSACTIONS: u64 = 1_000_000;
const SEED: u64 = 0x50A4_0003;
const RETRIES: u8 = 2;

/// `SOAK_SEED` and `SOAK_TRANSACTIONS` override the seed and the length, to soak longer or
/// differently by hand.
fn seed() -> u64 {
    std::env::var("SOAK_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(SEED)
}

fn axis(n: usize) -> Axis {
    Axis::new(u8::try_from(n).unwrap()).unwrap()
}

#[test]
fn a_million_transactions_on_a_faulty_bus() {
    let wall = std::time::Instant::now();
    let mut soak = Soak::new();
    soak.run();
    let elapsed = wall.elapsed();
    let s = &soak;
    let stats = s.h.bus.stats().clone();

    // Per-axis counters against the test's own account of every transaction.
    let mut sum = Counters::default();
    let mut findings: Vec<String> = Vec::new();
    for n in 0..16 {
        let c = s.h.engine.axis(axis(n)).counters;
        let [accepted, timeouts, early] = s.per_axis[n];
        let open = u64::from(
            s.cur
                .as_ref()
                .is_some_and(|t| usize::from(t.axis.get()) == n),
        );
        // Every attempt ends exactly once: answered, timed out, or ended by a corrupted answer.
        if u64::from(c.frames_sent) != u64::from(c.replies) + u64::from(c.timeouts) + early + open {
            findings.push(format!(
                "axis {n}: frames_sent {} != replies {} + timeouts {} + corrupted-answer ends {early} + open {open}",
                c.frames_sent, c.replies, c.timeouts
            ));
        }
        if (u64::from(c.replies), u64::from(c.timeouts)) != (accepted, timeouts) {
            findings.push(format!(
                "axis {n}: engine replies/timeouts {}/{} vs observed {accepted}/{timeouts}",
                c.replies, c.timeouts
            ));
        }
        // Each resend follows a failed attempt of the same axis.
        if u64::from(c.retries) > timeouts + early {
            findings.push(format!("axis {n}: retries {} > failures", c.retries));
        }
        sum.frames_sent += c.frames_sent;
        sum.replies += c.replies;
        sum.timeouts += c.timeouts;
        sum.bcc_errors += c.bcc_errors;
        sum.bad_replies += c.bad_replies;
        sum.retries += c.retries;
        sum.rejections += c.rejections;
    }
    let t = &s.tally;
    let bus = s.h.engine.bus_counters();
    // Σ frames_sent: every host transmission on the sim's side is one engine frame.
    if u64::from(sum.frames_sent) != stats.host_transmissions {
        findings.push(format!(
            "Σ frames_sent {} != host transmissions {}",
            sum.frames_sent, stats.host_transmissions
        ));
    }
    // Every injected fault happened inside some transaction's window, so the per-transaction
    // deltas add up to the sim's totals exactly.
    for (name, ours, sim) in [
        (
            "host frames corrupted",
            t.host_corrupted_txns,
            stats.host_frames_corrupted,
        ),
        ("replies dropped", t.drops_in_flight, stats.replies_dropped),
        ("replies late", t.delays_in_flight, stats.replies_delayed),
    ] {
        if ours != sim {
            findings.push(format!("{name}: per transaction {ours} vs sim {sim}"));
        }
    }
    // Frames the controllers received valid and addressed to them: one per transaction whose
    // command arrived (more only if corruption turned a frame into a valid one for another axis).
    let addressed: u64 =
        s.h.bus
            .controllers()
            .map(|c| c.stats().frames_addressed)
            .sum();
    if addressed < t.cmd_received {
        findings.push(format!(
            "frames addressed {addressed} < commands received {}",
            t.cmd_received
        ));
    }
    // Failures: each is explained by a fault (checked one by one); conversely every faulted
    // transaction failed unless a stale or altered frame answered it.
    let failures = t.timeouts + t.early_ends;
    if failures + t.faulted_but_accepted != t.faulted_txns {
        findings.push(format!(
            "failures {failures} + faulted-but-answered {} != faulted transactions {}",
            t.faulted_but_accepted, t.faulted_txns
        ));
    }
    // Σ time-outs (and corrupted-answer ends) >= replies dropped while their command was in
    // flight, less those answered by a stale frame.
    if failures + t.faulted_but_accepted < t.drops_in_flight {
        findings.push("fewer failures than dropped replies".into());
    }
    // Candidates: what the engine counted equals what the mirror saw, category by category.
    let rejected: u64 = t
        .candidates
        .iter()
        .filter(|(k, _)| !k.starts_with("unsolicited"))
        .map(|(_, v)| v)
        .sum();
    let unsolicited: u64 = t
        .candidates
        .iter()
        .filter(|(k, _)| k.starts_with("unsolicited"))
        .map(|(_, v)| v)
        .sum();
    if rejected != u64::from(sum.bcc_errors) + u64::from(sum.bad_replies)
        || unsolicited != u64::from(bus.unsolicited)
    {
        findings.push(format!(
            "candidates {rejected}/{unsolicited} vs engine bcc+bad {}/{} unsolicited {}",
            sum.bcc_errors, sum.bad_replies, bus.unsolicited
        ));
    }
    if u64::from(sum.retries) != t.retries_seen {
        findings.push(format!(
            "Σ retries {} vs resends seen {}",
            sum.retries, t.retries_seen
        ));
    }
    if bus.events_lost != 0 {
        findings.push(format!("{} events lost", bus.events_lost));
    }

    // Jobs.
    let mut by_kind: BTreeMap<&'static str, BTreeMap<String, u64>> = BTreeMap::new();
    let mut unfinished = 0;
    for job in &s.jobs {
        match &job.done {
            Some(result) => {
                *by_kind
                    .entry(kind_name(&job.kind))
                    .or_default()
                    .entry(result_name(result))
                    .or_default() += 1
            }
            None => {
                unfinished += 1;
                *by_kind
                    .entry(kind_name(&job.kind))
                    .or_default()
                    .entry("UNFINISHED".into())
                    .or_default() += 1;
                if unfinished <= 3 {
                    let st = s.h.engine.axis(job.axis);
                    println!(
                        "unfinished: {:?} {:?} submitted {} link {:?} report {:?}",
                        job.axis, job.kind, job.submitted, st.link, st.report
                    );
                }
            }
        }
    }
    let m_sent: u64 = s.jobs.iter().map(|j| u64::from(j.m_sends)).sum();
    let mut lost_stops: BTreeMap<u32, u64> = BTreeMap::new();
    for job in s
        .jobs
        .iter()
        .filter(|j| j.kind == JobKind::Stop && j.done.is_none())
    {
        *lost_stops.entry(job.d_sends).or_default() += 1;
    }

    println!(
        "soak: seed {:#x}, {:.1} s wall, {:.2} h virtual",
        seed(),
        elapsed.as_secs_f64(),
        s.now() as f64 / 3.6e9
    );
    println!(
        "transactions (frames sent): {} (Σ frames_sent {}), replies {}, time-outs {}, \
         attempts ended by a corrupted answer {}, retries {}",
        s.frames, sum.frames_sent, sum.replies, sum.timeouts, t.early_ends, sum.retries
    );
    println!(
        "injected: host bytes corrupted {} ({} frames), reply bytes corrupted {} ({} replies), \
         replies dropped {}, late {}, noise bursts {} ({} bytes), collisions {} ({} bytes)",
        stats.host_bytes_corrupted,
        stats.host_frames_corrupted,
        stats.reply_bytes_corrupted,
        stats.replies_corrupted,
        stats.replies_dropped,
        stats.replies_delayed,
        stats.noise_bursts,
        stats.noise_bytes,
        stats.collisions,
        stats.collided_bytes
    );
    println!(
        "engine: bcc errors {}, bad replies {}, unsolicited {}, rejections {}, offline events {}, \
         queue full {}",
        sum.bcc_errors,
        sum.bad_replies,
        bus.unsolicited,
        sum.rejections,
        t.offline_events,
        t.queue_full
    );
    println!(
        "replies on the wire {}, arrived altered {}; altered frames with a valid BCC on the wire {}; \
         corrupted commands the controller still took as valid {}",
        t.replies_on_wire, t.replies_altered, t.altered_valid_on_wire, t.corrupted_commands_taken
    );
    println!(
        "accepted: fresh {}, stale (late answer to an earlier command) {} [{} before the earliest \
         possible answer time; by command {:?}], altered-but-valid {}",
        t.accepted[0], t.accepted[1], t.accepted_early, t.stale_by_command, t.accepted[2]
    );
    println!(
        "commands received valid by their axis {} of {}, frames addressed at the controllers {}, \
         deframer resets {}",
        t.cmd_received, s.frames, addressed, t.deframer_resets
    );
    println!("failed transactions by cause: {:?}", t.causes);
    println!("rejected candidates by cause: {:?}", t.candidates);
    println!(
        "jobs: {} submitted, {} unfinished, m transmissions {m_sent}",
        s.jobs.len(),
        unfinished
    );
    for (kind, results) in &by_kind {
        println!("  {kind}: {results:?}");
    }
    if !lost_stops.is_empty() {
        println!(
            "unfinished stops by `d` transmissions on their axis while outstanding: {lost_stops:?}"
        );
    }
    for d in &s.details {
        println!("  {d}");
    }
    println!("violations: {:?}", s.violations);
    println!("findings: {findings:?}");

    assert!(
        unfinished == 0 && findings.is_empty() && s.violations.is_empty(),
        "{unfinished} jobs never finished (by kind above); counter findings {findings:#?}; \
         violations {:#?}",
        s.violations
    );
}

// ------------------------------------------------------------------------------ reproductions
//
// Minimal, fault-free reproductions of what the soak found, with a silent axis (it executes
// commands but never answers) standing in for a lost answer.

/// Engine bug: a job frame in flight when a stop cancels its job becomes a poll
/// (`cancel_jobs`: `origin = Origin::Poll`), and a poll that times out is resent: the `a` goes
/// out again after the `d`, and the axis drives on to the cancelled target.
#[test]
fn a_move_cancelled_while_its_answer_is_lost_is_not_resent_after_the_stop() {
    let target = Pulses(-8_000);
    let (h, sent, _) = stop_while_unanswered(Command::MoveAbsolute(target));
    let resent: Vec<_> = h.sent[sent..]
        .iter()
        .filter(|(_, r)| r.command == Command::MoveAbsolute(target))
        .collect();
    let c = h.bus.controller(axis(0)).unwrap();
    assert!(
        resent.is_empty(),
        "the cancelled move went out again after the stop: {resent:?}; the axis is at {} \
         (target {}), moving {}",
        c.position(),
        target.0,
        c.moving()
    );
    assert!(c.position() > -7_000, "stopped short of the target");
}

/// Engine bug, same cause: the lost answer of a cancelled `m` (not resendable) fails the
/// "poll" it became, and a failed poll takes the axis offline after one lost answer.
#[test]
fn a_lost_answer_to_a_cancelled_m_does_not_take_the_axis_offline() {
    let (h, _, events) = stop_while_unanswered(Command::MoveRelative(Pulses(-3_000)));
    let offline: Vec<_> = h.events[events..]
        .iter()
        .filter(|(_, e)| matches!(e, Event::Offline(_)))
        .collect();
    assert!(
        offline.is_empty(),
        "one lost answer took the axis offline: {offline:?}"
    );
}

/// Engine bug: stops go before the resend slot, and a stop that needs a resend takes the slot
/// (`self.retry = Some(..)`) even when another stop's resend is waiting in it: that stop is never
/// sent again and never finishes (no JobDone).
#[test]
fn a_stop_waiting_for_its_resend_is_not_lost_behind_another_axis_stop() {
    let mut h = quiet(2);
    for n in 0..2 {
        h.bus.set_silent(axis(n), true);
    }
    let first = h
        .engine
        .submit(Job {
            axis: axis(0),
            kind: JobKind::Stop,
        })
        .unwrap();
    run_until_sent(&mut h, |r| {
        r.axis == axis(0) && r.command == Command::CancelMotion
    });
    // While the first `d` waits for its (lost) answer, stop the other axis.
    let second = h
        .engine
        .submit(Job {
            axis: axis(1),
            kind: JobKind::Stop,
        })
        .unwrap();
    h.run_until(h.now + 2 * S);
    let d0 = h
        .sent
        .iter()
        .filter(|(_, r)| r.axis == axis(0) && r.command == Command::CancelMotion)
        .count();
    assert_eq!(done(&h, second), Some(Err(JobError::Timeout)));
    assert_eq!(
        done(&h, first),
        Some(Err(JobError::Timeout)),
        "the first stop never finished; its `d` went out {d0} time(s) (1 + Nrt = 3 expected)"
    );
}
