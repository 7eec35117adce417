//! Fault injection: corruption, drops, delays, silence, power cycles, noise, collisions and breaks.

use protocol::line::Baud;
use protocol::memory::{self, common};
use protocol::{Command, Pulses, Request, Transfer};
use rc_tools::sim::realtime::Control;
use rc_tools::sim::wire::{ms, transmit_time};
use rc_tools::sim::{BusConfig, ControllerConfig, Faults, ScriptedHost};

use crate::{
    accept, axis, controller, establish, fast_host, home, host_on, host_with, move_to, read,
    reject, rtim, send, status, wait_pfin,
};

// ----- fault injection -----

fn fast_host_with_faults(axes: &[u8], seed: u64, faults: Faults) -> ScriptedHost {
    let bus = BusConfig {
        seed,
        ..BusConfig::default()
    };
    let mut host = host_with(axes, ControllerConfig::default(), bus);
    establish(&mut host, axes, Baud::B115200, 3);
    host.bus_mut().set_faults(faults);
    host
}

/// `count` status polls of axis 0; returns how many were answered.
fn polls(host: &mut ScriptedHost, count: usize) -> usize {
    (0..count)
        .filter(|_| host.status(axis(0)).is_some())
        .count()
}

/// Within `sigmas` standard deviations of a binomial(n, p) mean.
fn within(observed: u64, n: u64, p: f64, sigmas: f64) -> bool {
    let mean = n as f64 * p;
    let sd = (n as f64 * p * (1.0 - p)).sqrt();
    (observed as f64 - mean).abs() <= sigmas * sd
}

#[test]
fn byte_corruption_happens_at_the_configured_rate() {
    let mut host = fast_host_with_faults(&[0], 11, Faults::byte_corruption(0.01));
    let before = host.bus().stats().clone();
    let sent_before = before.host_bytes_sent + 16 * before.replies_sent;
    let answered = polls(&mut host, 3_200);
    let stats = host.bus().stats().clone();
    let bytes = stats.host_bytes_sent + 16 * stats.replies_sent - sent_before;
    let corrupted = stats.host_bytes_corrupted + stats.reply_bytes_corrupted;
    assert!(bytes >= 90_000, "{bytes}");
    assert!(
        within(corrupted, bytes, 0.01, 4.0),
        "{corrupted} of {bytes}"
    );
    // Every corrupted frame is seen as broken, every intact one arrives.
    let intact_replies = stats.replies_sent - stats.replies_corrupted;
    let packets = u64::from(host.deframer().counters().packets);
    assert!(packets >= intact_replies && packets <= intact_replies + 3);
    let intact_commands =
        stats.host_transmissions - stats.host_frames_corrupted - before.host_transmissions;
    let addressed = controller(&host, 0).stats().frames_addressed - before.host_transmissions
        + before.host_frames_corrupted;
    assert!(
        addressed.abs_diff(intact_commands) <= 3,
        "{addressed} {intact_commands}"
    );
    // About (0.99^16)^2 of the polls are answered.
    assert!(
        within(answered as u64, 3_200, 0.99f64.powi(32), 4.0),
        "{answered}"
    );
    assert!(controller(&host, 0).stats().bad_bcc > 0);
}

#[test]
fn faults_are_deterministic_for_a_seed() {
    let faults = Faults {
        host_byte_corruption: 0.01,
        reply_byte_corruption: 0.01,
        reply_drop: 0.05,
        reply_delay: 0.05,
        reply_delay_us: ms(5),
        noise: 0.05,
        noise_max_bytes: 2,
    };
    let run = |seed: u64| {
        let mut host = fast_host_with_faults(&[0], seed, faults);
        polls(&mut host, 300);
        (host.log().to_vec(), host.bus().stats().clone())
    };
    let (log_a, stats_a) = run(1);
    let (log_b, stats_b) = run(1);
    let (log_c, stats_c) = run(2);
    assert_eq!(log_a, log_b);
    assert_eq!(stats_a, stats_b);
    assert_ne!(log_a, log_c);
    assert_ne!(stats_a, stats_c);
}

#[test]
fn dropped_replies_happen_at_the_configured_rate() {
    let faults = Faults {
        reply_drop: 0.1,
        ..Faults::default()
    };
    let mut host = fast_host_with_faults(&[0], 3, faults);
    let answered = polls(&mut host, 2_000);
    let dropped = host.bus().stats().replies_dropped;
    assert_eq!(2_000 - answered as u64, dropped);
    assert!(within(dropped, 2_000, 0.1, 4.0), "{dropped}");
}

#[test]
fn delayed_replies_happen_at_the_configured_rate() {
    let faults = Faults {
        reply_delay: 0.2,
        reply_delay_us: ms(10),
        ..Faults::default()
    };
    let mut host = fast_host_with_faults(&[0], 4, faults);
    let mut late = 0;
    for _ in 0..1_000 {
        let answer = send(&mut host, 0, Command::Status);
        let delay = answer.first_byte_at - answer.sent_end;
        let normal = ms(3) + transmit_time(1, Baud::B115200);
        if delay == normal + ms(10) {
            late += 1;
        } else {
            assert_eq!(delay, normal);
        }
    }
    assert_eq!(late, host.bus().stats().replies_delayed);
    assert!(within(late, 1_000, 0.2, 4.0), "{late}");
}

#[test]
fn a_silent_axis_executes_but_never_answers() {
    let mut host = fast_host(&[0, 1]);
    host.bus_mut().set_silent(axis(1), true);
    assert!(host
        .transact(&Request::new(axis(1), Command::Servo(false)))
        .is_none());
    assert!(!controller(&host, 1).servo(), "the command was executed");
    assert!(host.status(axis(1)).is_none());
    assert_eq!(host.bus().stats().replies_silenced, 2);
    assert!(host.status(axis(0)).is_some());
    host.bus_mut().set_silent(axis(1), false);
    assert!(host.status(axis(1)).is_some());
}

#[test]
fn a_cut_axis_hears_nothing_answers_nothing_and_keeps_moving() {
    // Through rc-sim's control (`cut AXIS on|off`), as the emulator tests cut a wire.
    let mut host = fast_host(&[0, 1]);
    home(&mut host, 1);
    move_to(&mut host, 1, -3_000);
    let profile = controller(&host, 1).profile().expect("moving").clone();
    assert!(
        profile.end() - host.now() > ms(100),
        "a move long enough to cut"
    );
    Control::parse("cut 1 on")
        .unwrap()
        .apply(host.bus_mut())
        .unwrap();
    let before = controller(&host, 1).position();
    assert!(host
        .transact(&Request::new(axis(1), Command::CancelMotion))
        .is_none());
    host.wait(ms(20));
    assert!(controller(&host, 1).moving(), "the stop was never heard");
    assert_ne!(controller(&host, 1).position(), before, "still moving");
    assert_eq!(
        host.bus().stats().replies_silenced,
        0,
        "not heard, so not silenced"
    );
    assert!(host.status(axis(0)).is_some(), "the other wire is whole");
    Control::parse("cut 1 off")
        .unwrap()
        .apply(host.bus_mut())
        .unwrap();
    accept(&mut host, 1, Command::CancelMotion);
    host.wait(ms(200));
    assert!(!controller(&host, 1).moving(), "stopped once heard");
    assert!(host.now() < profile.end(), "by the stop, not by arriving");
}

#[test]
fn power_cycle_restores_non_volatile_settings() {
    let mut host = fast_host(&[0]);
    home(&mut host, 0);
    move_to(&mut host, 0, -3_000);
    wait_pfin(&mut host, 0);
    host.wait(ms(20));
    let at = host.now() + ms(10);
    host.bus_mut().schedule_power_cycle(axis(0), at, ms(50));
    host.wait(ms(100));
    assert_eq!(host.bus().stats().power_cycles, 1);
    let c = controller(&host, 0);
    assert_eq!(c.stats().power_ups, 2);
    // Nothing was stored with V5: back to the default line state.
    assert_eq!((c.baud(), c.rtim_ms()), (Baud::B9600, 255));
    assert!(
        host.status(axis(0)).is_none(),
        "the host still talks at 115.2"
    );
    host.set_baud(Baud::B9600);
    host.set_rtim_belief(255);
    let r = status(&mut host, 0);
    assert!(r.status.servo() && r.status.run() && !r.status.home() && r.outputs.pfin());
    // The slider did not move; the incremental encoder counts from 0 again.
    assert_eq!(controller(&host, 0).physical_position(), 3_000);
    assert_eq!(read(&mut host, 0, memory::PNOW.0), 0);
    assert_eq!(reject(&mut host, 0, Command::MoveAbsolute(Pulses(0))), 0x71);
}

#[test]
fn power_cycle_comes_back_at_the_stored_baud() {
    let mut host = fast_host(&[0]);
    // Store BRSL 57.6k and RTIM 5 ms (common parameters, V5) without changing the line now.
    accept(
        &mut host,
        0,
        Command::LoadToEdit(Transfer::CommonParameters),
    );
    accept(
        &mut host,
        0,
        Command::SetWriteAddress {
            address: common::BRSL,
        },
    );
    accept(&mut host, 0, Command::WriteMemory { value: 0x13 });
    accept(
        &mut host,
        0,
        Command::SetWriteAddress {
            address: common::RTIM,
        },
    );
    accept(&mut host, 0, Command::WriteMemory { value: 5 });
    let v5 = accept(
        &mut host,
        0,
        Command::StoreFromEdit(Transfer::CommonParameters),
    );
    assert_eq!(v5.reply.memory_value(), Some(1));
    let at = host.now();
    host.bus_mut().schedule_power_cycle(axis(0), at, ms(10));
    host.wait(ms(20));
    host.set_baud(Baud::B57600);
    host.set_rtim_belief(5);
    let answer = send(&mut host, 0, Command::Status);
    assert_eq!(
        answer.first_byte_at - answer.sent_end,
        ms(5) + transmit_time(1, Baud::B57600)
    );
}

#[test]
fn noise_between_frames_happens_at_the_configured_rate() {
    let faults = Faults {
        noise: 0.05,
        noise_max_bytes: 3,
        ..Faults::default()
    };
    let mut host = fast_host_with_faults(&[0], 5, faults);
    let noise_before = host.deframer().counters().noise_bytes;
    let answered = polls(&mut host, 1_000);
    assert_eq!(answered, 1_000, "noise between frames harms nothing");
    let stats = host.bus().stats();
    assert_eq!(stats.collisions, 0);
    let seen = u64::from(host.deframer().counters().noise_bytes - noise_before);
    assert_eq!(seen, stats.noise_bytes);
    assert!(within(stats.noise_bursts, 2_000, 0.05, 4.0), "{stats:?}");
    assert!(stats.noise_bytes >= stats.noise_bursts && stats.noise_bytes <= 3 * stats.noise_bursts);
}

#[test]
fn talking_over_a_reply_is_a_collision() {
    let mut host = host_on(&[0]);
    accept(&mut host, 0, Command::SetResponseDelay(rtim(3)));
    host.set_rtim_belief(3);
    let request = Request::new(axis(0), Command::Status);
    let (sent_at, end) = host.send_bytes(&request.emit().to_bytes());
    // The reply starts 3 ms after `end` and lasts 16.7 ms: talk 5 ms after `end`.
    host.wait_until(end + ms(5));
    let (second_at, second_end) = host.send_bytes(&request.emit().to_bytes());
    assert!(host
        .await_reply(&request, sent_at, end, second_end + ms(40))
        .is_none());
    let stats = host.bus().stats();
    assert_eq!(stats.collisions, 1);
    assert!(stats.collided_bytes >= 16, "{stats:?}");
    // The host read garbage, and the controller did not understand the second command.
    assert!(host.log().iter().any(|&(t, _)| t > second_at));
    assert_eq!(controller(&host, 0).stats().replies_scheduled, 2);
    // The line recovers.
    host.wait(ms(10));
    assert!(host.status(axis(0)).is_some());
}

#[test]
fn a_break_over_a_reply_cancels_and_garbles() {
    let mut host = host_on(&[0]);
    let (_, end) = host.send_bytes(&Request::new(axis(0), Command::Status).emit().to_bytes());
    host.wait_until(end + ms(100));
    // The reply is still waiting for its RTIM (255 ms): the break drops it.
    host.break_line(ms(200));
    assert_eq!(host.bus().stats().replies_cancelled, 1);
    assert_eq!(controller(&host, 0).stats().replies_sent, 0);
    assert!(host.status(axis(0)).is_some());
}

#[test]
fn a_short_low_pulse_is_not_a_break() {
    let mut host = fast_host(&[0]);
    // 10 bit times at 115.2 kbit/s are 87 µs.
    let now = host.now();
    let end = host.bus_mut().host_break(now, 50);
    host.wait_until(end + ms(1));
    assert_eq!(controller(&host, 0).baud(), Baud::B115200);
    assert_eq!(controller(&host, 0).stats().breaks, 1, "only §6-1's break");
    assert!(host.status(axis(0)).is_some());
    let now = host.now();
    let end = host.bus_mut().host_break(now, 200);
    host.wait_until(end + ms(1));
    assert_eq!(controller(&host, 0).baud(), Baud::B9600);
    assert_eq!(controller(&host, 0).rtim_ms(), 255);
}
