//! The PIO state machine in virtual time: scripted input sequences against hand-made axis states.
//!
//! A [`Rig`] samples the PIO every millisecond, as the firmware does. Times in the assertions are
//! in milliseconds from the rig's start; the rig first runs a warm-up so that every input is
//! recognised, with *STP and SON ON and the axis ready (servo on, homed, in position at point 3).

use proptest::prelude::*;
use protocol::engine::{AxisState, Counters, JobKind, Link};
use protocol::pio::{Config, Pio, PioInputs as In, PioOutputs as Out, STOP_REPEAT};
use protocol::time::{Duration, Instant};
use protocol::{
    AlarmCode, HomeDirection, Inputs, Outputs, PositionNo, Status, StatusReport, RTIM_AFTER_BREAK,
};

const MS: u64 = 1000;

/// Status: power, servo, run, home.
const READY_STATUS: u8 = 0x0F;
/// OUT: *ALM on, ZFIN, PFIN.
const DONE_OUT: u8 = 0xB0;

fn p(n: u8) -> PositionNo {
    PositionNo::new(n).unwrap()
}

fn report(status: u8, alarm: u8, out: u8) -> StatusReport {
    StatusReport {
        status: Status::from_bits(status),
        alarm: AlarmCode(alarm),
        inputs: Inputs::default(),
        outputs: Outputs::from_bits(out),
    }
}

fn axis(report: StatusReport, at_us: u64) -> AxisState {
    AxisState {
        link: Link::Online,
        report: Some(report),
        report_at: Some(Instant(at_us)),
        position: None,
        position_at: None,
        rtim: RTIM_AFTER_BREAK,
        last_error: None,
        counters: Counters::default(),
    }
}

/// *STP and SON ON, position 3 selected.
fn base() -> In {
    In::STP_N | In::SON | In::PC1 | In::PC2
}

struct Rig {
    pio: Pio,
    /// Microseconds.
    now: u64,
    start: u64,
    axis: AxisState,
    link_ok: bool,
    inputs: In,
    out: Out,
}

impl Rig {
    fn new(config: Config) -> Rig {
        Rig::with_axis(config, axis(report(READY_STATUS, 0, DONE_OUT | 3), 0))
    }

    fn with_axis(config: Config, axis: AxisState) -> Rig {
        let mut rig = Rig {
            pio: Pio::new(config),
            now: 0,
            start: 0,
            axis,
            link_ok: true,
            inputs: base(),
            out: Out::SAFE,
        };
        let jobs = rig.run(30);
        assert_eq!(jobs, vec![], "warm-up");
        rig.start = rig.now;
        rig
    }

    /// Milliseconds since the warm-up.
    fn t(&self) -> u64 {
        (self.now - self.start) / MS
    }

    /// One sample at the current time, then 1 ms passes.
    fn tick(&mut self) -> Option<JobKind> {
        let (out, job) = self
            .pio
            .sample(Instant(self.now), self.inputs, &self.axis, self.link_ok);
        self.out = out;
        self.now += MS;
        job
    }

    /// `n` samples; the jobs with the time (ms) of the sample that returned them.
    fn run(&mut self, n: u64) -> Vec<(u64, JobKind)> {
        let mut jobs = vec![];
        for _ in 0..n {
            let t = self.t();
            if let Some(job) = self.tick() {
                jobs.push((t, job));
            }
        }
        jobs
    }

    fn set(&mut self, flag: In, on: bool) {
        self.inputs = self.inputs.with(flag, on);
    }

    fn select(&mut self, n: u8) {
        self.inputs = self.inputs.with_position(p(n));
    }

    /// A new status, received now.
    fn status(&mut self, status: u8, alarm: u8, out: u8) {
        self.axis.report = Some(report(status, alarm, out));
        self.axis.report_at = Some(Instant(self.now));
    }
}

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
    assert_eq!(rig.run(1), vec![(6, JobKind::MoveToPoint(p(3)))]);
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
    assert_eq!(jobs, vec![(11, JobKind::MoveToPoint(p(3)))]);
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
    assert_eq!(rig.run(1), vec![(0, JobKind::MoveToPoint(p(9)))]);
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
    assert_eq!(jobs, vec![(12, JobKind::MoveToPoint(p(5)))]);
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
    assert_eq!(jobs, vec![(15, JobKind::MoveToPoint(p(12)))]);
}

#[test]
fn cstr_held_on_moves_once_and_each_new_edge_moves_again() {
    let mut rig = Rig::new(Config::default());
    rig.set(In::CSTR, true);
    assert_eq!(rig.run(200), vec![(6, JobKind::MoveToPoint(p(3)))]);
    rig.set(In::CSTR, false);
    assert_eq!(rig.run(20), vec![]);
    rig.select(12);
    assert_eq!(rig.run(20), vec![]);
    rig.set(In::CSTR, true);
    assert_eq!(rig.run(50), vec![(246, JobKind::MoveToPoint(p(12)))]);
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
        let (_, job) = pio.sample(Instant(t * MS), held, &ready, true);
        assert_eq!(job, None, "t={t}");
    }
    let mut jobs = vec![];
    for t in 100..140 {
        let inputs = if t < 110 { base() } else { base() | In::CSTR };
        if let (_, Some(job)) = pio.sample(Instant(t * MS), inputs, &ready, true) {
            jobs.push((t, job));
        }
    }
    assert_eq!(jobs, vec![(116, JobKind::MoveToPoint(p(3)))]);
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

    let mut rig = Rig::new(Config {
        home_direction: HomeDirection::NonMotorEnd,
        ..Config::default()
    });
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
        if let (_, Some(job)) = pio.sample(Instant(t * MS), base(), &off, true) {
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
    assert_eq!(rig.run(20), vec![(186, JobKind::MoveToPoint(p(3)))]);
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
    let (out, _) = pio.sample(Instant(0), base(), &unknown, true);
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
    assert_eq!(rig.tick(), Some(JobKind::MoveToPoint(p(5))));
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
    assert_eq!(rig.run(20), vec![(12, JobKind::MoveToPoint(p(9)))]);
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
    assert_eq!(rig.run(20), vec![(12, JobKind::MoveToPoint(p(2)))]);
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

#[test]
fn a_rejected_move_releases_the_outputs() {
    let mut rig = Rig::new(Config::default());
    rig.select(5);
    rig.set(In::CSTR, true);
    rig.run(20);
    rig.set(In::CSTR, false);
    rig.run(10);
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
    assert_eq!(rig.run(20), vec![(12, JobKind::MoveToPoint(p(6)))]);
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
        (In::HOME, 11),
        (In::STP_N, 12),
        (In::CSTR, 13),
        (In::RES, 14),
        (In::SON, 15),
    ];
    for (flag, bit) in ports {
        assert_eq!(flag.bits(), 1 << bit, "{flag:?}");
    }
    assert_eq!(In::MASK, 0xF83F);
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
        (Out::MOVE, 6),
        (Out::ZONE1, 7),
        (Out::HEND, 10),
        (Out::PEND, 11),
        (Out::SV, 12),
        (Out::LINK, 13),
        (Out::ALM_N, 14),
    ];
    for (flag, bit) in ports {
        assert_eq!(flag.bits(), 1 << bit, "{flag:?}");
    }
    assert_eq!(Out::MASK, 0x7CCF);
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

// ---------------------------------------------------------------- properties

#[derive(Clone, Debug)]
struct Step {
    dt_us: u64,
    inputs: u16,
    link_ok: bool,
    online: bool,
    report: Option<(u8, u8, u8)>,
    rejections: u32,
}

fn step() -> impl Strategy<Value = Step> {
    (
        prop_oneof![0u64..3_000, Just(1_000), 0u64..50_000],
        // Mostly *STP ON with a few bits flipping, sometimes anything.
        prop_oneof![
            3 => (any::<u16>(), any::<bool>()).prop_map(|(b, stp)| {
                let b = b & !In::STP_N.bits();
                if stp { b | In::STP_N.bits() } else { b }
            }),
            1 => any::<u16>(),
        ],
        prop_oneof![5 => Just(true), 1 => Just(false)],
        prop_oneof![5 => Just(true), 1 => Just(false)],
        proptest::option::weighted(0.9, (any::<u8>(), any::<u8>(), any::<u8>())),
        0u32..3,
    )
        .prop_map(
            |(dt_us, inputs, link_ok, online, report, rejections)| Step {
                dt_us,
                inputs,
                link_ok,
                online,
                report,
                rejections,
            },
        )
}

fn config() -> impl Strategy<Value = Config> {
    (0u64..10_000, 0u64..10_000, 0u64..2_000_000, any::<bool>()).prop_map(
        |(debounce, settle, retry, dir)| Config {
            debounce: Duration::from_micros(debounce),
            settle: Duration::from_micros(settle),
            servo_retry: Duration::from_micros(retry),
            home_direction: if dir {
                HomeDirection::MotorEnd
            } else {
                HomeDirection::NonMotorEnd
            },
        },
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Whatever the PLC and the bus do: no panic; no move or home while *STP has read OFF for the
    /// debounce time; the stop on the sample *STP is recognised OFF; safe outputs with the link
    /// down; nothing but a stop for an axis whose link is down.
    #[test]
    fn stp_off_never_moves(config in config(), steps in proptest::collection::vec(step(), 1..400)) {
        let mut pio = Pio::new(config);
        let mut now = 0u64;
        let mut state = axis(report(0, 0, 0), 0);
        // *STP as the debounce defines it: first sample of the current raw run, recognised level.
        let mut stp_raw: Option<(bool, u64)> = None;
        let mut stp_recognised: Option<bool> = None;
        for s in steps {
            now += s.dt_us;
            if let Some((st, al, out)) = s.report {
                state.report = Some(report(st, al, out));
                state.report_at = Some(Instant(now));
            }
            state.link = if s.online { Link::Online } else { Link::Offline };
            state.counters.rejections = state.counters.rejections.wrapping_add(s.rejections);

            let stp = s.inputs & In::STP_N.bits() != 0;
            let run_since = match stp_raw {
                Some((level, since)) if level == stp => since,
                _ => now,
            };
            stp_raw = Some((stp, run_since));
            let before = stp_recognised;
            if now - run_since >= config.debounce.as_micros() {
                stp_recognised = Some(stp);
            }
            let newly_off = stp_recognised == Some(false) && before != Some(false);

            let (out, job) = pio.sample(Instant(now), In::from_bits(s.inputs), &state, s.link_ok);

            let motion = matches!(job, Some(JobKind::MoveToPoint(_) | JobKind::Home(_)));
            prop_assert!(
                !(motion && stp_recognised != Some(true)),
                "motion {:?} with *STP {:?}",
                job,
                stp_recognised
            );
            prop_assert_eq!(pio.inputs().stp_n(), stp_recognised == Some(true));
            if newly_off {
                prop_assert_eq!(job, Some(JobKind::Stop));
            }
            let up = s.link_ok && s.online && state.report.is_some();
            if !up {
                prop_assert_eq!(out, Out::SAFE);
                prop_assert!(
                    job.is_none() || job == Some(JobKind::Stop),
                    "{:?} with the link down",
                    job
                );
            } else {
                prop_assert!(out.link());
            }
            prop_assert_eq!(out.bits() & !Out::MASK, 0);
        }
    }
}

proptest! {
    /// Time going backwards (a caller's bug) and arbitrary words never panic, and the outputs
    /// keep to the defined bits.
    #[test]
    fn arbitrary_samples_never_panic(
        samples in proptest::collection::vec(
            (any::<u64>(), any::<u16>(), any::<bool>(), any::<[u8; 3]>(), any::<u64>()),
            1..100,
        ),
        config in config(),
    ) {
        let mut pio = Pio::new(config);
        for (now, inputs, link_ok, [st, al, out], at) in samples {
            let state = axis(report(st, al, out), at);
            let (outputs, _) = pio.sample(Instant(now), In::from_bits(inputs), &state, link_ok);
            prop_assert_eq!(outputs.bits() & !Out::MASK, 0);
        }
    }
}
