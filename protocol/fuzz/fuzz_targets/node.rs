//! The whole gateway (`Node`): bytes from the RS485 bus and from the PLC line, input samples,
//! the stop input and time steps, interleaved as the input says (issue 24).
//!
//! Input: a set-up byte (bits 0-3: the axes on the bus, at least axis 0; bit 4: the §6-1
//! establishment at start; bit 5: a PIO axis; bits 6-7: its pattern, 0, 1, 4 or 5), then
//! operations. An operation byte's low three
//! bits choose it, its high five bits give a length `n`:
//! 0 `n` bytes from the bus; 1 `n` bytes from the PLC; 2 an input sample (two bytes);
//! 3 the stop input active (bit 3 set) or released; 4 time passes (two bytes, x 50 µs).
//! After each operation the node is polled until it has nothing to do now.
//!
//! Checks, besides "nothing panics":
//! - every frame for the bus is a valid frame (BCC) of a command to an axis on the bus;
//! - once the stop input goes active, nothing that moves an axis goes out until every axis on
//!   the bus has had its stop (`d`);
//! - and every one of them does get it: after the input's end, time passes with a silent bus
//!   until no stop is owed (to an axis still on the bus), at most a minute;
//! - a reply for the PLC only follows bytes from the PLC (none unasked), and is a whole Modbus
//!   frame with a valid CRC.
#![no_main]

use libfuzzer_sys::fuzz_target;
use protocol::command::{Command, Request};
use protocol::frame::Frame;
use protocol::modbus::crc;
use protocol::node::{Action, Node};
use protocol::pio::{Pattern, PioInputs};
use protocol::plc::{GatewayConfig, Store};
use protocol::time::Instant;
use protocol::{Axis, AxisSet};

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
    config.pio_axis = if setup & 0x20 != 0 { Axis::new(0) } else { None };
    config.pio_pattern = [
        Pattern::Positioning,
        Pattern::Teaching,
        Pattern::Solenoid7,
        Pattern::Solenoid3,
    ][usize::from(setup >> 6)];
    let mut node = Node::new(config);
    let mut now = 0u64;
    let mut stop_active = false;
    // The axes still owed their stop since the stop input went active.
    let mut owed = AxisSet::EMPTY;
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
                node.plc_received(Instant(now), bytes);
            }
            2 => {
                let b = take(&mut rest, 2);
                let bits = u16::from(b.first().copied().unwrap_or(0))
                    | u16::from(b.get(1).copied().unwrap_or(0)) << 8;
                node.sample_inputs(Instant(now), PioInputs::from_bits(bits));
            }
            3 => {
                let active = op & 0x08 != 0;
                if active && !stop_active {
                    owed = node.gateway().config().bus.axes;
                }
                stop_active = active;
                node.set_stop_input(Instant(now), active);
            }
            _ => {
                let b = take(&mut rest, 2);
                let step = u64::from(b.first().copied().unwrap_or(0))
                    | u64::from(b.get(1).copied().unwrap_or(0)) << 8;
                now += step * 50;
            }
        }
        if !drain(&mut node, now, &mut owed, &mut asked) {
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
        if !drain(&mut node, now, &mut owed, &mut asked) {
            return;
        }
    }
});

/// Poll the node at `now` until it has nothing to do, checking each action; `false` when the
/// board restarts.
fn drain(node: &mut Node, now: u64, owed: &mut AxisSet, asked: &mut bool) -> bool {
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
                if *owed != AxisSet::EMPTY {
                    // Nothing that moves an axis until every axis has had its stop. (Not
                    // "nothing but stops": a stop that got no answer is resent before the
                    // next axis' first one, and an establishment or a rejoin that is under
                    // way sends its frames first; this target found both.)
                    assert!(
                        !request.command.moves(),
                        "{:?} before the stops still owed to {:?}",
                        request,
                        owed
                    );
                    if request.command == Command::CancelMotion {
                        *owed = owed.without(request.axis);
                    }
                }
            }
            Action::Reply(reply) => {
                assert!(*asked, "a reply nobody asked for");
                assert!(reply.len() >= 4 && reply.len() <= 256, "reply length");
                assert!(crc::is_valid(reply), "reply CRC");
                *asked = false;
            }
            Action::Store(Store::Save(_)) => node.stored(Ok(1)),
            // The board restarts.
            Action::Store(Store::FactoryReset | Store::Restart) => return false,
            Action::Line(_) | Action::PlcLine(_) => {}
        }
    }
    true
}
