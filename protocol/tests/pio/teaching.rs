//! Pattern 1 (teaching): MODE and MODES, the JOG inputs (held and inching), PWRT and WEND.

use protocol::engine::JobKind;
use protocol::pio::{Config, Jog, Pattern, PioInputs as In, PioOutputs as Out};
use protocol::{Acceleration, Pulses, Velocity};

use crate::{axis, base, p, report, Rig, DONE_OUT, READY_STATUS};

/// Status: power, servo, home (not running).
const MOVING_STATUS: u8 = 0x0B;
/// OUT: *ALM on, ZFIN (PFIN off: moving).
const MOVING_OUT: u8 = 0xA0;

const JOG: Jog = Jog {
    plus_end: Pulses(-8000),
    minus_end: Pulses(0),
    plus_step: Pulses(-10),
    minus_step: Pulses(10),
    velocity: match Velocity::new(500) {
        Some(v) => v,
        None => panic!(),
    },
    acceleration: match Acceleration::new(30) {
        Some(a) => a,
        None => panic!(),
    },
};

/// A rig in pattern 1, MODE OFF, the jog known, the axis at rest at point 3.
fn rig() -> Rig {
    let mut rig = Rig::with_axis(
        Config {
            pattern: Pattern::Teaching,
            ..Config::DEFAULT
        },
        axis(report(READY_STATUS, 0, DONE_OUT | 3), 0),
    );
    rig.pio.set_jog(Some(JOG));
    rig
}

/// MODE ON, recognised: teaching mode.
fn teaching() -> Rig {
    let mut rig = rig();
    rig.set(In::ST6, true);
    assert_eq!(rig.run(10), vec![]);
    assert!(rig.out.contains(Out::MODES), "MODES");
    rig
}

fn jog_to(end: Pulses) -> JobKind {
    JobKind::Jog {
        end,
        velocity: JOG.velocity,
        acceleration: JOG.acceleration,
    }
}

fn inch(step: i32) -> JobKind {
    JobKind::DirectMove {
        target: Pulses(step),
        relative: true,
        velocity: JOG.velocity,
        acceleration: JOG.acceleration,
    }
}

fn kinds(jobs: Vec<(u64, JobKind)>) -> Vec<JobKind> {
    jobs.into_iter().map(|(_, j)| j).collect()
}

#[test]
fn mode_off_is_pattern_0() {
    let mut rig = rig();
    assert!(!rig.out.contains(Out::MODES));
    rig.set(In::CSTR, true);
    assert_eq!(kinds(rig.run(10)), vec![JobKind::MoveToPoint(p(3), None)]);
    rig.set(In::CSTR, false);
    rig.set(In::JOG_PLUS, true);
    assert_eq!(rig.run(20), vec![], "no jog outside teaching mode");
}

#[test]
fn mode_waits_for_the_axis_to_rest() {
    let mut rig = rig();
    rig.status(MOVING_STATUS, 0, MOVING_OUT);
    rig.set(In::ST6, true);
    rig.run(20);
    assert!(!rig.out.contains(Out::MODES), "not while it moves");
    rig.status(READY_STATUS, 0, DONE_OUT | 3);
    rig.run(1);
    assert!(rig.out.contains(Out::MODES));
}

#[test]
fn a_held_jog_runs_to_the_stroke_end_and_stops_on_release() {
    let mut rig = teaching();
    rig.set(In::JOG_PLUS, true);
    assert_eq!(kinds(rig.run(10)), vec![jog_to(JOG.plus_end)]);
    assert_eq!(rig.run(50), vec![], "held: one jog");
    rig.set(In::JOG_PLUS, false);
    assert_eq!(kinds(rig.run(10)), vec![JobKind::Stop]);
    rig.set(In::JOG_MINUS, true);
    assert_eq!(kinds(rig.run(10)), vec![jog_to(JOG.minus_end)]);
    // The other JOG input too: both ON stops.
    rig.set(In::JOG_PLUS, true);
    assert_eq!(kinds(rig.run(10)), vec![JobKind::Stop]);
}

#[test]
fn jisl_inches_one_step_per_edge() {
    let mut rig = teaching();
    rig.set(In::JISL, true);
    rig.run(10);
    for _ in 0..2 {
        rig.set(In::JOG_PLUS, true);
        assert_eq!(kinds(rig.run(10)), vec![inch(-10)]);
        rig.set(In::JOG_PLUS, false);
        assert_eq!(rig.run(10), vec![], "no stop on release: a step");
    }
    rig.set(In::JOG_MINUS, true);
    assert_eq!(kinds(rig.run(10)), vec![inch(10)]);
}

#[test]
fn leaving_teaching_mode_stops_a_jog() {
    let mut rig = teaching();
    rig.set(In::JOG_MINUS, true);
    assert_eq!(kinds(rig.run(10)), vec![jog_to(JOG.minus_end)]);
    rig.set(In::ST6, false);
    assert_eq!(kinds(rig.run(10)), vec![JobKind::Stop]);
    assert!(!rig.out.contains(Out::MODES));
}

#[test]
fn stp_off_stops_a_jog_and_blocks_the_next() {
    let mut rig = teaching();
    rig.set(In::JOG_PLUS, true);
    assert_eq!(kinds(rig.run(10)), vec![jog_to(JOG.plus_end)]);
    rig.set(In::STP_N, false);
    assert_eq!(kinds(rig.run(10)), vec![JobKind::Stop]);
    rig.set(In::JOG_PLUS, false);
    rig.run(10);
    rig.set(In::JOG_PLUS, true);
    assert_eq!(rig.run(20), vec![], "nothing while *STP is OFF");
}

#[test]
fn pwrt_asks_for_the_selected_point_and_wend_follows_the_store_and_pwrt() {
    let mut rig = teaching();
    rig.select(7);
    rig.run(10);
    rig.set(In::CSTR, true);
    assert_eq!(rig.run(20), vec![], "no move in teaching mode");
    assert_eq!(rig.pio.take_teach(), Some(p(7)));
    assert_eq!(rig.pio.take_teach(), None, "once");
    assert!(!rig.out.pend(), "WEND OFF until stored");
    rig.pio.taught(true);
    rig.run(1);
    assert!(rig.out.pend(), "WEND");
    rig.set(In::CSTR, false);
    rig.run(10);
    assert!(!rig.out.pend(), "WEND OFF with PWRT");
    // A failed store leaves WEND OFF.
    rig.set(In::CSTR, true);
    rig.run(20);
    assert_eq!(rig.pio.take_teach(), Some(p(7)));
    rig.pio.taught(false);
    rig.run(5);
    assert!(!rig.out.pend());
}

#[test]
fn without_the_jog_known_the_jog_inputs_do_nothing() {
    let mut rig = teaching();
    rig.pio.set_jog(None);
    rig.set(In::JOG_PLUS, true);
    assert_eq!(rig.run(20), vec![]);
    assert_eq!(rig.pio.inputs(), base() | In::ST6 | In::JOG_PLUS);
}

/// A held jog outlives a link down: its release still stops the axis.
#[test]
fn a_held_jog_outlives_a_link_down() {
    let mut rig = teaching();
    rig.set(In::JOG_PLUS, true);
    assert_eq!(kinds(rig.run(10)), vec![jog_to(JOG.plus_end)]);
    rig.link_ok = false;
    rig.run(20);
    rig.set(In::JOG_PLUS, false);
    assert_eq!(kinds(rig.run(10)), vec![JobKind::Stop]);
}

/// MODE turned OFF while a PWRT waits for PC1-PC8 to settle: the PWRT is dropped, it does not
/// become a CSTR.
#[test]
fn a_pwrt_never_becomes_a_move() {
    let mut rig = teaching();
    rig.select(5);
    rig.set(In::CSTR, true);
    // The PWRT and PC1-PC8 change together: the strobe waits for them to settle (until 12 ms),
    // and MODE is recognised OFF at 8 ms.
    rig.run(2);
    rig.set(In::ST6, false);
    assert_eq!(rig.run(20), vec![]);
    assert_eq!(rig.pio.take_teach(), None);
}

/// A pattern's PIO with a jog under way is in motion (the node stops the axis when PIOPAT
/// replaces it).
#[test]
fn a_jog_is_motion() {
    let mut rig = teaching();
    assert!(!rig.pio.in_motion());
    rig.set(In::JOG_MINUS, true);
    rig.run(10);
    assert!(rig.pio.in_motion());
}
