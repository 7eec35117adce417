//! A stop is never refused, lost or late (issue 33): taken first and unconditionally in every
//! face, and owed to an axis that did not answer it until the axis answers again.

use protocol::engine::WAITING_PER_AXIS;
use protocol::modbus::Exception;
use protocol::pio::PioInputs;
use protocol::plc::map::*;
use protocol::time::Instant;
use protocol::Command;
use rc_host::node_harness::NodeHarness;

use crate::{axis, coil, gateway, home, read, unit, write, MS, S};

/// A move that runs for most of a minute (90 mm at 2 mm/s): what a held jog is to the bus.
const SLOW_MOVE: [u16; 7] = [0, 90_00, 0, 10, 0, 2_00, 30];

/// Axes 0..n homed, with the PLC watchdog off (so that only the stop under test stops).
fn homed(n: u8) -> NodeHarness {
    let mut h = gateway(n);
    write(&mut h, 63, G_WATCHDOG, &[0]).unwrap();
    for a in 0..n {
        home(&mut h, a);
    }
    h
}

fn moving(h: &NodeHarness, a: u8) -> bool {
    h.bus.controller(axis(a)).unwrap().moving()
}

/// `d`s sent to axis `a` at or after `since`.
fn stops_sent(h: &NodeHarness, a: u8, since: u64) -> usize {
    h.sent
        .iter()
        .filter(|(t, r)| *t >= since && r.axis == axis(a) && r.command == Command::CancelMotion)
        .count()
}

/// Fill axis `a`'s queue: a slow move running, CSTR edges waiting behind it until it has no
/// room (and keeps none: the move runs for most of a minute).
fn fill_queue(h: &mut NodeHarness, a: u8) {
    write(h, unit(a), DIRECT, &SLOW_MOVE).unwrap();
    for _ in 0..WAITING_PER_AXIS {
        write(h, unit(a), DRG1, &[DRG1_SON | DRG1_CSTR]).unwrap();
        write(h, unit(a), DRG1, &[DRG1_SON]).unwrap();
    }
    assert_eq!(h.node.gateway().engine().room(axis(a)), 0, "queue full");
}

/// Issue 33's first reproduction: with the queue full, the usual e-stop word (STP with SON
/// dropping) answered 04 and sent nothing. Now the stop goes first, the servo-off after it.
#[test]
fn a_stop_with_son_dropping_is_taken_when_the_queue_is_full() {
    let mut h = homed(1);
    fill_queue(&mut h, 0);
    let at = h.now;
    assert_eq!(write(&mut h, unit(0), DRG1, &[DRG1_STP]), Ok(()));
    assert_eq!(read(&mut h, unit(0), DRG1, 1).unwrap(), [DRG1_STP]);
    h.run_for(200 * MS);
    assert!(stops_sent(&h, 0, at) >= 1, "the stop went out");
    let servo_off = h
        .sent
        .iter()
        .any(|(t, r)| *t >= at && r.axis == axis(0) && r.command == Command::Servo(false));
    assert!(servo_off, "SON off was taken after the stop");
    assert!(!h.node.gateway().engine().busy(axis(0)), "queue emptied");
    assert!(!moving(&h, 0));
}

/// Issue 33's second reproduction: a broadcast STP ended at the first axis that refused it,
/// leaving the next one's move queued. Now every axis takes it.
#[test]
fn a_broadcast_stop_reaches_every_axis_even_when_one_refuses_the_rest() {
    let mut h = homed(2);
    fill_queue(&mut h, 0);
    write(&mut h, unit(1), DIRECT, &SLOW_MOVE).unwrap();
    write(&mut h, unit(1), DRG1, &[DRG1_SON | DRG1_CSTR]).unwrap();
    h.run_for(100 * MS);
    assert!(moving(&h, 1));
    let at = h.now;
    write(&mut h, 0, DRG1, &[DRG1_STP]).unwrap();
    h.run_for(300 * MS);
    for a in 0..2 {
        assert_eq!(
            read(&mut h, unit(a), DRG1, 1).unwrap(),
            [DRG1_STP],
            "axis {a}"
        );
        assert!(stops_sent(&h, a, at) >= 1, "axis {a} got its stop");
        assert!(
            !h.node.gateway().engine().busy(axis(a)),
            "axis {a}: nothing queued"
        );
        assert!(!moving(&h, a), "axis {a} at rest");
    }
}

/// A write with a stop to an axis that does not answer is not refused: the stop is owed.
#[test]
fn a_stop_to_an_offline_axis_is_taken_and_owed() {
    let mut h = homed(2);
    h.bus.set_cut(axis(1), true);
    h.run_for(2 * S);
    assert_eq!(read(&mut h, unit(1), LINK, 1).unwrap(), [2], "offline");
    // SON dropping with STP: before, 04 (Offline) and no stop at all.
    assert_eq!(write(&mut h, unit(1), DRG1, &[DRG1_STP]), Ok(()));
    h.run_for(S);
    assert_eq!(read(&mut h, unit(1), LINK, 1).unwrap(), [3], "owed a stop");
    // A command without a stop is still refused while it does not answer.
    assert_eq!(
        write(&mut h, unit(1), DRG1, &[DRG1_SON | DRG1_HOME]),
        Err(Exception::ServerDeviceFailure)
    );
}

/// PIOAXIS 0, its *STP and SON inputs ON.
fn wire_drive_axis_0(h: &mut NodeHarness) {
    write(h, 63, G_PIO_AXIS, &[0]).unwrap();
    h.inputs = Some(PioInputs::from_bits(
        PioInputs::STP_N.bits() | PioInputs::SON.bits(),
    ));
    h.run_for(200 * MS);
}

/// Axis 0 on [`SLOW_MOVE`], then its wire cut mid-move.
fn move_slowly_then_cut(h: &mut NodeHarness) {
    write(h, unit(0), DIRECT, &SLOW_MOVE).unwrap();
    h.run_for(500 * MS);
    assert!(moving(h, 0), "the move runs");
    h.bus.set_cut(axis(0), true);
}

/// The owed stop: a move running (a held jog, as the bus sees it), the wire cut, the stop
/// applied by `stop` and unanswered; the wire mended with the controller still moving. The
/// first frame the axis gets after that is `d`, it ends at rest, and LINK reads 3 meanwhile.
fn owed_stop_is_the_first_frame_after_the_wire_is_mended(
    pio: bool,
    stop: impl FnOnce(&mut NodeHarness),
) {
    let mut h = homed(2);
    if pio {
        wire_drive_axis_0(&mut h);
    }
    move_slowly_then_cut(&mut h);
    stop(&mut h);
    h.run_for(2 * S);
    assert_eq!(read(&mut h, unit(0), LINK, 1).unwrap(), [3], "owed a stop");
    assert!(moving(&h, 0), "nothing reached it");
    let mended = h.now;
    h.bus.set_cut(axis(0), false);
    h.run_for(5 * S);
    let first = h
        .sent
        .iter()
        .find(|(t, r)| *t >= mended && r.axis == axis(0))
        .map(|(_, r)| r.command);
    assert_eq!(
        first,
        Some(Command::CancelMotion),
        "the first frame is the stop"
    );
    assert!(!moving(&h, 0), "at rest");
    assert_eq!(
        read(&mut h, unit(0), LINK, 1).unwrap(),
        [1],
        "online, nothing owed"
    );
}

#[test]
fn an_unanswered_drg1_stop_is_owed_until_the_axis_answers() {
    owed_stop_is_the_first_frame_after_the_wire_is_mended(false, |h| {
        write(h, unit(0), DRG1, &[DRG1_SON | DRG1_STP]).unwrap();
    });
}

#[test]
fn an_unanswered_stop_coil_is_owed_until_the_axis_answers() {
    owed_stop_is_the_first_frame_after_the_wire_is_mended(false, |h| {
        coil(h, unit(0), COIL_STOP, true).unwrap();
    });
}

#[test]
fn an_unanswered_broadcast_stop_is_owed_until_the_axis_answers() {
    owed_stop_is_the_first_frame_after_the_wire_is_mended(false, |h| {
        write(h, 0, DRG1, &[DRG1_SON | DRG1_STP]).unwrap();
    });
}

#[test]
fn an_unanswered_stop_input_stop_is_owed_until_the_axis_answers() {
    owed_stop_is_the_first_frame_after_the_wire_is_mended(false, |h| {
        h.node.set_stop_input(Instant(h.now), true);
    });
}

#[test]
fn an_unanswered_pio_stp_stop_is_owed_until_the_axis_answers() {
    owed_stop_is_the_first_frame_after_the_wire_is_mended(true, |h| {
        h.inputs = Some(PioInputs::from_bits(PioInputs::SON.bits()));
    });
}

/// The stop input opens: every axis' first stop goes before any other frame, the resends of
/// the ones that got no answer included (an offline axis' resend used to go before the next
/// axis' first stop).
#[test]
fn every_first_stop_goes_before_any_resend_or_poll() {
    let mut h = homed(4);
    h.bus.set_cut(axis(0), true);
    h.bus.set_cut(axis(2), true);
    h.run_for(2 * S);
    let at = h.now;
    h.node.set_stop_input(Instant(h.now), true);
    h.run_for(S);
    let after: Vec<_> = h
        .sent
        .iter()
        .filter(|(t, _)| *t >= at)
        .map(|(_, r)| *r)
        .collect();
    let firsts: Vec<u8> = after.iter().take(4).map(|r| r.axis.get()).collect();
    assert!(
        after
            .iter()
            .take(4)
            .all(|r| r.command == Command::CancelMotion),
        "four stops first: {after:?}"
    );
    let mut sorted = firsts.clone();
    sorted.sort_unstable();
    assert_eq!(sorted, [0, 1, 2, 3], "one to each axis: {firsts:?}");
    assert_eq!(&firsts[..2], &[1, 3], "the axes known to answer first");
}

mod property {
    //! From any reachable state, a write that contains a stop leaves its axis stopped or owing
    //! a stop, is never refused, and the axis ends at rest once it can hear.

    use proptest::prelude::*;

    use super::*;

    /// What a PLC (and a cabinet) did before the stop.
    #[derive(Clone, Debug)]
    enum Op {
        Drg1(u8, u16),
        Direct(u8, u16, u16),
        Posr(u8, u16),
        Coil(u8, u16, bool),
        Cut(u8, bool),
        Wait(u16),
    }

    /// The write that carries the stop.
    #[derive(Clone, Copy, Debug)]
    enum StopWrite {
        Stp,
        Emg,
        SonOff,
        StopCoil,
        StpCoil,
        SonCoilOff,
        Broadcast,
    }

    fn op() -> impl Strategy<Value = Op> {
        let axis = 0u8..2;
        prop_oneof![
            (axis.clone(), 0u16..=u16::MAX).prop_map(|(a, v)| Op::Drg1(a, v & DRG1_SUPPORTED)),
            (axis.clone(), 0u16..100, 1u16..200).prop_map(|(a, mm, v)| Op::Direct(a, mm, v)),
            (axis.clone(), 0u16..5).prop_map(|(a, p)| Op::Posr(a, p)),
            (
                axis.clone(),
                prop::sample::select(vec![COIL_SON, COIL_ALRS, COIL_STP, COIL_HOME, COIL_STOP]),
                any::<bool>()
            )
                .prop_map(|(a, c, on)| Op::Coil(a, c, on)),
            (axis, any::<bool>()).prop_map(|(a, cut)| Op::Cut(a, cut)),
            (0u16..3000).prop_map(Op::Wait),
        ]
    }

    fn stop_write() -> impl Strategy<Value = StopWrite> {
        prop::sample::select(vec![
            StopWrite::Stp,
            StopWrite::Emg,
            StopWrite::SonOff,
            StopWrite::StopCoil,
            StopWrite::StpCoil,
            StopWrite::SonCoilOff,
            StopWrite::Broadcast,
        ])
    }

    fn apply(h: &mut NodeHarness, cut: &mut [bool; 2], op: &Op) {
        // Refusals are part of the state reached: ignored.
        let _ = match *op {
            Op::Drg1(a, v) => write(h, unit(a), DRG1, &[v]),
            Op::Direct(a, mm, v) => {
                write(h, unit(a), DIRECT, &[0, mm * 100, 0, 10, 0, v * 100, 30])
            }
            Op::Posr(a, p) => write(h, unit(a), POSR, &[p]),
            Op::Coil(a, c, on) => coil(h, unit(a), c, on),
            Op::Cut(a, c) => {
                cut[usize::from(a)] = c;
                h.bus.set_cut(axis(a), c);
                Ok(())
            }
            Op::Wait(ms) => {
                h.run_for(u64::from(ms) * MS);
                Ok(())
            }
        };
    }

    /// Found by the property below (its shrunk case): axis 1 on a long slow move, axis 0's wire
    /// cut, a stop for axis 0. With one axis online the cycle is one transaction, the mover was
    /// always at its limit and the offline axis never probed: its owed stop never went, even
    /// after its wire was back.
    #[test]
    fn an_owed_stop_reaches_its_axis_once_it_hears_while_another_moves() {
        let mut h = homed(2);
        let mut cut = [false; 2];
        for op in &[Op::Direct(1, 68, 1), Op::Direct(0, 0, 1), Op::Cut(0, true)] {
            apply(&mut h, &mut cut, op);
        }
        let drg1 = read(&mut h, unit(0), DRG1, 1).unwrap()[0];
        let plain = drg1 & !(DRG1_STP | DRG1_EMG | DRG1_CSTR | DRG1_HOME | DRG1_ALRS);
        assert_eq!(write(&mut h, unit(0), DRG1, &[plain | DRG1_STP]), Ok(()));
        h.run_for(3 * S);
        assert!(
            h.node.gateway().engine().stop_owed(axis(0)),
            "owed while cut"
        );
        assert!(moving(&h, 1), "the other axis still moves");
        h.bus.set_cut(axis(0), false);
        h.run_for(5 * S);
        assert!(
            !h.node.gateway().engine().stop_owed(axis(0)),
            "taken once it hears"
        );
        assert!(!moving(&h, 0), "at rest");
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]
        #[test]
        fn a_write_with_a_stop_leaves_its_axis_stopped_or_owing_one(
            ops in prop::collection::vec(op(), 0..10),
            stop in stop_write(),
            a in 0u8..2,
        ) {
            let mut h = homed(2);
            let mut cut = [false; 2];
            for op in &ops {
                apply(&mut h, &mut cut, op);
            }
            // Make the stop an edge from where DRG1 is now (the unpausing write may be refused:
            // then the stop write below carries no edge, and the case says nothing).
            let now = read(&mut h, unit(a), DRG1, 1).unwrap()[0];
            let plain = now & !(DRG1_STP | DRG1_EMG | DRG1_CSTR | DRG1_HOME | DRG1_ALRS);
            match stop {
                StopWrite::Stp | StopWrite::Emg | StopWrite::StpCoil | StopWrite::Broadcast => {
                    let _ = write(&mut h, unit(a), DRG1, &[plain]);
                }
                StopWrite::SonOff | StopWrite::SonCoilOff => {
                    let _ = write(&mut h, unit(a), DRG1, &[plain | DRG1_SON]);
                }
                StopWrite::StopCoil => {}
            }
            let drg1 = read(&mut h, unit(a), DRG1, 1).unwrap()[0];
            let edge = match stop {
                StopWrite::Stp | StopWrite::Emg | StopWrite::StpCoil | StopWrite::Broadcast => {
                    drg1 & (DRG1_STP | DRG1_EMG) == 0
                }
                StopWrite::SonOff | StopWrite::SonCoilOff => drg1 & DRG1_SON != 0,
                StopWrite::StopCoil => true,
            };
            prop_assume!(edge);
            let at = h.now;
            let answer = match stop {
                StopWrite::Stp => write(&mut h, unit(a), DRG1, &[drg1 | DRG1_STP | DRG1_CSTR]),
                StopWrite::Emg => write(&mut h, unit(a), DRG1, &[(drg1 | DRG1_EMG | DRG1_HOME) & !DRG1_SON]),
                StopWrite::SonOff => write(&mut h, unit(a), DRG1, &[(drg1 & !DRG1_SON) | DRG1_ALRS]),
                StopWrite::StopCoil => coil(&mut h, unit(a), COIL_STOP, true),
                StopWrite::StpCoil => coil(&mut h, unit(a), COIL_STP, true),
                StopWrite::SonCoilOff => coil(&mut h, unit(a), COIL_SON, false),
                StopWrite::Broadcast => write(&mut h, 0, DRG1, &[DRG1_STP]),
            };
            prop_assert_eq!(answer, Ok(()), "a write with a stop is never refused");
            h.run_for(3 * S);
            prop_assert!(stops_sent(&h, a, at) >= 1, "its stop went out");
            if cut[usize::from(a)] {
                prop_assert!(h.node.gateway().engine().stop_owed(axis(a)), "owed while cut");
                prop_assert_eq!(read(&mut h, unit(a), LINK, 1).unwrap(), vec![3]);
            } else {
                prop_assert!(!moving(&h, a), "stopped");
            }
            // Once it can hear, it ends at rest.
            h.bus.set_cut(axis(a), false);
            h.run_for(5 * S);
            prop_assert!(!moving(&h, a), "at rest once it hears");
            prop_assert!(!h.node.gateway().engine().stop_owed(axis(a)));
        }
    }
}

/// The hand-over (issue 33, item 4): a commissioning PC's requests armed the PLC watchdog and
/// the PC is unplugged; the watchdog trips on a machine driven by its wires alone. One RES pulse
/// acknowledges it (before, RES was refused for as long as the silence lasted: for ever), the
/// watchdog stays disarmed while no master speaks, and the wires drive the axis again.
#[test]
fn one_res_pulse_clears_the_watchdog_latch_a_commissioning_pc_left_behind() {
    let pins = |bits: &[PioInputs]| PioInputs::from_bits(bits.iter().fold(0, |b, p| b | p.bits()));
    let mut h = gateway(1);
    // Commissioning over Modbus: the wire-driven axis named, the watchdog at its default.
    write(&mut h, 63, G_PIO_AXIS, &[0]).unwrap();
    h.inputs = Some(pins(&[PioInputs::STP_N, PioInputs::SON]));
    h.run_for(300 * MS);
    assert_eq!(read(&mut h, 63, G_WATCHDOG, 1).unwrap(), [1000]);
    // The PC is unplugged: silence.
    h.run_for(3 * S);
    assert_eq!(h.node.gateway().failsafe() & 1, 1, "the watchdog tripped");
    let before = h.sent.len();
    h.inputs = Some(pins(&[PioInputs::STP_N, PioInputs::SON, PioInputs::HOME]));
    h.run_for(100 * MS);
    let homing = |h: &NodeHarness, from: usize| {
        h.sent[from..]
            .iter()
            .any(|(_, r)| matches!(r.command, Command::Home(_)))
    };
    assert!(!homing(&h, before), "held by the latch");
    // One RES pulse, the master still silent.
    h.inputs = Some(pins(&[PioInputs::STP_N, PioInputs::SON, PioInputs::RES]));
    h.run_for(50 * MS);
    h.inputs = Some(pins(&[PioInputs::STP_N, PioInputs::SON]));
    h.run_for(50 * MS);
    assert_eq!(h.node.gateway().failsafe(), 0, "acknowledged by the pulse");
    assert_eq!(h.node.gateway().watchdog_deadline(), None, "disarmed");
    // The wires drive it, and nothing trips while no master speaks.
    let before = h.sent.len();
    h.inputs = Some(pins(&[PioInputs::STP_N, PioInputs::SON, PioInputs::HOME]));
    h.run_for(5 * S);
    assert!(homing(&h, before), "HOME by wire runs");
    assert_eq!(h.node.gateway().failsafe(), 0, "no new trip while silent");
    // A master that comes back arms it again.
    read(&mut h, 63, G_FAILSAFE, 1).unwrap();
    assert!(
        h.node.gateway().watchdog_deadline().is_some(),
        "armed again"
    );
}

/// The PIO repeats its *STP stop every 100 ms while its axis last reported moving. With the wire
/// cut, each repeat used to start the unanswered stop's tries over: the axis never went offline
/// nor owed its stop, and a fresh first stop always waiting kept every other axis off the bus
/// (found by tests/emu/test_stops.py). A repeat now takes over the tries it supersedes.
#[test]
fn a_repeated_pio_stop_to_a_cut_axis_leaves_the_bus_to_the_others() {
    let mut h = homed(2);
    // Controllers that answer late (RTIM 150 ms): one try of a stop outlasts the PIO's repeat.
    write(&mut h, 63, G_BUS_RTIM, &[150]).unwrap();
    write(&mut h, 63, G_APPLY, &[1]).unwrap();
    h.run_for(3 * S);
    assert_eq!(h.node.gateway().engine().config().rtim.get(), 150);
    wire_drive_axis_0(&mut h);
    move_slowly_then_cut(&mut h);
    h.inputs = Some(PioInputs::from_bits(PioInputs::SON.bits()));
    h.run_for(2 * S);
    assert_eq!(
        read(&mut h, unit(0), LINK, 1).unwrap(),
        [3],
        "owed, not online"
    );
    let at = h.now;
    h.run_for(S);
    let polls = h
        .sent
        .iter()
        .filter(|(t, r)| *t >= at && r.axis == axis(1))
        .count();
    assert!(
        polls >= 3,
        "axis 1 keeps its share of the bus: {polls} frames in 1 s"
    );
}
