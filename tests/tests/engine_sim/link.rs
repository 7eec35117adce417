//! The link: establishment, a silent or power-cycled axis that rejoins without stalling the
//! others, every fault kind survived and counted, sixteen axes polled.

use protocol::engine::*;
use protocol::line::Baud;
use protocol::*;

use rc_host::harness::Harness;
use rc_tools::sim::{Bus, BusConfig};

use crate::{axis, established, MS, S};

#[test]
fn establishment_brings_every_axis_to_115200_and_rtim_3() {
    let mut h = established(4);
    for a in 0..4 {
        let c = h.bus.controller(axis(a)).unwrap();
        assert_eq!((c.baud(), c.rtim_ms()), (Baud::B115200, 3));
    }
    // Polling now runs at the new rate: a status round trip is about 2 x 1.39 ms + 3 ms.
    let start = h.sent.len();
    h.run_until(h.now + 100 * MS);
    let polls = h.sent.len() - start;
    let per_transaction = 100 * MS / polls as u64;
    let limit = timing::transaction_time(Baud::B115200, Rtim::MIN).as_micros();
    assert!(
        per_transaction <= limit * 105 / 100,
        "{per_transaction} µs per poll vs {limit}"
    );
    assert!(h.engine.axis(axis(3)).counters.timeouts == 0);
}

#[test]
fn a_silent_axis_goes_offline_and_rejoins_without_stalling_the_others() {
    let mut h = established(4);
    h.bus.set_silent(axis(2), true);
    h.run_until_event(2 * S, |e| *e == Event::Offline(axis(2)))
        .expect("offline");
    // Live axes keep being polled while axis 2 is probed at the reduced rate.
    let before = h.engine.axis(axis(0)).counters.replies;
    let probes_before = h.engine.axis(axis(2)).counters.frames_sent;
    h.run_until(h.now + 2 * S);
    let polled = h.engine.axis(axis(0)).counters.replies - before;
    let probes = h.engine.axis(axis(2)).counters.frames_sent - probes_before;
    // Three live axes at the wire limit get 2 s / (3 transactions) polls each. A dead axis costs
    // them a fast probe (one Trt, ~24 ms) every 500 ms and, every 5 s, one try at the power-up
    // settings (a ~310 ms time-out at 9.6 kbit/s, RTIM 255 ms).
    let rejoin_try = 310 * MS;
    let cycle = 3 * timing::transaction_time(Baud::B115200, Rtim::MIN).as_micros();
    let ideal = ((2 * S - rejoin_try) / cycle) as u32;
    assert!(
        polled * 100 >= ideal * 90,
        "axis 0 answered {polled} polls in 2 s, ideal {ideal}"
    );
    // Probes back off 20, 40, 80 ... 500 ms: at most 7 in 2 s, plus one try at 9.6 kbit/s.
    assert!(probes <= 8, "axis 2 probed {probes} times in 2 s");
    h.bus.set_silent(axis(2), false);
    h.run_until_event(2 * S, |e| *e == Event::Online(axis(2)))
        .expect("back online");
}

#[test]
fn a_power_cycled_axis_rejoins_at_its_stored_rate_without_stalling_the_others() {
    let mut h = established(4);
    let cycled = axis(1);
    h.bus
        .schedule_power_cycle(cycled, h.now + 100 * MS, 50 * MS);
    h.run_until_event(2 * S, |e| *e == Event::Offline(cycled))
        .expect("offline after power cycle");
    let back = h.run_until_event(10 * S, |e| *e == Event::Online(cycled));
    assert!(back.is_some(), "rejoined");
    let c = h.bus.controller(cycled).unwrap();
    assert_eq!((c.baud(), c.rtim_ms()), (Baud::B115200, 3));
    // While it rejoined, axis 0 was never left unpolled for more than a few hundred ms.
    let polls: Vec<u64> = h
        .sent
        .iter()
        .filter(|(_, r)| r.axis == axis(0) && r.command == Command::Status)
        .map(|(t, _)| *t)
        .collect();
    let worst = polls.windows(2).map(|w| w[1] - w[0]).max().unwrap();
    assert!(
        worst < 400 * MS,
        "axis 0 waited {} ms between polls",
        worst / MS
    );
    // The others were never reset: no break after the initial establishment.
    assert_eq!(h.engine.bus_counters().establishments, 1);
    for a in [0, 2, 3] {
        assert_eq!(h.engine.axis(axis(a)).link, Link::Online);
    }
}

/// Every injected fault kind, one at a time: the engine recovers and counts.
#[test]
fn each_fault_kind_is_survived_and_counted() {
    use rc_tools::sim::Faults;
    let kinds = [
        (
            "corruption",
            Faults {
                host_byte_corruption: 0.01,
                reply_byte_corruption: 0.01,
                ..Faults::default()
            },
        ),
        (
            "drops",
            Faults {
                reply_drop: 0.05,
                ..Faults::default()
            },
        ),
        (
            "late",
            Faults {
                reply_delay: 0.05,
                reply_delay_us: 40 * MS,
                ..Faults::default()
            },
        ),
        (
            "noise",
            Faults {
                noise: 0.2,
                noise_max_bytes: 3,
                ..Faults::default()
            },
        ),
    ];
    for (name, faults) in kinds {
        let mut h = established(4);
        h.bus.set_faults(faults);
        h.run_until(h.now + 5 * S);
        let stats = h.bus.stats().clone();
        let totals = (0..4).fold((0, 0, 0, 0), |acc, a| {
            let c = h.engine.axis(axis(a)).counters;
            (
                acc.0 + c.timeouts,
                acc.1 + c.retries,
                acc.2 + c.bcc_errors,
                acc.3 + c.replies,
            )
        });
        let (timeouts, retries, bcc_errors, replies) = totals;
        // 4 axes for 5 s at the wire limit would be ~740 transactions. At 1 % per byte both
        // ways, 0.99^32 = 72.5 % of transactions are intact, a corrupted answer costs one more
        // transaction, a corrupted command a 26-ms Trt: about 380 answers are expected.
        assert!(
            replies > 300,
            "{name}: polling continued ({replies} replies)"
        );
        match name {
            "corruption" => {
                assert!(stats.replies_corrupted + stats.host_frames_corrupted > 0);
                assert!(bcc_errors > 0 && retries > 0, "{name}: {totals:?}");
            }
            // One time-out per lost answer; the last one may still be waiting for its Trt
            // when the run stops.
            "drops" => {
                let lost = stats.replies_dropped;
                assert!(
                    (lost.saturating_sub(1)..=lost).contains(&u64::from(timeouts)),
                    "{name}: {timeouts} time-outs for {lost} dropped replies"
                );
            }
            "late" => {
                let late = stats.replies_delayed;
                assert!(
                    (late.saturating_sub(1)..=late).contains(&u64::from(timeouts)),
                    "{name}: {timeouts} time-outs for {late} replies later than Trt"
                );
            }
            _ => {
                assert!(stats.noise_bytes > 0);
                assert_eq!(timeouts, 0, "{name}: noise between frames costs nothing");
            }
        }
        // Survived: an axis the faults took off the bus (three bad answers in a row, about one
        // poll sequence in fifty at 1 % per byte) comes back once they stop, within a probe
        // interval (500 ms) and a rejoin try.
        h.bus.set_faults(Faults::default());
        h.run_until(h.now + S);
        for a in 0..4 {
            assert_eq!(
                h.engine.axis(axis(a)).link,
                Link::Online,
                "{name}: axis {a}"
            );
        }
    }
}

#[test]
fn sixteen_axes_are_all_polled() {
    let mut h = established(16);
    let before: Vec<u32> = (0..16)
        .map(|a| h.engine.axis(axis(a)).counters.replies)
        .collect();
    h.run_until(h.now + S);
    for a in 0..16u8 {
        let polled = h.engine.axis(axis(a)).counters.replies - before[usize::from(a)];
        // 1 s / (16 x 6.8 ms) = 9.2 cycles.
        assert!(
            (8..=10).contains(&polled),
            "axis {a}: {polled} polls in 1 s"
        );
    }
}

/// On a bus slower than its nominal transaction time (every reply 6 ms late: about twice the
/// transaction time at 115.2 kbit/s) every idle axis is always due; the polls of idle axes must
/// still leave room for the rest: each axis' first position read (its position registers wait
/// for it) and the probes of an absent axis.
#[test]
fn a_slow_bus_starves_neither_position_reads_nor_probes() {
    let present: Vec<Axis> = (0..15).map(axis).collect();
    let mut bus = Bus::with_axes(BusConfig::default(), &present);
    bus.set_faults(rc_tools::sim::Faults {
        reply_delay: 1.0,
        reply_delay_us: 6 * MS,
        ..Default::default()
    });
    let engine = Engine::new(Config {
        axes: AxisSet::first(16),
        baud: Baud::B115200,
        rtim: Rtim::MIN,
        establish: true,
        ..Config::default()
    });
    let mut h = Harness::new(engine, bus);
    h.run_until_event(20 * S, |e| *e == Event::Established)
        .expect("establishment finishes");
    let start = h.sent.len();
    h.run_until(h.now + 2 * S);
    for &a in &present {
        assert_eq!(h.engine.axis(a).link, Link::Online, "axis {a:?}");
        assert!(
            h.engine.axis(a).position.is_some(),
            "axis {a:?}: position never read"
        );
    }
    let absent = axis(15);
    let probes = h.sent[start..]
        .iter()
        .filter(|(_, r)| r.axis == absent)
        .count();
    assert!(probes >= 2, "absent axis probed {probes} times in 2 s");
}
