//! The whole gateway (`Node`): bytes from the RS485 bus and from the PLC line, input samples,
//! the stop input and time steps, interleaved as the input says (issue 24).
//!
//! Input: a set-up byte (bits 0-3: the axes on the bus, at least axis 0; bit 4: the §6-1
//! establishment at start; bit 5: a PIO axis; bits 6-7: its pattern, 0, 1, 4 or 5), then
//! operations. An operation byte's low three
//! bits choose it, its high five bits give a length `n`:
//! 0 `n` bytes from the bus; 1 `n` bytes from the PLC; 2 an input sample (two bytes);
//! 3 the stop input active (bit 3 set) or released; 4 time passes (two bytes, x 50 µs);
//! Modbus TCP on socket `n % 5`: 5 a client connects (one byte: the last byte of its address
//! 10.0.0.x), 6 bytes from it (one length byte, then the bytes), 7 it closes.
//! After each operation the node is polled until it has nothing to do now.
//!
//! Checks, besides "nothing panics":
//! - every frame for the bus is a valid frame (BCC) of a command to an axis on the bus;
//! - once the stop input goes active, every axis on the bus gets its first stop (`d`) before
//!   any other frame (one whose `d` is on the wire then has it): nothing but `d`s go out until each has had one, and none of them a second
//!   (a resend) before the others' first, unless something may have stopped it again since
//!   (bytes from the PLC or a TCP client, PIO inputs, an armed watchdog);
//! - nothing, not even a stop, goes to an axis after it leaves the bus (a PLC may take one off;
//!   it may be another gateway's now);
//! - and every one of them does get it: after the input's end, time passes with a silent bus
//!   until no stop is owed (to an axis still on the bus), at most a minute;
//! - a reply for the PLC only follows bytes from the PLC (none unasked), and is a whole Modbus
//!   frame with a valid CRC;
//! - a TCP reply goes only to a connection that is open and has sent bytes,
//!   and is a whole MBAP frame (protocol id 0, a length that counts the rest, at most 260
//!   bytes); a close names a socket that exists. (Bit 6 of the set-up byte, which also picks
//!   the pattern, sets an allow-list of 10.0.0.1, two connections at most and 1 s idle.)
//! - flash work for a firmware update (a DFU partition of [`PARTITION`] bytes, board 1) stays in
//!   the partition, and each write starts on a flash word.
#![no_main]

use libfuzzer_sys::fuzz_target;
use protocol::command::{Command, Request};
use protocol::frame::Frame;
use protocol::modbus::crc;
use protocol::modbus::tcp::{SocketHandle, SOCKETS};
use protocol::net::Ipv4;
use protocol::node::TcpAction;
use protocol::node::{Action, Node};
use protocol::pio::{Pattern, PioInputs};
use protocol::plc::update::{Target, UpdateJob, CHUNK_ALIGN};
use protocol::plc::{GatewayConfig, SettingsRequest};
use protocol::time::Instant;
use protocol::{Axis, AxisSet};

/// The DFU partition's size: small, so that a fuzzed image can fill it.
const PARTITION: u32 = 1024;

/// The first `n` bytes of `rest` (fewer at its end), taken off it.
fn take<'a>(rest: &mut &'a [u8], n: usize) -> &'a [u8] {
    let (head, tail) = rest.split_at(n.min(rest.len()));
    *rest = tail;
    head
}

fuzz_target!(|data: &[u8]| {
    let Some((&setup, mut rest)) = data.split_first() else {
        return;
    };
    let mut config = GatewayConfig::new(AxisSet(u16::from(setup & 0x0F) | 1));
    config.bus.establish = setup & 0x10 != 0;
    config.settings.pio_axis = if setup & 0x20 != 0 {
        Axis::new(0)
    } else {
        None
    };
    config.settings.pio_pattern = [
        Pattern::Positioning,
        Pattern::Teaching,
        Pattern::Solenoid7,
        Pattern::Solenoid3,
    ][usize::from(setup >> 6)];
    if setup & 0x40 != 0 {
        config.settings.net.policy.allow[0] = Ipv4([10, 0, 0, 1]);
        config.settings.net.policy.max_connections = 2;
        config.settings.net.policy.idle_s = 1;
    }
    let mut node = Node::new(
        config,
        &protocol::plc::IDENTITY,
        protocol::plc::Boot::DEFAULT,
    );
    node.set_update_target(Target {
        board: 1,
        partition: PARTITION,
    });
    // Per socket: a connection is open; it sent bytes since its last reply.
    let mut tcp = Tcp::default();
    let mut now = 0u64;
    let mut stop_active = false;
    // The axes still owed their first stop since the stop input went active.
    let mut owed = AxisSet::EMPTY;
    // The PLC or a TCP client sent bytes since the stop input went active.
    let mut talked = false;
    // PLC bytes received since the last reply.
    let mut asked = false;

    while let Some((&op, after)) = rest.split_first() {
        rest = after;
        let n = usize::from(op >> 3);
        match op & 0x07 {
            0 => node.bus_received(Instant(now), take(&mut rest, n)),
            1 => {
                let bytes = take(&mut rest, n);
                asked |= !bytes.is_empty();
                talked |= !bytes.is_empty();
                // Read late, as the firmware reads what waited through a bus send: the bytes
                // came after some earlier time (up to 35 ms before, from the op).
                let since = Instant(now.saturating_sub(u64::from(op) * 137));
                node.plc_received_between(since, Instant(now), bytes);
            }
            2 => {
                let b = take(&mut rest, 2);
                let bits = u16::from(b.first().copied().unwrap_or(0))
                    | u16::from(b.get(1).copied().unwrap_or(0)) << 8;
                // The PIO's inputs stop its axis too (*STP, a jog released).
                talked |= node.gateway().config().settings.pio_axis.is_some();
                node.sample_inputs(Instant(now), PioInputs::from_bits(bits));
            }
            3 => {
                let active = op & 0x08 != 0;
                if active && !stop_active {
                    owed = node.gateway().config().bus.axes;
                    // A `d` on the wire as the input opens is that axis' stop: the one asked
                    // for now takes over its tries and goes as its resend.
                    if let Some(r) = node.gateway().engine().in_flight() {
                        if r.command == Command::CancelMotion {
                            owed = owed.without(r.axis);
                        }
                    }
                    // A request still being received, or an armed watchdog (it may trip and
                    // stop every axis again), may bring new stops too.
                    talked = asked
                        || tcp.asked.iter().any(|&a| a)
                        || node.gateway().watchdog_deadline().is_some();
                }
                stop_active = active;
                node.set_stop_input(Instant(now), active);
            }
            4 => {
                let b = take(&mut rest, 2);
                let step = u64::from(b.first().copied().unwrap_or(0))
                    | u64::from(b.get(1).copied().unwrap_or(0)) << 8;
                now += step * 50;
            }
            5 => {
                let socket = n % SOCKETS;
                let host = take(&mut rest, 1).first().copied().unwrap_or(0);
                let open = node.tcp_opened(Instant(now), handle(socket), Ipv4([10, 0, 0, host]));
                tcp.open[socket] = open;
                tcp.asked[socket] = false;
            }
            6 => {
                let socket = n % SOCKETS;
                let len = usize::from(take(&mut rest, 1).first().copied().unwrap_or(0));
                let bytes = take(&mut rest, len);
                talked |= !bytes.is_empty();
                let taken = node.tcp_received(Instant(now), handle(socket), bytes);
                assert!(taken <= bytes.len());
                if tcp.open[socket] && taken > 0 {
                    tcp.asked[socket] = true;
                }
            }
            _ => {
                let socket = n % SOCKETS;
                node.tcp_closed(handle(socket));
                tcp.open[socket] = false;
            }
        }
        if !drain(&mut node, now, &mut owed, talked, &mut asked, &mut tcp) {
            return;
        }
    }
    // Every axis gets its stop: with no more input but time passing (the bus silent, so every
    // stop ends by its time-out), every stop still owed goes out within a minute.
    // (Only to the axes still on the bus: a PLC may have taken one off since.)
    let end = now + 60_000_000;
    loop {
        let still = AxisSet(owed.0 & node.gateway().config().bus.axes.0);
        if still.is_empty() {
            break;
        }
        assert!(
            now < end,
            "stops still owed to {still:?} a minute after the input ended"
        );
        now = node.poll_at().map_or(end, |at| at.0.clamp(now + 1, end));
        if !drain(&mut node, now, &mut owed, talked, &mut asked, &mut tcp) {
            return;
        }
    }
});

/// What the harness knows of the TCP sockets.
#[derive(Default)]
struct Tcp {
    open: [bool; SOCKETS],
    asked: [bool; SOCKETS],
}

/// Poll the node at `now` until it has nothing to do, checking each action; `false` when the
/// board restarts.
fn drain(
    node: &mut Node,
    now: u64,
    owed: &mut AxisSet,
    talked: bool,
    asked: &mut bool,
    tcp: &mut Tcp,
) -> bool {
    for _ in 0..256 {
        let bus_axes = node.gateway().config().bus.axes;
        let Some(action) = node.poll(Instant(now)) else {
            break;
        };
        match action {
            Action::Bus(bytes) => {
                let frame = Frame::new_checked(&bytes).expect("a valid frame");
                let request = Request::parse(&frame).expect("a command frame");
                assert!(
                    bus_axes.contains(request.axis),
                    "a frame to axis {:?}, not on the bus {:?}",
                    request.axis,
                    bus_axes
                );
                *owed = AxisSet(owed.0 & bus_axes.0);
                if *owed != AxisSet::EMPTY {
                    // Every first stop before any other frame, and before any resend.
                    assert_eq!(
                        request.command,
                        Command::CancelMotion,
                        "{request:?} before the first stops still owed to {owed:?}"
                    );
                    assert!(
                        owed.contains(request.axis) || talked,
                        "a second stop to {:?} before the first stops still owed to {owed:?}",
                        request.axis
                    );
                    *owed = owed.without(request.axis);
                }
            }
            Action::Reply(reply) => {
                assert!(*asked, "a reply nobody asked for");
                assert!(reply.len() >= 4 && reply.len() <= 256, "reply length");
                assert!(crc::is_valid(reply), "reply CRC");
                *asked = false;
            }
            Action::Settings(SettingsRequest::Save) => node.stored(Ok(1)),
            // The board restarts.
            Action::Settings(SettingsRequest::FactoryReset | SettingsRequest::Restart) => {
                return false
            }
            Action::Line(_) | Action::PlcLine(_) => {}
            // Flash work stays in the partition, a write on its flash words; done at once.
            Action::Update(job) => {
                let (end, aligned) = match job {
                    UpdateJob::Erase { len } | UpdateJob::Finish { len, .. } => {
                        (u64::from(len), true)
                    }
                    UpdateJob::Write { offset, bytes } => (
                        u64::from(offset) + bytes.len() as u64,
                        offset % CHUNK_ALIGN == 0,
                    ),
                };
                assert!(
                    end <= u64::from(PARTITION),
                    "flash work past the partition: {job:?}"
                );
                assert!(aligned, "a write off a flash word: {job:?}");
                node.update_done(Ok(()));
            }
            Action::Tcp(TcpAction::Reply(handle)) => {
                let (socket, bytes) = (handle.index(), node.tcp_reply());
                assert!(
                    socket < SOCKETS && tcp.open[socket],
                    "a reply to socket {socket}, not open"
                );
                assert!(tcp.asked[socket], "a TCP reply nobody asked for");
                assert!(bytes.len() >= 9 && bytes.len() <= 260, "TCP reply length");
                assert_eq!(&bytes[2..4], &[0, 0], "protocol id");
                let length = usize::from(u16::from_be_bytes([bytes[4], bytes[5]]));
                assert_eq!(length, bytes.len() - 6, "MBAP length");
            }
            Action::Tcp(TcpAction::Close(handle)) => {
                let socket = handle.index();
                assert!(socket < SOCKETS, "a close of socket {socket}");
                tcp.open[socket] = false;
                node.tcp_closed(handle);
            }
        }
    }
    true
}

/// Socket `socket`'s handle (`socket` is below [`SOCKETS`]).
fn handle(socket: usize) -> SocketHandle {
    SocketHandle::new(socket).expect("a socket below SOCKETS")
}
