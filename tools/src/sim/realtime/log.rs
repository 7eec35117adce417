//! The frame log on standard error ([`Options::log`](super::Options::log)): both directions
//! decoded.

use protocol::frame::{Frame, Packet};
use protocol::{Deframer, Reply, Request};

/// Decodes both directions for [`Options::log`](super::Options::log).
#[derive(Clone, Debug, Default)]
pub(super) struct FrameLog {
    from_master: Deframer,
    to_master: Deframer,
}

impl FrameLog {
    pub(super) fn host(&mut self, now: u64, bytes: &[u8]) {
        for &byte in bytes {
            let line = describe(&mut self.from_master, byte, |frame| {
                Request::parse(frame).map(|r| format!("{r:?}"))
            });
            if let Some(line) = line {
                eprintln!("{} >> {line}", stamp(now));
            }
        }
    }

    pub(super) fn master(&mut self, received: &[(u64, u8)]) {
        for &(at, byte) in received {
            let line = describe(&mut self.to_master, byte, |frame| {
                Reply::parse(frame).map(|r| format!("{r:?}"))
            });
            if let Some(line) = line {
                eprintln!("{} << {line}", stamp(at));
            }
        }
    }
}

fn describe(
    deframer: &mut Deframer,
    byte: u8,
    parse: impl Fn(&Frame) -> Result<String, protocol::Error>,
) -> Option<String> {
    match deframer.push(byte) {
        Ok(Packet::CommChange) => Some("communication-change broadcast".into()),
        Ok(Packet::Frame(frame)) => Some(match parse(&frame) {
            Ok(text) => text,
            Err(e) => format!("{frame:?}: {e:?}"),
        }),
        Err(protocol::nb::Error::WouldBlock) => None,
        Err(protocol::nb::Error::Other(e)) => Some(format!(
            "bad frame {:?}: {e:?}",
            String::from_utf8_lossy(deframer.rejected())
        )),
    }
}

/// Virtual time as seconds with µs.
pub(super) fn stamp(us: u64) -> String {
    format!("{:>4}.{:06}", us / 1_000_000, us % 1_000_000)
}
