//! The inputs: debounce, CSTR and the position-number settle time, HOME, SON, RES and *STP.

use protocol::engine::{JobKind, Link};
use protocol::pio::{Config, Pio, PioInputs as In, PioOutputs as Out, STOP_REPEAT};
use protocol::time::{Duration, Instant};
use protocol::HomeDirection;

use crate::{axis, base, p, report, Rig, DONE_OUT, MS, READY_STATUS};

/// The home direction of the axes these samples stand for.
const MOTOR_END: HomeDirection = HomeDirection::MotorEnd;

// ---------------------------------------------------------------- debounce

#[test]
fn a_glitch_shorter_than_the_debounce_time_does_nothing() {
    let mut rig = Rig::new(Config::default());
    for flag in [In::CSTR, In::HOME, In::RES] {
        rig.set(flag, true);
        assert_eq!(rig.run(5), vec![], "{flag:?} ON for 5 ms");
        rig.set(flag, false);
        assert_eq!(rig.run(20), vec![]);
    }
    for flag in [In::STP_N, In::SON] {
        rig.set(flag, false);
        assert_eq!(rig.run(5), vec![], "{flag:?} OFF for 5 ms");
        rig.set(flag, true);
        assert_eq!(rig.run(20), vec![]);
    }
    assert_eq!(rig.pio.inputs(), base());
}

#[test]
fn an_input_counts_after_exactly_the_debounce_time() {
    let mut rig = Rig::new(Config::default());
    rig.set(In::CSTR, true);
    assert_eq!(rig.run(6), vec![]);
    assert!(!rig.pio.inputs().cstr());
    // The sample 6 ms after the pin changed recognises it; PC1-PC8 have long been stable.
    assert_eq!(rig.run(1), vec![(6, JobKind::MoveToPoint(p(3), None))]);
    assert!(rig.pio.inputs().cstr());
}

#[test]
fn a_glitch_restarts_the_debounce_time() {
    let mut rig = Rig::new(Config::default());
    rig.set(In::CSTR, true);
    assert_eq!(rig.run(4), vec![]);
    rig.set(In::CSTR, false);
    assert_eq!(rig.run(1), vec![]);
    rig.set(In::CSTR, true);
    let jobs = rig.run(10);
    assert_eq!(jobs, vec![(11, JobKind::MoveToPoint(p(3), None))]);
}

#[test]
fn zero_debounce_and_settle_act_on_the_sample() {
    let mut rig = Rig::new(Config {
        debounce: Duration::ZERO,
        settle: Duration::ZERO,
        ..Config::default()
    });
    rig.select(9);
    rig.set(In::CSTR, true);
    assert_eq!(rig.run(1), vec![(0, JobKind::MoveToPoint(p(9), None))]);
    rig.set(In::STP_N, false);
    assert_eq!(rig.run(1), vec![(1, JobKind::Stop)]);
}

// ---------------------------------------------------------------- CSTR

#[test]
fn cstr_latches_the_position_once_the_pc_bits_have_settled() {
    let mut rig = Rig::new(Config::default());
    // t=0: PC changes 3 -> 5; t=2: CSTR (the PLC set both within one 2 ms scan).
    rig.select(5);
    assert_eq!(rig.run(2), vec![]);
    rig.set(In::CSTR, true);
    // PC recognised at 6, CSTR at 8: PC has been stable only 2 ms then; latched at 6 + 6 = 12.
    let jobs = rig.run(40);
    assert_eq!(jobs, vec![(12, JobKind::MoveToPoint(p(5), None))]);
}

#[test]
fn a_strobe_waits_while_the_pc_bits_keep_changing_and_is_not_dropped() {
    let mut rig = Rig::new(Config::default());
    // t=0: PC 3 -> 4 and CSTR; both recognised at 6, the latch is due at 12.
    rig.select(4);
    rig.set(In::CSTR, true);
    assert_eq!(rig.run(3), vec![]);
    // t=3: PC8 on as well (4 -> 12), recognised at 9: the latch moves to 15.
    rig.select(12);
    assert_eq!(rig.run(4), vec![]);
    // t=7: CSTR falls (recognised at 13), before the latch: the strobe stays.
    rig.set(In::CSTR, false);
    let jobs = rig.run(40);
    assert_eq!(jobs, vec![(15, JobKind::MoveToPoint(p(12), None))]);
}

#[test]
fn cstr_held_on_moves_once_and_each_new_edge_moves_again() {
    let mut rig = Rig::new(Config::default());
    rig.set(In::CSTR, true);
    assert_eq!(rig.run(200), vec![(6, JobKind::MoveToPoint(p(3), None))]);
    rig.set(In::CSTR, false);
    assert_eq!(rig.run(20), vec![]);
    rig.select(12);
    assert_eq!(rig.run(20), vec![]);
    rig.set(In::CSTR, true);
    assert_eq!(rig.run(50), vec![(246, JobKind::MoveToPoint(p(12), None))]);
}

#[test]
fn a_strobe_with_pc16_or_pc32_on_is_refused() {
    for flag in [In::PC16, In::PC32] {
        let mut rig = Rig::new(Config::default());
        rig.set(flag, true);
        assert_eq!(rig.run(20), vec![]);
        rig.set(In::CSTR, true);
        assert_eq!(rig.run(50), vec![], "{flag:?}");
    }
}

#[test]
fn inputs_on_at_start_up_must_go_off_before_their_edge_counts() {
    let mut pio = Pio::new(Config::default());
    let ready = axis(report(READY_STATUS, 0, DONE_OUT), 0);
    let held = base() | In::CSTR | In::HOME;
    for t in 0..100 {
        let (_, job) = pio.sample(Instant(t * MS), held, &ready, true, MOTOR_END);
        assert_eq!(job, None, "t={t}");
    }
    let mut jobs = vec![];
    for t in 100..140 {
        let inputs = if t < 110 { base() } else { base() | In::CSTR };
        if let (_, Some(job)) = pio.sample(Instant(t * MS), inputs, &ready, true, MOTOR_END) {
            jobs.push((t, job));
        }
    }
    assert_eq!(jobs, vec![(116, JobKind::MoveToPoint(p(3), None))]);
}

#[test]
fn cstr_and_home_are_ignored_while_the_link_is_down() {
    let mut rig = Rig::new(Config::default());
    rig.link_ok = false;
    rig.set(In::CSTR, true);
    rig.set(In::HOME, true);
    assert_eq!(rig.run(30), vec![]);
    assert_eq!(rig.out, Out::SAFE);
    // Back up: the edges are gone, nothing starts late.
    rig.link_ok = true;
    assert_eq!(rig.run(30), vec![]);
}

// ---------------------------------------------------------------- HOME, SON, RES

#[test]
fn home_edge_homes_in_the_configured_direction() {
    let mut rig = Rig::new(Config::default());
    rig.set(In::HOME, true);
    assert_eq!(
        rig.run(50),
        vec![(6, JobKind::Home(HomeDirection::MotorEnd))]
    );

    let mut rig = Rig::new(Config::default());
    rig.home = HomeDirection::NonMotorEnd;
    rig.set(In::HOME, true);
    assert_eq!(
        rig.run(50),
        vec![(6, JobKind::Home(HomeDirection::NonMotorEnd))]
    );
}

#[test]
fn son_turns_the_servo_on_and_off() {
    let mut rig = Rig::new(Config::default());
    rig.set(In::SON, false);
    assert_eq!(rig.run(20), vec![(6, JobKind::Servo(false))]);
    rig.status(0x01, 0, DONE_OUT); // servo off reported
    assert_eq!(rig.run(2000), vec![]);
    rig.set(In::SON, true);
    assert_eq!(rig.run(20), vec![(2026, JobKind::Servo(true))]);
}

#[test]
fn son_is_reapplied_while_the_reported_servo_disagrees() {
    // Start-up with SON ON and the servo off: on as soon as SON is recognised.
    let mut pio = Pio::new(Config::default());
    let off = axis(report(0x01, 0, DONE_OUT), 0);
    let mut jobs = vec![];
    for t in 0..2500 {
        if let (_, Some(job)) = pio.sample(Instant(t * MS), base(), &off, true, MOTOR_END) {
            jobs.push((t, job));
        }
    }
    // Then once per servo_retry (1 s) while the status still says off.
    assert_eq!(
        jobs,
        vec![
            (6, JobKind::Servo(true)),
            (1006, JobKind::Servo(true)),
            (2006, JobKind::Servo(true)),
        ]
    );
}

#[test]
fn son_is_not_reapplied_during_an_alarm() {
    let alarm = axis(report(0x01, 0xD8, 0x0B), 0);
    let mut rig = Rig::with_axis(Config::default(), alarm);
    assert_eq!(rig.run(3000), vec![]);
}

#[test]
fn res_edge_resets_an_alarm_and_the_servo_comes_back_with_son() {
    let mut rig = Rig::with_axis(Config::default(), axis(report(0x01, 0xD8, 0x0B), 0));
    rig.set(In::RES, true);
    assert_eq!(rig.run(20), vec![(6, JobKind::AlarmReset)]);
    rig.set(In::RES, false);
    assert_eq!(rig.run(10), vec![]);
    // The reset cleared the alarm; the servo is off and SON is still ON: on again.
    rig.status(0x01, 0, DONE_OUT);
    assert_eq!(rig.run(10), vec![(30, JobKind::Servo(true))]);
}

#[test]
fn res_edge_without_an_alarm_does_nothing() {
    let mut rig = Rig::new(Config::default());
    rig.set(In::RES, true);
    assert_eq!(rig.run(50), vec![]);
}

// ---------------------------------------------------------------- *STP

#[test]
fn stp_off_stops_on_the_sample_it_is_recognised() {
    let mut rig = Rig::new(Config::default());
    rig.set(In::STP_N, false);
    for t in 0..6 {
        assert_eq!(rig.tick(), None, "t={t}");
        assert!(rig.pio.inputs().stp_n());
    }
    assert_eq!(rig.tick(), Some(JobKind::Stop));
    assert!(!rig.pio.inputs().stp_n());
    assert_eq!(rig.run(100), vec![]);
}

#[test]
fn cstr_and_home_are_ignored_while_stp_is_off_and_release_does_not_resume() {
    let mut rig = Rig::new(Config::default());
    rig.set(In::STP_N, false);
    assert_eq!(rig.run(10), vec![(6, JobKind::Stop)]);
    for flag in [In::CSTR, In::HOME] {
        rig.set(flag, true);
        assert_eq!(rig.run(20), vec![], "{flag:?}");
        rig.set(flag, false);
        assert_eq!(rig.run(20), vec![]);
    }
    // Held through the release: no edge after it, no resume.
    rig.set(In::CSTR, true);
    assert_eq!(rig.run(20), vec![]);
    rig.set(In::STP_N, true);
    assert_eq!(rig.run(50), vec![]);
    // A new strobe after the release moves.
    rig.set(In::CSTR, false);
    assert_eq!(rig.run(20), vec![]);
    rig.set(In::CSTR, true);
    assert_eq!(rig.run(20), vec![(186, JobKind::MoveToPoint(p(3), None))]);
}

#[test]
fn stp_off_and_cstr_recognised_together_only_stop() {
    let mut rig = Rig::new(Config::default());
    rig.set(In::CSTR, true);
    rig.set(In::STP_N, false);
    assert_eq!(rig.run(100), vec![(6, JobKind::Stop)]);
    assert!(!rig.pio.motion_pending());
}

#[test]
fn stp_off_during_the_settle_time_cancels_the_move() {
    let mut rig = Rig::new(Config {
        settle: Duration::from_millis(20),
        ..Config::default()
    });
    rig.select(8);
    rig.set(In::CSTR, true);
    assert_eq!(rig.run(10), vec![]); // PC and CSTR recognised at 6; latch due at 26
    assert!(rig.pio.motion_pending());
    rig.set(In::STP_N, false); // recognised at 16
    assert_eq!(rig.run(10), vec![(16, JobKind::Stop)]);
    assert!(!rig.pio.motion_pending());
    rig.set(In::STP_N, true);
    assert_eq!(rig.run(100), vec![]);
}

#[test]
fn the_stop_repeats_while_stp_is_off_and_the_axis_still_moves() {
    let mut rig = Rig::new(Config::default());
    rig.set(In::STP_N, false);
    assert_eq!(rig.run(10), vec![(6, JobKind::Stop)]);
    // Something else moves the axis (servo on, PFIN off).
    rig.status(READY_STATUS, 0, 0xA0);
    let jobs = rig.run(250);
    assert_eq!(
        jobs,
        vec![(106, JobKind::Stop), (206, JobKind::Stop)],
        "every {STOP_REPEAT:?}"
    );
    rig.status(READY_STATUS, 0, DONE_OUT);
    assert_eq!(rig.run(300), vec![]);
}

#[test]
fn the_stop_goes_out_even_with_the_link_down() {
    let mut rig = Rig::new(Config::default());
    rig.axis.link = Link::Offline;
    rig.set(In::STP_N, false);
    assert_eq!(rig.run(10), vec![(6, JobKind::Stop)]);
}
