//! Every worked example of both vendor documents, encoded and decoded.
//!
//! Frames are written as the documents print them: the 14 characters between STX and ETX.
//! Where an example contradicts a stated rule, the test is named `*_contradicts_*`, follows the
//! rule, and says why in its comment.
//!
//! Lengths are in 0.01 mm and speeds in 0.01 mm/s, so `Length(56_80)` reads as 56.80 mm.
#![allow(clippy::inconsistent_digit_grouping)]

mod brief;
mod complete;

use protocol::frame::Frame;
use protocol::units::{Lead, Scale};
use protocol::*;

fn axis(n: u8) -> Axis {
    Axis::new(n).unwrap()
}
fn pos(n: u8) -> PositionNo {
    PositionNo::new(n).unwrap()
}
fn lead_mm(hundredths: u16) -> Lead {
    Lead::from_hundredths(hundredths).unwrap()
}
fn text(frame: Frame) -> String {
    String::from_utf8(frame.to_text().to_vec()).unwrap()
}

/// Encode `request`, compare with the document's text, and decode the text back.
fn both_ways(doc: &str, request: Request) {
    assert_eq!(text(request.emit()), doc, "encoding {request:?}");
    let frame = Frame::from_text(doc.as_bytes()).unwrap();
    assert_eq!(Request::parse(&frame).unwrap(), request, "decoding {doc}");
}

fn reply_both_ways(doc: &str, reply: Reply) {
    assert_eq!(text(reply.emit()), doc, "encoding {reply:?}");
    let frame = Frame::from_text(doc.as_bytes()).unwrap();
    assert_eq!(Reply::parse(&frame).unwrap(), reply, "decoding {doc}");
}

fn motor_end(lead: u16) -> Scale {
    Scale::new(lead_mm(lead), HomeDirection::MotorEnd)
}
