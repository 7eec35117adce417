//! Properties over random input sequences: *STP off never moves, arbitrary samples never panic.

use proptest::prelude::*;
use protocol::engine::{JobKind, Link};
use protocol::pio::{Config, Pio, PioInputs as In, PioOutputs as Out};
use protocol::time::{Duration, Instant};
use protocol::HomeDirection;

use crate::{axis, report};

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
    (0u64..10_000, 0u64..10_000, 0u64..2_000_000).prop_map(|(debounce, settle, retry)| Config {
        debounce: Duration::from_micros(debounce),
        settle: Duration::from_micros(settle),
        servo_retry: Duration::from_micros(retry),
        ..Config::DEFAULT
    })
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

            let (out, job) = pio.sample(Instant(now), In::from_bits(s.inputs), &state, s.link_ok, HomeDirection::MotorEnd);

            let motion = matches!(job, Some(JobKind::MoveToPoint(..) | JobKind::Home(_)));
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
            let (outputs, _) = pio.sample(Instant(now), In::from_bits(inputs), &state, link_ok, HomeDirection::MotorEnd);
            prop_assert_eq!(outputs.bits() & !Out::MASK, 0);
        }
    }
}
