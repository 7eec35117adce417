//! Properties of the codec over every valid value and over arbitrary bytes.
//!
//! Strategies generate every [`Command`] variant and every valid [`Reply`] over the full range of
//! each field; the properties check that encoding and decoding are inverse, that decoding is
//! canonical (a frame that parses is exactly the frame its value emits), that nothing panics on
//! arbitrary input, that the BCC catches every single-byte substitution, that
//! [`Reply::answers`] follows the §5 rules, and that the unit conversions round-trip within
//! their resolution.
//!
//! Lengths are in 0.01 mm and speeds in 0.01 mm/s, so `Length(56_80)` reads as 56.80 mm.
#![allow(clippy::inconsistent_digit_grouping)]

mod codec;
mod strategies;
mod units;

use protocol::frame::Frame;
use protocol::*;

// ---------------------------------------------------------------- helpers

/// Exercise everything a caller does with a parsed reply; must never panic.
fn use_reply(reply: &Reply) {
    // A memory code answers in the direct format only when rejected (§4-3).
    if let Reply::Status { code, report, .. } = reply {
        if code.memory_function_number().is_some() {
            assert!(
                report.rejected(),
                "{reply:?} is a memory reply in the direct format"
            );
        }
    }
    let _ = reply.axis();
    let _ = reply.code();
    let _ = reply.rejection().map(|a| (a.text(), a.level(), a.info()));
    let _ = reply.memory_value();
    let _ = reply.position();
    let _ = format!("{reply:?}");
    if let Some(report) = reply.report() {
        let _ = report.outputs.completed_position();
        let _ = report.outputs.abbreviated_alarm();
        let _ = report.status.set_names().count();
    }
}

/// Exercise everything a caller does with a parsed request; must never panic.
fn use_request(request: &Request) {
    let _ = request.command.moves();
    let _ = request.command.resendable();
    let _ = request.command.code();
    let _ = format!("{request:?}");
    if let Command::Buffer(b) = request.command {
        let inner = b
            .command()
            .expect("a parsed Buffered holds a valid command");
        assert!(inner.bufferable(), "a parsed h carries {inner:?}");
    }
}

/// Parse `frame` both ways; whatever parses must be canonical and round-trip.
fn check_parses(frame: &Frame) {
    if let Ok(request) = Request::parse(frame) {
        use_request(&request);
        assert_eq!(request.emit(), *frame, "{request:?} is not canonical");
        assert_eq!(Request::parse(&request.emit()), Ok(request));
    }
    if let Ok(reply) = Reply::parse(frame) {
        use_reply(&reply);
        assert_eq!(reply.emit(), *frame, "{reply:?} is not canonical");
        assert_eq!(Reply::parse(&reply.emit()), Ok(reply));
    }
}
