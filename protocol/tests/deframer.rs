//! The [`Deframer`] through its public API: resynchronisation after garbage, half frames and
//! corrupted frames, noise counting, the communication-change broadcast, and echo suppression.

use proptest::prelude::*;
use protocol::deframer::DeframerCounters;
use protocol::frame::{Frame, COMM_CHANGE, ETX, FRAME_LEN, STX};
use protocol::*;

// ---------------------------------------------------------------- helpers

fn axis(n: u8) -> Axis {
    Axis::new(n).unwrap()
}

fn status_request(n: u8) -> Frame {
    Request::new(axis(n), Command::Status).emit()
}

fn move_request(n: u8, pulses: i32) -> Frame {
    Request::new(axis(n), Command::MoveAbsolute(Pulses(pulses))).emit()
}

fn status_reply(n: u8) -> Frame {
    Reply::Status {
        axis: axis(n),
        code: Code::Status,
        report: StatusReport {
            status: Status::POWER | Status::SERVO | Status::RUN | Status::HOME,
            alarm: AlarmCode(0),
            inputs: Inputs::default(),
            outputs: Outputs::PFIN | Outputs::ZFIN | Outputs::ALM_N,
        },
    }
    .emit()
}

/// What one push gave, in a form that compares easily.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Out {
    Packet(Packet),
    Error(Error),
}

/// Push every byte; collect everything that is not `WouldBlock`.
fn feed(deframer: &mut Deframer, bytes: &[u8]) -> Vec<Out> {
    bytes
        .iter()
        .filter_map(|&b| match deframer.push(b) {
            Ok(packet) => Some(Out::Packet(packet)),
            Err(nb::Error::WouldBlock) => None,
            Err(nb::Error::Other(e)) => Some(Out::Error(e)),
        })
        .collect()
}

/// Only the packets of `feed`.
fn packets(deframer: &mut Deframer, bytes: &[u8]) -> Vec<Packet> {
    feed(deframer, bytes)
        .into_iter()
        .filter_map(|o| match o {
            Out::Packet(p) => Some(p),
            Out::Error(_) => None,
        })
        .collect()
}

fn frame_out(frame: Frame) -> Out {
    Out::Packet(Packet::Frame(frame))
}

// ---------------------------------------------------------------- plain deframing

#[test]
fn one_frame_is_delivered_on_its_last_byte() {
    let mut d = Deframer::new();
    let bytes = status_request(0).to_bytes();
    for &b in &bytes[..FRAME_LEN - 1] {
        assert_eq!(d.push(b), Err(nb::Error::WouldBlock));
    }
    assert_eq!(
        d.push(bytes[FRAME_LEN - 1]),
        Ok(Packet::Frame(status_request(0)))
    );
    assert_eq!(
        d.counters(),
        DeframerCounters {
            packets: 1,
            ..DeframerCounters::default()
        }
    );
}

/// `missing` counts down the candidate and the echo, so that a receiver may wait for the rest
/// of a frame instead of waking for every byte of it.
#[test]
fn missing_counts_what_completes_the_frame_or_the_echo() {
    let mut d = Deframer::new();
    assert_eq!(d.missing(), 0, "between frames: wake on the first byte");
    let reply = status_reply(3).to_bytes();
    for (n, &byte) in reply.iter().enumerate() {
        assert_eq!(d.missing(), if n == 0 { 0 } else { FRAME_LEN - n });
        let _ = d.push(byte);
    }
    assert_eq!(d.missing(), 0, "complete");
    // Noise outside a candidate starts nothing.
    let _ = d.push(b'x');
    assert_eq!(d.missing(), 0);
    // The echo: nothing until it starts, then the rest of it.
    let sent = status_request(3).to_bytes();
    d.expect_echo(&sent);
    assert_eq!(d.missing(), 0);
    for (n, &byte) in sent.iter().enumerate().take(5) {
        assert_eq!(d.missing(), if n == 0 { 0 } else { FRAME_LEN - n });
        let _ = d.push(byte);
    }
    assert_eq!(d.missing(), FRAME_LEN - 5);
    // A collision: the echo is abandoned, its bytes become a candidate, still counting.
    let _ = d.push(b'Z');
    assert_eq!(d.missing(), FRAME_LEN - 6);
    // A half frame abandoned by the next STX: the new candidate counts from 1.
    let _ = d.push(STX);
    assert_eq!(d.missing(), FRAME_LEN - 1);
}

#[test]
fn two_frames_back_to_back() {
    let mut d = Deframer::default();
    let mut bytes = status_request(1).to_bytes().to_vec();
    bytes.extend_from_slice(&status_reply(1).to_bytes());
    assert_eq!(
        feed(&mut d, &bytes),
        [frame_out(status_request(1)), frame_out(status_reply(1))]
    );
    assert_eq!(d.counters().packets, 2);
    assert_eq!(d.counters().errors, 0);
    assert_eq!(d.counters().noise_bytes, 0);
}

#[test]
fn half_frame_then_good_frame_is_truncated_then_delivered() {
    let mut d = Deframer::new();
    let half = &move_request(2, -1).to_bytes()[..7];
    assert_eq!(feed(&mut d, half), []);
    assert_eq!(
        feed(&mut d, &status_request(2).to_bytes()),
        [
            Out::Error(Error::Truncated { len: 7 }),
            frame_out(status_request(2))
        ]
    );
    assert_eq!(d.rejected(), half);
    assert_eq!(d.counters().errors, 1);
    assert_eq!(d.counters().packets, 1);
}

#[test]
fn lone_stx_then_good_frame() {
    let mut d = Deframer::new();
    let mut bytes = vec![STX];
    bytes.extend_from_slice(&status_reply(0).to_bytes());
    assert_eq!(
        feed(&mut d, &bytes),
        [
            Out::Error(Error::Truncated { len: 1 }),
            frame_out(status_reply(0))
        ]
    );
    assert_eq!(d.rejected(), [STX]);
}

#[test]
fn corrupted_frame_is_an_error_and_the_next_frame_is_delivered() {
    let mut d = Deframer::new();
    let mut bad = move_request(3, 1000).to_bytes();
    bad[5] ^= 0x01;
    let out = feed(&mut d, &bad);
    assert!(
        matches!(out[..], [Out::Error(Error::BadBcc { .. })]),
        "{out:?}"
    );
    assert_eq!(d.rejected(), bad);
    assert_eq!(
        feed(&mut d, &status_reply(3).to_bytes()),
        [frame_out(status_reply(3))]
    );
    assert_eq!(d.counters().errors, 1);
    assert_eq!(d.counters().packets, 1);
}

#[test]
fn missing_etx_is_an_error_and_the_next_frame_is_delivered() {
    let mut d = Deframer::new();
    let mut bad = status_request(4).to_bytes();
    bad[FRAME_LEN - 1] = b'X';
    assert_eq!(
        feed(&mut d, &bad),
        [Out::Error(Error::MissingEtx { found: b'X' })]
    );
    assert_eq!(d.rejected(), bad);
    // The byte after the 16th is outside any candidate: noise.
    assert_eq!(feed(&mut d, &[ETX]), []);
    assert_eq!(d.counters().noise_bytes, 1);
    assert_eq!(
        feed(&mut d, &status_request(4).to_bytes()),
        [frame_out(status_request(4))]
    );
}

#[test]
fn noise_bytes_are_counted() {
    let mut d = Deframer::new();
    let noise = b"\x00\xFFhello\x03\x03";
    assert_eq!(feed(&mut d, noise), []);
    assert_eq!(d.counters().noise_bytes, noise.len() as u32);
    assert_eq!(
        feed(&mut d, &status_request(0).to_bytes()),
        [frame_out(status_request(0))]
    );
    assert_eq!(feed(&mut d, b"xyz"), []);
    assert_eq!(
        d.counters(),
        DeframerCounters {
            packets: 1,
            noise_bytes: noise.len() as u32 + 3,
            ..DeframerCounters::default()
        }
    );
}

#[test]
fn comm_change_is_a_packet() {
    let mut d = Deframer::new();
    let mut bytes = b"\x05\x05".to_vec();
    bytes.extend_from_slice(&COMM_CHANGE);
    bytes.extend_from_slice(&status_request(0).to_bytes());
    assert_eq!(
        feed(&mut d, &bytes),
        [
            Out::Packet(Packet::CommChange),
            frame_out(status_request(0))
        ]
    );
    assert_eq!(d.counters().packets, 2);
    assert_eq!(d.counters().noise_bytes, 2);
}

#[test]
fn comm_change_with_one_enq_changed_is_an_error() {
    let mut d = Deframer::new();
    let mut bytes = COMM_CHANGE;
    bytes[7] = b'0';
    let out = feed(&mut d, &bytes);
    assert_eq!(out.len(), 1);
    assert!(matches!(out[0], Out::Error(_)), "{out:?}");
    assert_eq!(d.rejected(), bytes);
}

#[test]
fn reset_drops_a_partial_frame_as_noise() {
    let mut d = Deframer::new();
    assert_eq!(feed(&mut d, &status_request(0).to_bytes()[..5]), []);
    d.reset();
    assert_eq!(d.counters().noise_bytes, 5);
    assert_eq!(d.counters().errors, 0);
    // The rest of the cut frame is noise too, and the next frame is whole.
    assert_eq!(feed(&mut d, &status_request(0).to_bytes()[5..]), []);
    assert_eq!(
        feed(&mut d, &status_request(0).to_bytes()),
        [frame_out(status_request(0))]
    );
}

// ---------------------------------------------------------------- echo suppression

#[test]
fn echo_is_swallowed_and_the_reply_delivered() {
    let mut d = Deframer::new();
    let sent = status_request(5).to_bytes();
    d.expect_echo(&sent);
    assert!(d.echo_pending());
    assert_eq!(feed(&mut d, &sent), []);
    assert!(!d.echo_pending());
    assert_eq!(
        feed(&mut d, &status_reply(5).to_bytes()),
        [frame_out(status_reply(5))]
    );
    assert_eq!(
        d.counters(),
        DeframerCounters {
            packets: 1,
            echoes: 1,
            ..DeframerCounters::default()
        }
    );
}

#[test]
fn comm_change_echo_is_swallowed() {
    let mut d = Deframer::new();
    d.expect_echo(&COMM_CHANGE);
    assert_eq!(feed(&mut d, &COMM_CHANGE), []);
    assert_eq!(d.counters().echoes, 1);
    assert_eq!(d.counters().packets, 0);
}

#[test]
fn lost_echo_still_delivers_the_reply() {
    let mut d = Deframer::new();
    d.expect_echo(&status_request(6).to_bytes());
    assert_eq!(
        feed(&mut d, &status_reply(6).to_bytes()),
        [frame_out(status_reply(6))]
    );
    assert!(!d.echo_pending());
    assert_eq!(d.counters().echo_mismatches, 1);
    assert_eq!(d.counters().echoes, 0);
    assert_eq!(d.counters().packets, 1);
    assert_eq!(d.counters().errors, 0);
}

#[test]
fn noise_before_the_echo_is_skipped() {
    let mut d = Deframer::new();
    let sent = move_request(7, 12345).to_bytes();
    d.expect_echo(&sent);
    let mut bytes = b"\x00\xFF\x03".to_vec();
    bytes.extend_from_slice(&sent);
    bytes.extend_from_slice(&status_reply(7).to_bytes());
    assert_eq!(feed(&mut d, &bytes), [frame_out(status_reply(7))]);
    assert_eq!(d.counters().echoes, 1);
    assert_eq!(d.counters().echo_mismatches, 0);
    assert_eq!(d.counters().noise_bytes, 3);
}

#[test]
fn echo_corrupted_by_a_collision_is_counted_and_the_next_frame_delivered() {
    let sent = move_request(8, -500).to_bytes();
    for index in 1..FRAME_LEN {
        for garbled in [b'#', STX, ETX, 0x00, 0xFF] {
            if sent[index] == garbled {
                continue;
            }
            let mut d = Deframer::new();
            d.expect_echo(&sent);
            let mut echo = sent;
            echo[index] = garbled;
            let out = feed(&mut d, &echo);
            assert!(
                out.iter().all(|o| matches!(o, Out::Error(_))),
                "byte {index} -> {garbled:#04X}: {out:?}"
            );
            assert!(!d.echo_pending());
            assert_eq!(d.counters().echo_mismatches, 1);
            assert_eq!(d.counters().echoes, 0);
            assert_eq!(d.counters().packets, 0);
            let out = feed(&mut d, &status_reply(8).to_bytes());
            assert_eq!(
                out.last(),
                Some(&frame_out(status_reply(8))),
                "byte {index} -> {garbled:#04X}: {out:?}"
            );
            assert_eq!(d.counters().packets, 1);
        }
    }
}

#[test]
fn echo_cut_short_by_the_reply_is_counted_and_the_reply_delivered() {
    let mut d = Deframer::new();
    let sent = status_request(9).to_bytes();
    d.expect_echo(&sent);
    let mut bytes = sent[..10].to_vec();
    bytes.extend_from_slice(&status_reply(9).to_bytes());
    assert_eq!(feed(&mut d, &bytes), [frame_out(status_reply(9))]);
    assert_eq!(d.counters().echo_mismatches, 1);
    assert_eq!(d.counters().packets, 1);
}

#[test]
fn expect_echo_drops_a_partial_frame_as_noise() {
    let mut d = Deframer::new();
    assert_eq!(feed(&mut d, &status_reply(0).to_bytes()[..4]), []);
    let sent = status_request(0).to_bytes();
    d.expect_echo(&sent);
    assert_eq!(d.counters().noise_bytes, 4);
    assert_eq!(feed(&mut d, &sent), []);
    assert_eq!(d.counters().echoes, 1);
    assert_eq!(d.counters().errors, 0);
}

#[test]
fn reset_forgets_a_pending_echo() {
    let mut d = Deframer::new();
    let sent = status_request(0).to_bytes();
    d.expect_echo(&sent);
    d.reset();
    assert!(!d.echo_pending());
    // The "echo" is now an ordinary frame.
    assert_eq!(feed(&mut d, &sent), [frame_out(status_request(0))]);
    assert_eq!(d.counters().echoes, 0);
    assert_eq!(d.counters().echo_mismatches, 0);
}

#[test]
fn rejected_returns_the_rejected_candidate() {
    let mut d = Deframer::new();
    assert_eq!(d.rejected(), []);
    let mut bad = status_request(0).to_bytes();
    bad[13] = b'z';
    assert_eq!(
        feed(&mut d, &bad),
        [Out::Error(Error::NonHexDigit {
            index: 13,
            found: b'z'
        })]
    );
    assert_eq!(d.rejected(), bad);
    // A good frame does not clear it; the next rejection replaces it.
    feed(&mut d, &status_request(0).to_bytes());
    assert_eq!(d.rejected(), bad);
    feed(&mut d, &status_request(1).to_bytes()[..3]);
    feed(&mut d, &[STX]);
    assert_eq!(d.rejected(), &status_request(1).to_bytes()[..3]);
}

#[test]
fn long_streams_never_panic() {
    // A fixed struct: memory cannot grow, so a long run only checks that nothing panics and
    // that the deframer still works afterwards. xorshift keeps the stream deterministic.
    let mut d = Deframer::new();
    let mut x: u32 = 0x1234_5678;
    for i in 0..2_000_000u32 {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        // Bias toward STX and ETX so that candidates open and close often.
        let byte = match x % 7 {
            0 => STX,
            1 => ETX,
            _ => (x >> 8) as u8,
        };
        if i % 100_003 == 0 {
            d.expect_echo(&status_request((x % 16) as u8).to_bytes());
        }
        let _ = d.push(byte);
        let _ = d.rejected();
    }
    d.reset();
    assert_eq!(
        packets(&mut d, &status_request(0).to_bytes()),
        [Packet::Frame(status_request(0))]
    );
    let c = d.counters();
    assert!(c.errors > 0 && c.noise_bytes > 0, "{c:?}");
}

// ---------------------------------------------------------------- properties

/// A valid frame: any 12 data bytes that are not STX (STX never occurs inside a real frame:
/// data and BCC are printable ASCII), or a real request or reply.
fn frame() -> impl Strategy<Value = Frame> {
    prop_oneof![
        prop::array::uniform12(any::<u8>().prop_filter("no STX", |&b| b != STX))
            .prop_map(Frame::from_data),
        (0u8..16, any::<i32>()).prop_map(|(n, p)| move_request(n, p)),
        (0u8..16).prop_map(status_reply),
    ]
}

/// What the gateway sends, and so the echo it expects: a request (never a reply, so that the
/// reply after the echo is not mistaken for it), or any frame whose data does not start `U`.
fn sent() -> impl Strategy<Value = Frame> {
    prop_oneof![
        frame().prop_filter("not a reply", |f| f.data()[0] != b'U'),
        (0u8..16, any::<i32>()).prop_map(|(n, p)| move_request(n, p)),
        (0u8..16).prop_map(status_request),
    ]
}

fn packet() -> impl Strategy<Value = Packet> {
    prop_oneof![
        9 => frame().prop_map(Packet::Frame),
        1 => Just(Packet::CommChange),
    ]
}

fn packet_bytes(packet: &Packet) -> [u8; FRAME_LEN] {
    match packet {
        Packet::Frame(f) => f.to_bytes(),
        Packet::CommChange => COMM_CHANGE,
    }
}

fn garbage_without_stx() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(any::<u8>().prop_filter("no STX", |&b| b != STX), 0..40)
}

proptest! {
    /// A good frame after arbitrary garbage (STX and ETX included) is always delivered, on its
    /// last byte.
    #[test]
    fn good_frame_after_any_garbage_is_delivered(
        garbage in prop::collection::vec(
            prop_oneof![3 => any::<u8>(), 1 => Just(STX), 1 => Just(ETX)], 0..100),
        frame in frame(),
    ) {
        let mut d = Deframer::new();
        feed(&mut d, &garbage);
        let bytes = frame.to_bytes();
        let out = feed(&mut d, &bytes[..FRAME_LEN - 1]);
        // At most the abandoned candidate, reported when the frame's STX arrives.
        prop_assert!(
            matches!(out[..], [] | [Out::Error(Error::Truncated { .. })]),
            "{:?}", out
        );
        prop_assert_eq!(d.push(bytes[FRAME_LEN - 1]), Ok(Packet::Frame(frame)));
    }

    /// Any sequence of packets interleaved with garbage that holds no STX is delivered whole
    /// and in order, with nothing else; the garbage is counted as noise.
    #[test]
    fn packets_between_stx_free_garbage_are_delivered_in_order(
        items in prop::collection::vec((garbage_without_stx(), packet()), 0..12),
        tail in garbage_without_stx(),
    ) {
        let mut d = Deframer::new();
        let mut bytes = Vec::new();
        for (garbage, packet) in &items {
            bytes.extend_from_slice(garbage);
            bytes.extend_from_slice(&packet_bytes(packet));
        }
        bytes.extend_from_slice(&tail);
        let expected: Vec<Out> = items.iter().map(|(_, p)| Out::Packet(*p)).collect();
        prop_assert_eq!(feed(&mut d, &bytes), expected);
        let noise: usize = items.iter().map(|(g, _)| g.len()).sum::<usize>() + tail.len();
        prop_assert_eq!(
            d.counters(),
            DeframerCounters {
                packets: items.len() as u32,
                noise_bytes: noise as u32,
                ..DeframerCounters::default()
            }
        );
    }

    /// Echo suppression: noise without STX, the echo, then packets: only the packets come out.
    #[test]
    fn echo_then_packets(
        sent in sent(),
        noise in garbage_without_stx(),
        items in prop::collection::vec(packet(), 1..4),
    ) {
        let mut d = Deframer::new();
        d.expect_echo(&sent.to_bytes());
        let mut bytes = noise.clone();
        bytes.extend_from_slice(&sent.to_bytes());
        for p in &items {
            bytes.extend_from_slice(&packet_bytes(p));
        }
        let expected: Vec<Out> = items.iter().map(|p| Out::Packet(*p)).collect();
        prop_assert_eq!(feed(&mut d, &bytes), expected);
        prop_assert_eq!(d.counters().echoes, 1);
        prop_assert_eq!(d.counters().echo_mismatches, 0);
        prop_assert_eq!(d.counters().noise_bytes, noise.len() as u32);
    }

    /// Whatever replaces the echo (a lost echo, a collision, a cut echo) and whatever comes
    /// before the reply, the reply after it is delivered and the echo is not pending.
    #[test]
    fn reply_is_delivered_whatever_happens_to_the_echo(
        sent in sent(),
        line in prop::collection::vec(
            prop_oneof![3 => any::<u8>(), 1 => Just(STX), 1 => Just(ETX)], 0..40),
        reply in 0u8..16,
    ) {
        let mut d = Deframer::new();
        d.expect_echo(&sent.to_bytes());
        feed(&mut d, &line);
        let reply = status_reply(reply);
        let out = feed(&mut d, &reply.to_bytes());
        prop_assert_eq!(out.last(), Some(&frame_out(reply)), "{:?}", out);
        prop_assert!(!d.echo_pending());
        let c = d.counters();
        prop_assert_eq!(c.echoes + c.echo_mismatches, 1, "{:?}", c);
    }

    /// Arbitrary streams, with echoes expected at arbitrary points, never panic; every packet
    /// delivered is valid, and every error leaves its bytes in `rejected`.
    #[test]
    fn arbitrary_streams_never_panic(
        bytes in prop::collection::vec(
            prop_oneof![6 => any::<u8>(), 1 => Just(STX), 1 => Just(ETX), 1 => Just(0x05)],
            0..600),
        echo_at in prop::collection::vec((0usize..600, sent()), 0..4),
    ) {
        let mut d = Deframer::new();
        for (i, &b) in bytes.iter().enumerate() {
            for (at, sent) in &echo_at {
                if *at == i {
                    d.expect_echo(&sent.to_bytes());
                }
            }
            match d.push(b) {
                Ok(Packet::Frame(f)) => {
                    prop_assert_eq!(Frame::new_checked(&f.to_bytes()), Ok(f));
                }
                Ok(Packet::CommChange) | Err(nb::Error::WouldBlock) => {}
                Err(nb::Error::Other(e)) => {
                    let rejected = d.rejected();
                    prop_assert!(!rejected.is_empty() && rejected.len() <= FRAME_LEN);
                    prop_assert_eq!(rejected[0], STX);
                    match e {
                        Error::Truncated { len } => prop_assert_eq!(usize::from(len), rejected.len()),
                        _ => {
                            prop_assert_eq!(rejected.len(), FRAME_LEN);
                            prop_assert!(Frame::new_checked(rejected).is_err());
                        }
                    }
                }
            }
        }
    }
}
