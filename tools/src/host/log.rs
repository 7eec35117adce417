//! `--log`: Modbus requests and replies, and bus frames, decoded, on standard error.

use protocol::frame::{Frame, Packet};
use protocol::{Command, Deframer, Reply, Request};

/// What is logged.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Level {
    /// Nothing.
    #[default]
    Off,
    /// Modbus traffic and bus frames, except the engine's polls (`n`, R4) and their replies.
    Commands,
    /// Everything, polls included.
    All,
}

/// Decodes what goes by for the log.
#[derive(Clone, Debug, Default)]
pub struct Log {
    level: Level,
    from_bus: Deframer,
    /// The last frame sent was a poll: its reply is not shown at [`Level::Commands`].
    poll_pending: bool,
}

/// Virtual time as seconds with µs.
pub fn stamp(us: u64) -> String {
    format!("{:>4}.{:06}", us / 1_000_000, us % 1_000_000)
}

fn hex(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:02X}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Whether a command is one of the engine's polls rather than something a job sent.
pub fn is_poll(command: &Command) -> bool {
    matches!(command, Command::Status | Command::ReadMemory { .. })
}

impl Log {
    /// A log at `level`.
    pub fn new(level: Level) -> Log {
        Log {
            level,
            ..Log::default()
        }
    }

    /// Whether anything is logged.
    pub fn on(&self) -> bool {
        self.level != Level::Off
    }

    /// A line as it is.
    pub fn note(&self, now: u64, what: &str) {
        if self.on() {
            eprintln!("{} -- {what}", stamp(now));
        }
    }

    /// A Modbus burst from the PLC and what became of it.
    pub fn modbus_request(&self, now: u64, bytes: &[u8], outcome: &str) {
        if !self.on() {
            return;
        }
        let decoded = match bytes {
            [_, pdu @ .., _, _] if !pdu.is_empty() => match protocol::modbus::Request::parse(pdu) {
                Ok(request) => format!("{request:?}"),
                Err(e) => format!("{e}"),
            },
            _ => String::new(),
        };
        eprintln!(
            "{} PLC >> [{}] {decoded} => {outcome}",
            stamp(now),
            hex(bytes)
        );
    }

    /// A Modbus reply to the PLC.
    pub fn modbus_reply(&self, now: u64, bytes: &[u8]) {
        if self.on() {
            eprintln!("{} PLC << [{}]", stamp(now), hex(bytes));
        }
    }

    /// A frame the gateway sends on the bus.
    pub fn bus_sent(&mut self, now: u64, frame: &Frame) {
        let text = match Request::parse(frame) {
            Ok(request) => {
                self.poll_pending = is_poll(&request.command);
                if self.poll_pending && self.level != Level::All {
                    return;
                }
                format!("{request:?}")
            }
            Err(e) => {
                self.poll_pending = false;
                format!("{frame:?}: {e:?}")
            }
        };
        if self.on() {
            eprintln!("{} bus >> {text}", stamp(now));
        }
    }

    /// Bytes the gateway receives from the bus.
    pub fn bus_received(&mut self, at: u64, byte: u8) {
        if !self.on() {
            return;
        }
        let text = match self.from_bus.push(byte) {
            Ok(Packet::CommChange) => "communication-change broadcast".to_string(),
            Ok(Packet::Frame(frame)) => {
                if self.poll_pending && self.level != Level::All {
                    self.poll_pending = false;
                    return;
                }
                match Reply::parse(&frame) {
                    Ok(reply) => format!("{reply:?}"),
                    Err(e) => format!("{frame:?}: {e:?}"),
                }
            }
            Err(protocol::nb::Error::WouldBlock) => return,
            Err(protocol::nb::Error::Other(e)) => format!(
                "bad frame {:?}: {e:?}",
                String::from_utf8_lossy(self.from_bus.rejected())
            ),
        };
        eprintln!("{} bus << {text}", stamp(at));
    }
}
