//! The outputs (completed position, alarm code, PEND/PM/HEND, link down) and the bit words.

use proptest::prelude::*;
use protocol::engine::{AxisState, JobKind, Link};
use protocol::pio::{Config, Pio, PioInputs as In, PioOutputs as Out};
use protocol::time::Instant;
use protocol::HomeDirection;

use crate::{axis, base, p, report, Rig, DONE_OUT, READY_STATUS};

// ---------------------------------------------------------------- outputs

#[test]
fn outputs_show_the_completed_position() {
    let mut rig = Rig::new(Config::default());
    rig.status(
        READY_STATUS | 0x20, /* + interlock */
        0,
        DONE_OUT | 0x40 | 5,
    );
    rig.run(1);
    let out = rig.out;
    assert_eq!(out.pm(), 5);
    assert!(out.pend() && out.hend() && out.sv() && out.link() && out.alm_n() && out.zone1());
    assert!(!out.moving() && !out.alarm());
    assert_eq!(
        out.bits(),
        0b0111_1100_1000_0101,
        "PM=5, ZONE1, HEND, PEND, SV, LINK, *ALM"
    );
}

#[test]
fn outputs_show_the_abbreviated_alarm_code_with_alm_off() {
    let mut rig = Rig::new(Config::default());
    // D8 (deviation): servo off, *ALM off, PM = 0B (complete edition §8-1-1).
    rig.status(0x01, 0xD8, 0x0B);
    rig.run(1);
    let out = rig.out;
    assert_eq!(out.pm(), 0x0B);
    assert!(out.alarm() && !out.alm_n());
    assert!(out.link() && !out.sv() && !out.pend() && !out.moving());
}

#[test]
fn outputs_are_safe_while_the_link_is_down_or_before_a_status() {
    let mut rig = Rig::new(Config::default());
    rig.run(1);
    assert!(rig.out.link());

    rig.link_ok = false;
    rig.run(1);
    assert_eq!(rig.out, Out::SAFE);
    assert!(rig.out.alarm() && !rig.out.link() && !rig.out.pend());

    rig.link_ok = true;
    rig.axis.link = Link::Offline;
    rig.run(1);
    assert_eq!(rig.out, Out::SAFE);

    rig.axis.link = Link::Online;
    rig.axis.report = None;
    rig.run(1);
    assert_eq!(rig.out, Out::SAFE);

    let mut pio = Pio::new(Config::default());
    let unknown = AxisState {
        link: Link::Unknown,
        report: None,
        report_at: None,
        ..axis(report(0, 0, 0), 0)
    };
    let (out, _) = pio.sample(Instant(0), base(), &unknown, true, HomeDirection::MotorEnd);
    assert_eq!(out.bits(), 0);
}

#[test]
fn pend_and_pm_are_off_from_the_strobe_until_the_move_completes() {
    let mut rig = Rig::new(Config::default());
    rig.select(5);
    assert_eq!(rig.run(20), vec![]);
    assert!(rig.out.pend());
    assert_eq!(rig.out.pm(), 3);
    rig.set(In::CSTR, true);
    assert_eq!(rig.run(6), vec![]);
    assert!(rig.out.pend(), "CSTR not recognised yet");
    assert_eq!(rig.tick(), Some(JobKind::MoveToPoint(p(5), None)));
    assert!(!rig.out.pend());
    assert_eq!(rig.out.pm(), 0);
    rig.set(In::CSTR, false);
    // The stale status (PFIN, PM 3) does not bring PEND back.
    rig.run(20);
    assert!(!rig.out.pend());
    assert_eq!(rig.out.pm(), 0);
    // A poll received before the Q3 went out, still at 3: still masked.
    rig.status(READY_STATUS, 0, DONE_OUT | 3);
    rig.run(3);
    assert!(!rig.out.pend() && rig.out.pm() == 0);
    // Moving: PFIN off, PM 0.
    rig.status(READY_STATUS, 0, 0xA0);
    rig.run(3);
    assert!(rig.out.moving() && !rig.out.pend() && rig.out.pm() == 0);
    // Arrived.
    rig.status(READY_STATUS, 0, DONE_OUT | 5);
    rig.run(1);
    assert!(rig.out.pend() && !rig.out.moving());
    assert_eq!(rig.out.pm(), 5);
}

#[test]
fn a_short_move_missed_by_the_samples_completes_on_pm() {
    let mut rig = Rig::new(Config::default());
    rig.select(9);
    rig.set(In::CSTR, true);
    // PC and CSTR recognised together at 6; PC stable for the settle time at 12.
    assert_eq!(rig.run(20), vec![(12, JobKind::MoveToPoint(p(9), None))]);
    rig.set(In::CSTR, false);
    rig.run(10);
    // The only status seen after the command already shows it done.
    rig.status(READY_STATUS, 0, DONE_OUT | 9);
    rig.run(1);
    assert!(rig.out.pend());
    assert_eq!(rig.out.pm(), 9);
}

#[test]
fn pm_is_shown_while_cstr_is_held_but_pend_only_after_it_falls() {
    let mut rig = Rig::new(Config::default());
    rig.select(2);
    rig.set(In::CSTR, true);
    assert_eq!(rig.run(20), vec![(12, JobKind::MoveToPoint(p(2), None))]);
    rig.status(READY_STATUS, 0, 0xA0);
    rig.run(2);
    rig.status(READY_STATUS, 0, DONE_OUT | 2);
    rig.run(2);
    assert_eq!(rig.out.pm(), 2);
    assert!(!rig.out.pend());
    rig.set(In::CSTR, false);
    rig.run(6);
    assert!(!rig.out.pend());
    rig.run(1);
    assert!(rig.out.pend());
}

/// A rig whose CSTR strobe for point 5 has been taken and returned (PEND masked), the axis at
/// point 3.
fn strobed_to_point_5() -> Rig {
    let mut rig = Rig::new(Config::default());
    rig.select(5);
    rig.set(In::CSTR, true);
    rig.run(20);
    rig.set(In::CSTR, false);
    rig.run(10);
    rig
}

#[test]
fn a_rejected_move_releases_the_outputs() {
    let mut rig = strobed_to_point_5();
    assert!(!rig.out.pend());
    // The Q3 was rejected (e.g. 0x70, RUN off): the status is unchanged, the count moves.
    rig.axis.counters.rejections += 1;
    rig.run(1);
    assert!(rig.out.pend());
    assert_eq!(
        rig.out.pm(),
        3,
        "still the old point: the PLC sees the move did not happen"
    );
}

#[test]
fn a_move_the_gateway_refuses_releases_the_outputs_and_nothing_else_does() {
    let mut rig = strobed_to_point_5();
    assert!(!rig.out.pend(), "waiting for the move");
    // Another job refused (a servo job, the queue full): the accepted move is still awaited.
    rig.pio.refused(&JobKind::Servo(true));
    rig.run(1);
    assert!(!rig.out.pend(), "still waiting: the move was taken");
    // The move itself refused (the stop input holds the axis): nothing is coming.
    rig.pio.refused(&JobKind::MoveToPoint(p(5), None));
    rig.run(1);
    assert!(rig.out.pend());
    assert_eq!(rig.out.pm(), 3, "the point the axis is at");
}

#[test]
fn hend_is_off_from_home_until_homing_completes() {
    let mut rig = Rig::new(Config::default());
    rig.set(In::HOME, true);
    assert_eq!(
        rig.run(10),
        vec![(6, JobKind::Home(HomeDirection::MotorEnd))]
    );
    assert!(!rig.out.hend() && !rig.out.pend());
    rig.status(READY_STATUS, 0, 0x80 | 0x20); // homing: PFIN off, ZFIN may stay on
    rig.run(5);
    assert!(!rig.out.hend() && rig.out.moving());
    rig.status(READY_STATUS, 0, DONE_OUT);
    rig.run(1);
    assert!(rig.out.hend() && rig.out.pend());
}

#[test]
fn an_alarm_during_a_move_shows_the_alarm() {
    let mut rig = Rig::new(Config::default());
    rig.select(6);
    rig.set(In::CSTR, true);
    assert_eq!(rig.run(20), vec![(12, JobKind::MoveToPoint(p(6), None))]);
    rig.status(0x01, 0xC8, 0x09);
    rig.run(1);
    assert!(rig.out.alarm());
    assert_eq!(rig.out.pm(), 0x09);
}

// ---------------------------------------------------------------- bit words

#[test]
fn input_bits_follow_pcon_pattern_0() {
    let ports = [
        (In::PC1, 0),
        (In::PC2, 1),
        (In::PC4, 2),
        (In::PC8, 3),
        (In::PC16, 4),
        (In::PC32, 5),
        (In::ST6, 6),
        (In::JISL, 7),
        (In::JOG_PLUS, 8),
        (In::JOG_MINUS, 9),
        (In::HOME, 11),
        (In::STP_N, 12),
        (In::CSTR, 13),
        (In::RES, 14),
        (In::SON, 15),
    ];
    for (flag, bit) in ports {
        assert_eq!(flag.bits(), 1 << bit, "{flag:?}");
    }
    assert_eq!(In::MASK, 0xFBFF);
    assert_eq!(In::from_bits(0b1010).position(), Some(p(10)));
    assert_eq!(In::from_bits(0b10_1010).position(), None);
    assert_eq!(In::NONE.with_position(p(13)).pc(), 13);
}

#[test]
fn output_bits_follow_pcon_pattern_0() {
    let ports = [
        (Out::PM1, 0),
        (Out::PM2, 1),
        (Out::PM4, 2),
        (Out::PM8, 3),
        (Out::PE4, 4),
        (Out::PE5, 5),
        (Out::MOVE, 6),
        (Out::ZONE1, 7),
        (Out::MODES, 9),
        (Out::HEND, 10),
        (Out::PEND, 11),
        (Out::SV, 12),
        (Out::LINK, 13),
        (Out::ALM_N, 14),
    ];
    for (flag, bit) in ports {
        assert_eq!(flag.bits(), 1 << bit, "{flag:?}");
    }
    assert_eq!(Out::MASK, 0x7EFF);
    assert_eq!(Out::NONE.with_pm(0x1B).pm(), 0x0B);
    assert_eq!(
        format!("{:?}", Out::PEND | Out::ALM_N),
        "PioOutputs(0x4800 PEND *ALM)"
    );
}

proptest! {
    #[test]
    fn bit_words_round_trip(bits: u16) {
        prop_assert_eq!(In::from_bits(bits).bits(), bits & In::MASK);
        prop_assert_eq!(In::from_bits(In::from_bits(bits).bits()), In::from_bits(bits));
        prop_assert_eq!(Out::from_bits(bits).bits(), bits & Out::MASK);
        prop_assert_eq!(Out::from_bits(Out::from_bits(bits).bits()), Out::from_bits(bits));
    }
}

/// *STP OFF mid-move cancels it (`d`); the controller then shows PFIN with PM 0 where the axis
/// stopped. PCON's *STP only pauses, and its PEND stays OFF until the move completes: a PLC that
/// waits for PEND must not take a move stopped short for done.
#[test]
fn pend_stays_off_after_stp_cancels_a_move_until_a_move_completes() {
    let mut rig = strobed_to_point_5();
    rig.status(READY_STATUS, 0, 0xA0); // moving
    rig.run(3);
    rig.set(In::STP_N, false);
    let stop_at = rig.t() + 6;
    assert_eq!(rig.run(10), vec![(stop_at, JobKind::Stop)]);
    rig.status(READY_STATUS, 0, DONE_OUT); // stopped short: PFIN, PM 0
    rig.run(5);
    assert!(
        !rig.out.pend(),
        "PEND OFF: the move did not reach its point"
    );
    assert_eq!(rig.out.pm(), 0);
    assert!(rig.out.sv() && rig.out.alm_n() && !rig.out.moving());
    // *STP ON again: still not at its point.
    rig.set(In::STP_N, true);
    rig.run(20);
    assert!(!rig.out.pend() && rig.out.pm() == 0);
    // A new strobe, the move completes: PEND again.
    rig.set(In::CSTR, true);
    let strobe_at = rig.t() + 6;
    assert_eq!(
        rig.run(10),
        vec![(strobe_at, JobKind::MoveToPoint(p(5), None))]
    );
    rig.set(In::CSTR, false);
    rig.run(10);
    rig.status(READY_STATUS, 0, 0xA0);
    rig.run(2);
    assert!(!rig.out.pend());
    rig.status(READY_STATUS, 0, DONE_OUT | 5);
    rig.run(1);
    assert!(rig.out.pend());
    assert_eq!(rig.out.pm(), 5);
}

/// A move stopped short by anything else (the gateway's stop input, the PLC watchdog, a Modbus
/// stop): the same, and a refused strobe meanwhile does not bring PEND back either.
#[test]
fn pend_stays_off_after_any_stop_cuts_a_move_short() {
    let mut rig = strobed_to_point_5();
    rig.status(READY_STATUS, 0, 0xA0);
    rig.run(3);
    rig.status(READY_STATUS, 0, DONE_OUT); // stopped: PFIN, PM 0
    rig.run(5);
    assert!(!rig.out.pend() && rig.out.pm() == 0);
    // The PLC strobes again while the stop input holds the axis: the move is refused.
    rig.set(In::CSTR, true);
    let jobs = rig.run(10);
    assert_eq!(jobs.len(), 1, "{jobs:?}");
    rig.pio.refused(&jobs[0].1);
    rig.set(In::CSTR, false);
    rig.run(10);
    assert!(!rig.out.pend() && rig.out.pm() == 0);
}
