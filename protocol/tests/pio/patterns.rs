//! Patterns 4 and 5 (solenoid valve modes 1 and 2): the ST inputs, level and edge start, the
//! refusal of two ST inputs at once, PE0-PE6 and the reed switches LS0-LS2.

use protocol::engine::JobKind;
use protocol::pio::{
    Band, Config, Pattern, PioInputs as In, PioOutputs as Out, StartMode, TEACHING,
};
use protocol::time::Duration;
use protocol::Pulses;

use crate::{axis, p, report, Rig, DONE_OUT, READY_STATUS};

/// Status: power, servo, home (not running).
const MOVING_STATUS: u8 = 0x0B;
/// OUT: *ALM on, ZFIN (PFIN off: moving).
const MOVING_OUT: u8 = 0xA0;

/// STn (IN n), as a flag.
fn st(n: u8) -> In {
    In::from_bits(1 << n)
}

fn config(pattern: Pattern, start: StartMode) -> Config {
    Config {
        pattern,
        start,
        ..Config::DEFAULT
    }
}

/// A rig in `pattern`, *STP and SON ON, no ST input, the axis at rest at point 3.
fn rig(pattern: Pattern, start: StartMode) -> Rig {
    Rig::with_inputs(
        config(pattern, start),
        axis(report(READY_STATUS, 0, DONE_OUT | 3), 0),
        In::STP_N | In::SON,
    )
}

/// Pattern 5 in edge mode with a settle time of 20 ms (longer than a short pulse is
/// recognised ON), otherwise as [`rig`].
fn slow_settle_rig() -> Rig {
    Rig::with_inputs(
        Config {
            settle: Duration::from_millis(20),
            ..config(Pattern::Solenoid3, StartMode::Edge)
        },
        axis(report(READY_STATUS, 0, DONE_OUT | 3), 0),
        In::STP_N | In::SON,
    )
}

/// The move to point `n` runs (the status shows it), then completes there.
fn complete(rig: &mut Rig, n: u8) {
    rig.status(MOVING_STATUS, 0, MOVING_OUT);
    assert_eq!(rig.run(5), vec![]);
    rig.status(READY_STATUS, 0, DONE_OUT | n);
    rig.run(1);
}

#[test]
fn each_st_input_moves_to_its_point_and_lights_its_pe() {
    for n in 0..=6 {
        let mut rig = rig(Pattern::Solenoid7, StartMode::Edge);
        rig.set(st(n), true);
        // Debounce (6 ms) and settle (6 ms) as for CSTR's position number.
        let jobs = rig.run(20);
        assert_eq!(jobs, vec![(12, JobKind::MoveToPoint(p(n), None))], "ST{n}");
        assert_eq!(rig.out.bits() & 0x7F, 0, "no PE while moving");
        complete(&mut rig, n);
        assert_eq!(rig.out.bits() & 0x7F, 1 << n, "PE{n} on at point {n}");
        assert!(rig.out.pend() && rig.out.alm_n());
        // The ST input still ON (level or edge) does not hold PE back, as CSTR holds PEND.
        rig.set(st(n), false);
        rig.run(10);
        assert_eq!(
            rig.out.bits() & 0x7F,
            1 << n,
            "PE{n} stays after ST{n} is released"
        );
    }
}

#[test]
fn pattern_4_has_no_move_output_and_pm_never_shows() {
    let mut rig = rig(Pattern::Solenoid7, StartMode::Edge);
    // At rest at point 3, but not by the PIO's move: no PE (the controller's PM reads 0 after
    // a home too, which is no point 0).
    assert_eq!(rig.out.bits() & 0x7F, 0);
    rig.status(MOVING_STATUS, 0, MOVING_OUT);
    rig.run(1);
    assert!(!rig.out.contains(Out::MOVE), "OUT6 is PE6, not MOVE");
}

#[test]
fn level_mode_release_mid_move_stops_and_pe_stays_off() {
    let mut rig = rig(Pattern::Solenoid7, StartMode::Level);
    rig.set(st(2), true);
    assert_eq!(rig.run(13), vec![(12, JobKind::MoveToPoint(p(2), None))]);
    rig.status(MOVING_STATUS, 0, MOVING_OUT);
    rig.run(5);
    rig.set(st(2), false);
    // The release is recognised after the debounce time: a stop (decelerating, `d`).
    let jobs = rig.run(10);
    assert_eq!(jobs.len(), 1, "{jobs:?}");
    assert_eq!(jobs[0].1, JobKind::Stop);
    // The axis stops short, PFIN on with PM 0: not point 2, so PE2 (and PEND) stay OFF.
    rig.status(READY_STATUS, 0, DONE_OUT);
    rig.run(5);
    assert_eq!(rig.out.bits() & 0x7F, 0);
    assert!(!rig.out.pend());
}

#[test]
fn edge_mode_release_mid_move_goes_on() {
    let mut rig = rig(Pattern::Solenoid7, StartMode::Edge);
    rig.set(st(5), true);
    assert_eq!(rig.run(13), vec![(12, JobKind::MoveToPoint(p(5), None))]);
    rig.status(MOVING_STATUS, 0, MOVING_OUT);
    rig.set(st(5), false);
    assert_eq!(rig.run(20), vec![], "no stop in edge mode");
    complete(&mut rig, 5);
    assert_eq!(rig.out.bits() & 0x7F, 1 << 5);
}

#[test]
fn level_mode_release_after_arrival_does_nothing() {
    let mut rig = rig(Pattern::Solenoid3, StartMode::Level);
    rig.set(st(1), true);
    assert_eq!(rig.run(13), vec![(12, JobKind::MoveToPoint(p(1), None))]);
    complete(&mut rig, 1);
    rig.set(st(1), false);
    assert_eq!(rig.run(20), vec![]);
}

#[test]
fn two_st_inputs_at_once_are_refused_until_res() {
    let mut rig = rig(Pattern::Solenoid7, StartMode::Level);
    rig.set(st(1), true);
    rig.set(st(4), true);
    assert_eq!(rig.run(20), vec![], "nothing moves");
    assert_eq!(
        rig.pio.take_refused(),
        Some(0b1_0010),
        "ST1 and ST4, for CMER"
    );
    assert_eq!(rig.pio.take_refused(), None);
    assert!(!rig.out.alm_n(), "*ALM OFF, as IAI's alarm 085");
    assert_eq!(rig.out.bits() & 0x7F, 0);
    // Released and one pressed again: still held until RES.
    rig.set(st(4), false);
    rig.set(st(1), false);
    rig.run(10);
    rig.set(st(1), true);
    assert_eq!(rig.run(20), vec![], "refused until RES");
    rig.set(st(1), false);
    rig.run(10);
    rig.set(In::RES, true);
    rig.run(10);
    rig.set(In::RES, false);
    rig.run(10);
    assert!(
        rig.out.alm_n(),
        "RES clears it (no alarm on the bus: nothing sent)"
    );
    rig.set(st(1), true);
    let t = rig.t();
    assert_eq!(
        rig.run(13),
        vec![(t + 12, JobKind::MoveToPoint(p(1), None))]
    );
}

#[test]
fn inputs_that_change_together_within_the_settle_time_are_one_selection() {
    let mut rig = rig(Pattern::Solenoid7, StartMode::Level);
    rig.set(st(1), true);
    assert_eq!(rig.run(13), vec![(12, JobKind::MoveToPoint(p(1), None))]);
    complete(&mut rig, 1);
    // The PLC switches from ST1 to ST2, its output card turning ST1 off 2 ms late.
    rig.set(st(2), true);
    rig.run(2);
    rig.set(st(1), false);
    let t = rig.t();
    let jobs = rig.run(20);
    // Taken once both have settled: 6 ms debounce + 6 ms settle after ST1's change.
    assert_eq!(jobs, vec![(t + 12, JobKind::MoveToPoint(p(2), None))]);
    assert_eq!(rig.pio.take_refused(), None);
}

#[test]
fn an_edge_pulse_shorter_than_the_settle_time_is_taken() {
    // A settle time of 20 ms, an 8 ms pulse: ST2 is recognised OFF again (and the settle time
    // restarted) before the selection is taken; its edge still is.
    let mut rig = slow_settle_rig();
    rig.set(st(2), true);
    rig.run(8);
    rig.set(st(2), false);
    let jobs = rig.run(50);
    // Recognised OFF at 14 ms, taken 20 ms later.
    assert_eq!(jobs, vec![(34, JobKind::MoveToPoint(p(2), None))]);
}

#[test]
fn stp_off_ignores_st_and_stops() {
    let mut rig = rig(Pattern::Solenoid3, StartMode::Edge);
    rig.set(In::STP_N, false);
    let jobs = rig.run(10);
    assert_eq!(
        jobs.iter().map(|j| j.1).collect::<Vec<_>>(),
        vec![JobKind::Stop]
    );
    rig.set(st(0), true);
    assert_eq!(rig.run(20), vec![]);
}

#[test]
fn pattern_5_ignores_st3_and_up_and_cstr() {
    let mut rig = rig(Pattern::Solenoid3, StartMode::Edge);
    for flag in [st(3), st(4), st(5), st(6), In::CSTR] {
        rig.set(flag, true);
        assert_eq!(rig.run(20), vec![], "{flag:?}");
        rig.set(flag, false);
        rig.run(10);
    }
}

#[test]
fn reed_switches_follow_the_position_however_the_axis_got_there() {
    let mut rig = rig(Pattern::Solenoid3, StartMode::Level);
    let band = |mm100: i32| {
        Some(Band {
            position: Pulses(mm100),
            band: 10,
        })
    };
    rig.pio.set_reeds([band(0), band(10_000), band(5_000)]);
    let at = |rig: &mut Rig, position: Option<i32>| {
        rig.axis.position = position.map(Pulses);
        rig.run(1);
        rig.out.bits() & 0x07
    };
    assert_eq!(at(&mut rig, None), 0, "position not read yet");
    assert_eq!(at(&mut rig, Some(0)), 0b001);
    assert_eq!(at(&mut rig, Some(-10)), 0b001, "band's ends included");
    assert_eq!(at(&mut rig, Some(11)), 0);
    assert_eq!(at(&mut rig, Some(9_990)), 0b010);
    assert_eq!(at(&mut rig, Some(5_005)), 0b100);
    // Moving (MOVE on) or in alarm: the switches still show where the axis is.
    rig.status(MOVING_STATUS, 0, MOVING_OUT);
    assert_eq!(at(&mut rig, Some(5_000)), 0b100);
    assert!(rig.out.contains(Out::MOVE));
    rig.status(0x03, 0x61, 0x03);
    assert_eq!(at(&mut rig, Some(5_000)), 0b100);
    assert!(!rig.out.alm_n());
    // An unknown point has no switch; with the link down every output is OFF.
    rig.pio.set_reeds([None, None, band(5_000)]);
    assert_eq!(at(&mut rig, Some(0)), 0);
    rig.link_ok = false;
    assert_eq!(at(&mut rig, Some(5_000)), 0);
    assert_eq!(rig.out, Out::SAFE);
}

#[test]
fn the_failsafe_shows_on_alm_only_in_the_solenoid_patterns() {
    let word = Out::PEND | Out::ALM_N | Out::from_bits(0b100);
    assert_eq!(
        word.with_failsafe(2, Pattern::Positioning),
        Out::PEND | Out::PM2
    );
    assert_eq!(word.with_failsafe(2, Pattern::Solenoid7), Out::PEND);
    assert_eq!(
        word.with_failsafe(2, Pattern::Solenoid3),
        Out::PEND | Out::PM4
    );
    assert_eq!(word.with_failsafe(0, Pattern::Solenoid7), word);
}

#[test]
fn each_pattern_names_its_ports() {
    assert_eq!(Pattern::Positioning.inputs(), 0xF83F);
    assert_eq!(Pattern::Positioning.outputs(), 0x7CCF);
    assert_eq!(Pattern::Solenoid7.inputs(), 0xD87F);
    assert_eq!(Pattern::Solenoid7.outputs(), 0x7CFF, "PE6 on MOVE's port");
    assert_eq!(Pattern::Solenoid3.inputs(), 0xD807);
    assert_eq!(Pattern::Solenoid3.outputs(), 0x7CC7);
    for pattern in Pattern::ALL {
        let built = pattern != Pattern::Teaching || TEACHING;
        assert_eq!(Pattern::from_code(pattern.code()), built.then_some(pattern));
    }
    assert_eq!(Pattern::Teaching.inputs(), 0xFBFF);
    assert_eq!(Pattern::Teaching.outputs(), 0x7ECF);
    for code in [2, 3, 6, 0xFFFF] {
        assert_eq!(Pattern::from_code(code), None);
    }
}

// ------------------------------------------------------- regressions (review of the patterns)

fn kinds(jobs: Vec<(u64, JobKind)>) -> Vec<JobKind> {
    jobs.into_iter().map(|(_, j)| j).collect()
}

/// A level-mode hold outlives a link down: its release still stops the axis (the wait for the
/// move was dropped with the link; the controller may still be running it).
#[test]
fn a_level_hold_outlives_a_link_down() {
    let mut rig = rig(Pattern::Solenoid7, StartMode::Level);
    rig.set(st(2), true);
    assert_eq!(kinds(rig.run(13)), vec![JobKind::MoveToPoint(p(2), None)]);
    rig.status(MOVING_STATUS, 0, MOVING_OUT);
    rig.run(3);
    rig.link_ok = false;
    rig.run(20);
    rig.set(st(2), false);
    assert_eq!(kinds(rig.run(10)), vec![JobKind::Stop]);
}

/// Two ST inputs while a level-mode move runs: refused, and the running move stops (its hold is
/// gone: nothing else would stop it).
#[test]
fn a_refusal_during_a_level_move_stops_it() {
    let mut rig = rig(Pattern::Solenoid7, StartMode::Level);
    rig.set(st(0), true);
    assert_eq!(kinds(rig.run(13)), vec![JobKind::MoveToPoint(p(0), None)]);
    rig.status(MOVING_STATUS, 0, MOVING_OUT);
    rig.set(st(1), true);
    assert_eq!(kinds(rig.run(20)), vec![JobKind::Stop]);
    assert!(!rig.out.alm_n());
    // HOME is refused too until RES (the PLC sees *ALM OFF: nothing moves).
    rig.set(In::HOME, true);
    assert_eq!(rig.run(20), vec![]);
    rig.set(In::HOME, false);
    rig.set(st(0), false);
    rig.set(st(1), false);
    assert_eq!(rig.run(20), vec![]);
}

/// Level mode, ST0 released and ST1 pressed in the same scan mid-move: the stop, then the move
/// to point 1 (the stop does not drop the new start).
#[test]
fn switching_st_inputs_mid_move_stops_then_starts_the_new_one() {
    let mut rig = rig(Pattern::Solenoid7, StartMode::Level);
    rig.set(st(0), true);
    assert_eq!(kinds(rig.run(13)), vec![JobKind::MoveToPoint(p(0), None)]);
    rig.status(MOVING_STATUS, 0, MOVING_OUT);
    rig.run(3);
    rig.set(st(0), false);
    rig.set(st(1), true);
    assert_eq!(
        kinds(rig.run(20)),
        vec![JobKind::Stop, JobKind::MoveToPoint(p(1), None)]
    );
}

/// A release on the very sample whose status shows the point reached: the move is done, not
/// cut short (no stop, PE on).
#[test]
fn a_release_on_arrival_is_after_the_arrival() {
    let mut rig = rig(Pattern::Solenoid7, StartMode::Level);
    rig.set(st(4), true);
    assert_eq!(kinds(rig.run(13)), vec![JobKind::MoveToPoint(p(4), None)]);
    rig.status(MOVING_STATUS, 0, MOVING_OUT);
    rig.run(3);
    rig.set(st(4), false);
    // The release is recognised 6 ms later: let the status show the arrival on that sample.
    assert_eq!(rig.run(5), vec![]);
    rig.status(READY_STATUS, 0, DONE_OUT | 4);
    assert_eq!(rig.run(10), vec![], "no stop");
    assert_eq!(rig.out.bits() & 0x7F, 1 << 4);
}

/// RES while the controller is in alarm resets the alarm and the refusal together.
#[test]
fn res_during_an_alarm_also_clears_a_refusal() {
    let mut rig = rig(Pattern::Solenoid3, StartMode::Edge);
    rig.set(st(0), true);
    rig.set(st(2), true);
    rig.run(20);
    rig.set(st(0), false);
    rig.set(st(2), false);
    rig.status(0x03, 0x61, 0x03);
    rig.run(10);
    rig.set(In::RES, true);
    assert_eq!(kinds(rig.run(10)), vec![JobKind::AlarmReset]);
    rig.set(In::RES, false);
    rig.status(READY_STATUS, 0, DONE_OUT);
    rig.run(10);
    assert!(rig.out.alm_n(), "no refusal left");
    rig.set(st(2), true);
    assert_eq!(kinds(rig.run(20)), vec![JobKind::MoveToPoint(p(2), None)]);
}

/// An edge-mode ST pulse that HOME drops (HOME within its settle time) leaves nothing behind:
/// a later single ST pulse is not refused as two.
#[test]
fn home_drops_a_waiting_st_edge_whole() {
    // A settle time of 20 ms, so that HOME comes while ST0's edge waits.
    let mut rig = slow_settle_rig();
    rig.set(st(0), true);
    rig.run(8);
    rig.set(st(0), false);
    rig.set(In::HOME, true);
    let jobs = kinds(rig.run(20));
    assert_eq!(jobs.len(), 1, "{jobs:?}");
    assert!(matches!(jobs[0], JobKind::Home(_)));
    rig.set(In::HOME, false);
    rig.status(READY_STATUS, 0, DONE_OUT);
    rig.run(10);
    rig.set(st(1), true);
    rig.run(8);
    rig.set(st(1), false);
    assert_eq!(kinds(rig.run(40)), vec![JobKind::MoveToPoint(p(1), None)]);
    assert_eq!(rig.pio.take_refused(), None);
}
