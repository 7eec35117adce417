//! Bytes from the line through the deframer and both parsers.
//!
//! The first input byte is a control byte; the rest is the byte stream. Every delivered frame is
//! parsed as a request and as a reply, and every successful parse must be canonical (emitting
//! it gives back the same frame) and round-trip. The raw input is also tried directly: every
//! 16-byte window with `Frame::new_checked`, every 14-byte window with `Frame::from_text`, and
//! every 12-byte chunk as frame data, so the parsers are reached without a valid BCC.
//!
//! Echo suppression: when control bit 0 is set, a 0x01 byte in the stream is not fed to the
//! deframer but makes it expect the echo of the last frame delivered (or, before any, of a
//! status request to the axis in the control byte's high nibble). Feeding that frame's 16
//! bytes again then exercises the echo path, and anything else the mismatch path.
#![no_main]

use libfuzzer_sys::fuzz_target;
use protocol::frame::FRAME_LEN;
use protocol::{Axis, Command, Deframer, Error, Frame, Packet, Reply, Request};

const ECHO_TRIGGER: u8 = 0x01;

fuzz_target!(|data: &[u8]| {
    let Some((&control, stream)) = data.split_first() else {
        return;
    };
    deframe(control, stream);
    for window in data.windows(FRAME_LEN) {
        if let Ok(frame) = Frame::new_checked(window) {
            assert_eq!(&frame.to_bytes()[..], window);
            check_frame(&frame);
        }
    }
    for window in data.windows(FRAME_LEN - 2) {
        if let Ok(frame) = Frame::from_text(window) {
            assert_eq!(&frame.to_text()[..], window);
            check_frame(&frame);
        }
    }
    for chunk in data.chunks_exact(12) {
        let frame = Frame::from_data(chunk.try_into().unwrap());
        check_frame(&frame);
    }
    // Whole-input calls, whatever the length.
    if let Ok(frame) = Frame::new_checked(data) {
        check_frame(&frame);
    }
    if let Ok(frame) = Frame::from_text(data) {
        check_frame(&frame);
    }
});

fn deframe(control: u8, stream: &[u8]) {
    let echo_enabled = control & 1 != 0;
    let axis = Axis::new(control >> 4).unwrap();
    let mut last_sent = Request::new(axis, Command::Status).emit().to_bytes();
    let mut deframer = Deframer::new();
    let mut echoes_expected = 0u32;
    for &byte in stream {
        if echo_enabled && byte == ECHO_TRIGGER {
            deframer.expect_echo(&last_sent);
            echoes_expected += 1;
            assert!(deframer.echo_pending());
            continue;
        }
        let before = deframer.counters();
        match deframer.push(byte) {
            Ok(Packet::Frame(frame)) => {
                assert_eq!(deframer.counters().packets, before.packets.wrapping_add(1));
                check_frame(&frame);
                last_sent = frame.to_bytes();
            }
            Ok(Packet::CommChange) => {
                assert_eq!(deframer.counters().packets, before.packets.wrapping_add(1));
            }
            Err(protocol::nb::Error::WouldBlock) => {
                assert_eq!(deframer.counters().packets, before.packets);
                assert_eq!(deframer.counters().errors, before.errors);
            }
            Err(protocol::nb::Error::Other(error)) => {
                assert_eq!(deframer.counters().errors, before.errors.wrapping_add(1));
                let _ = format!("{error} {error:?}");
                let rejected = deframer.rejected();
                assert!(!rejected.is_empty() && rejected.len() <= FRAME_LEN);
                match error {
                    Error::Truncated { len } => assert_eq!(usize::from(len), rejected.len()),
                    _ => {
                        assert_eq!(rejected.len(), FRAME_LEN);
                        assert!(Frame::new_checked(rejected).is_err());
                    }
                }
            }
        }
    }
    let counters = deframer.counters();
    let echo_outcomes = counters.echoes + counters.echo_mismatches;
    // Every expected echo ends as swallowed, mismatched, superseded by the next expect_echo,
    // or still pending.
    assert!(
        echo_outcomes <= echoes_expected,
        "{counters:?} of {echoes_expected}"
    );
    deframer.reset();
    assert!(!deframer.echo_pending());
}

/// Whatever parses is a valid value, canonical (its frame is the one parsed) and round-trips.
fn check_frame(frame: &Frame) {
    assert_eq!(Frame::new_checked(&frame.to_bytes()), Ok(*frame));
    assert_eq!(Frame::from_text(&frame.to_text()), Ok(*frame));
    let _ = format!("{frame:?}");
    match Request::parse(frame) {
        Ok(request) => {
            assert_eq!(request.emit(), *frame, "{request:?} is not canonical");
            assert_eq!(Request::parse(&request.emit()), Ok(request));
            if let Command::Buffer(buffered) = request.command {
                let inner = buffered
                    .command()
                    .expect("a parsed h holds a valid command");
                assert!(inner.bufferable(), "h carries {inner:?}");
            }
            let _ = (request.command.moves(), request.command.resendable());
            let _ = format!("{request:?}");
            // A request is never a reply.
            assert!(Reply::parse(frame).is_err());
        }
        Err(error) => {
            let _ = format!("{error} {error:?}");
        }
    }
    match Reply::parse(frame) {
        Ok(reply) => {
            assert_eq!(reply.emit(), *frame, "{reply:?} is not canonical");
            assert_eq!(Reply::parse(&reply.emit()), Ok(reply));
            if let Reply::Status { code, report, .. } = reply {
                if code.memory_function_number().is_some() {
                    assert!(report.rejected(), "{reply:?}: memory code, not rejected");
                }
            }
            let _ = reply.rejection().map(|alarm| (alarm.text(), alarm.level()));
            let _ = (reply.memory_value(), reply.position());
            let _ = format!("{reply:?}");
        }
        Err(error) => {
            let _ = format!("{error} {error:?}");
        }
    }
}
