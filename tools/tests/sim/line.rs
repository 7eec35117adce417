//! The line: communication establishment, the communication change, reply delays, baud rates.

use protocol::frame::COMM_CHANGE;
use protocol::line::Baud;
use protocol::memory::{self, common};
use protocol::{Command, Pulses, Request};
use rc_tools::sim::wire::{ms, transmit_time};
use rc_tools::sim::{BusConfig, ControllerConfig};

use crate::{accept, axis, controller, establish, fast_host, host_on, host_with, rtim, send};

// ----- line: establishment, delays, baud rates -----

#[test]
fn communication_establishment_6_1() {
    // Controllers that stored 38.4 kbit/s: the host cannot talk to them at 9.6 kbit/s...
    let config = ControllerConfig {
        stored_line: Some((Baud::B38400, rtim(10))),
        ..ControllerConfig::default()
    };
    let mut host = host_with(&[0, 3], config, BusConfig::default());
    assert_eq!(controller(&host, 0).baud(), Baud::B38400);
    assert!(host.status(axis(0)).is_none());
    // ...until the break, after which every axis is at 9.6 kbit/s and 255 ms.
    host.break_line(ms(200));
    for n in [0, 3] {
        assert_eq!(controller(&host, n).baud(), Baud::B9600);
        assert_eq!(controller(&host, n).rtim_ms(), 255);
    }
    // p: its own reply already comes 3 ms after the command.
    let p = accept(&mut host, 0, Command::SetResponseDelay(rtim(3)));
    assert_eq!(
        p.first_byte_at - p.sent_end,
        ms(3) + transmit_time(1, Baud::B9600)
    );
    host.set_baud(Baud::B9600);
    establish(&mut host, &[0, 3], Baud::B115200, 3);
    for n in [0, 3] {
        assert_eq!(controller(&host, n).baud(), Baud::B115200);
        assert_eq!(controller(&host, n).rtim_ms(), 3);
        assert_eq!(controller(&host, n).stats().comm_change_frames, 3);
        let answer = send(&mut host, n, Command::Status);
        let delay = answer.first_byte_at - answer.sent_end;
        assert_eq!(delay, ms(3) + transmit_time(1, Baud::B115200));
    }
}

#[test]
fn comm_change_takes_effect_about_150_ms_later() {
    let mut host = host_on(&[0]);
    host.break_line(ms(200));
    accept(&mut host, 0, Command::SetResponseDelay(rtim(3)));
    host.set_rtim_belief(3);
    accept(
        &mut host,
        0,
        Command::SetWriteAddress {
            address: common::BRSL,
        },
    );
    accept(&mut host, 0, Command::WriteMemory { value: 0x13 });
    let (_, end) = host.send_bytes(&COMM_CHANGE);
    host.wait_until(end + ms(140));
    assert_eq!(controller(&host, 0).baud(), Baud::B9600);
    host.wait_until(end + ms(151));
    assert_eq!(controller(&host, 0).baud(), Baud::B57600);
    // RTIM in the edit area was never written after the break: still 255 there.
    assert_eq!(controller(&host, 0).rtim_ms(), 255);
}

#[test]
fn replies_never_come_before_rtim() {
    let mut host = fast_host(&[0]);
    for delay_ms in [3u8, 10, 100, 255] {
        // The reply to p already waits for the new RTIM.
        host.set_rtim_belief(delay_ms);
        let p = accept(&mut host, 0, Command::SetResponseDelay(rtim(delay_ms)));
        assert!(p.first_byte_at - p.sent_end >= ms(delay_ms.into()));
        for command in [
            Command::Status,
            Command::ReadMemory {
                address: memory::PNOW,
            },
            Command::MoveAbsolute(Pulses(0)),
        ] {
            let answer = send(&mut host, 0, command);
            let delay = answer.first_byte_at - answer.sent_end;
            assert!(delay >= ms(delay_ms.into()), "{command:?}: {delay} µs");
            assert_eq!(delay, ms(delay_ms.into()) + transmit_time(1, Baud::B115200));
        }
    }
}

#[test]
fn bytes_at_the_wrong_baud_are_not_understood() {
    let mut host = host_on(&[0]);
    host.set_baud(Baud::B115200);
    assert!(host.status(axis(0)).is_none());
    assert_eq!(controller(&host, 0).stats().wrong_baud_bytes, 16);
    assert_eq!(controller(&host, 0).stats().frames_addressed, 0);
    host.set_baud(Baud::B19200);
    assert!(host.status(axis(0)).is_none());
    host.set_baud(Baud::B9600);
    assert!(host.status(axis(0)).is_some());

    // A controller at 115.2 kbit/s answering a host that listens at 9.6: garbage, not a reply.
    let mut host = fast_host(&[0]);
    let (_, end) = host.send_bytes(&Request::new(axis(0), Command::Status).emit().to_bytes());
    host.set_baud(Baud::B9600);
    host.wait_until(end + ms(50));
    assert_eq!(host.bus().stats().host_wrong_baud_bytes, 16);
    assert!(host.log().iter().rev().take(16).all(|&(_, b)| b == 0xFF));
}
