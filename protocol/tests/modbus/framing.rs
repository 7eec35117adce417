//! Framing in virtual time: the t1.5/t3.5 timers, overruns, merged frames, gaps, garbage,
//! CRC errors and reset.

use protocol::modbus::{t1_5, t3_5, Adu, FrameError, Handled, Receiver, ReplyBuffer, Slave};
use protocol::time::{Duration, Instant};

use crate::{feed, hex, with_crc, with_crc_bytes, Memory, CHAR_19200};

// ------------------------------------------------------------------------------ framing

#[test]
fn timers_follow_serial_line_2_5_1_1() {
    assert_eq!(t3_5(9_600), Duration::from_micros(4_011)); // 38.5 bits
    assert_eq!(t1_5(9_600), Duration::from_micros(1_719)); // 16.5 bits
    assert_eq!(t3_5(19_200), Duration::from_micros(2_006));
    assert_eq!(t1_5(19_200), Duration::from_micros(860));
    for baud in [19_201, 38_400, 57_600, 115_200, 230_400] {
        assert_eq!(t3_5(baud), Duration::from_micros(1_750));
        assert_eq!(t1_5(baud), Duration::from_micros(750));
    }
    assert_eq!(t3_5(1_200), Duration::from_micros(32_084));
    assert!(t3_5(0) > Duration::from_millis(1000), "no division by zero");
}

#[test]
fn frames_end_after_t3_5_of_silence() {
    let mut receiver = Receiver::new(19_200);
    let t35 = t3_5(19_200);
    assert_eq!(receiver.next_deadline(), None);
    assert!(receiver.poll(Instant(1_000_000)).is_none());
    let frame = hex("11 03 00 6B 00 03 76 87");
    let last = feed(&mut receiver, Instant(1_000), &frame, CHAR_19200);
    assert_eq!(receiver.next_deadline(), Some(last + t35));
    assert!(receiver
        .poll(last + Duration::from_micros(t35.as_micros() - 1))
        .is_none());
    let adu = receiver.poll(last + t35).unwrap().unwrap();
    assert_eq!(
        (adu.unit(), adu.function(), adu.as_bytes()),
        (0x11, 0x03, &frame[..])
    );
    assert_eq!(adu.pdu(), &frame[1..6]);
    assert!(receiver.poll(last + t35).is_none(), "delivered once");
    assert_eq!(receiver.next_deadline(), None);

    // Two frames separated by exactly t3.5 are two frames.
    let second = hex("11 06 00 01 00 03 9A 9B");
    let start = last + t35 + Duration::from_micros(10);
    let end = feed(&mut receiver, start, &frame, CHAR_19200);
    assert!(receiver.poll(end + t35).unwrap().is_ok());
    let end2 = feed(&mut receiver, end + t35, &second, CHAR_19200);
    assert_eq!(
        receiver.poll(end2 + t35).unwrap().unwrap().as_bytes(),
        &second[..]
    );
    assert_eq!(receiver.counters().frames, 3);
    assert_eq!(receiver.counters().overruns, 0);
}

#[test]
fn a_frame_not_polled_in_time_is_an_overrun() {
    let mut receiver = Receiver::new(19_200);
    let t35 = t3_5(19_200);
    let last = feed(
        &mut receiver,
        Instant(0),
        &hex("11 03 00 6B 00 03 76 87"),
        CHAR_19200,
    );
    let second = hex("11 06 00 01 00 03 9A 9B");
    let end = feed(&mut receiver, last + t35, &second, CHAR_19200);
    assert_eq!(
        receiver.poll(end + t35).unwrap().unwrap().as_bytes(),
        &second[..]
    );
    assert_eq!(
        (receiver.counters().frames, receiver.counters().overruns),
        (2, 1)
    );
}

/// A task reads a frame's first bytes, sends on another line for longer than t3.5, then reads
/// the rest, which waited in the UART meanwhile: stamped with when the task last found the line
/// empty, they continue the frame; stamped with the time of the read alone they would start a
/// frame of their own (both halves lost: an overrun and a CRC error).
#[test]
fn bytes_that_waited_through_a_send_continue_their_frame() {
    let t35 = t3_5(115_200);
    let frame = hex("11 03 00 6B 00 03 76 87");
    let send = Duration::from_micros(16_700); // a 16-byte bus frame at 9.6 kbit/s
    for (waited, whole) in [(true, true), (false, false)] {
        let mut receiver = Receiver::new(115_200).without_gap_check();
        let looked = Instant(1_000);
        receiver.push_between(looked, looked, &frame[..3]);
        let read = looked + send;
        let since = if waited { looked } else { read };
        receiver.push_between(since, read, &frame[3..]);
        assert!(
            receiver
                .poll(read + Duration::from_micros(t35.as_micros() - 1))
                .is_none(),
            "the end counts from the read"
        );
        let result = receiver
            .poll(read + t35)
            .unwrap()
            .map(|adu| adu.as_bytes().to_vec());
        assert_eq!(result.is_ok(), whole, "waited {waited}: {result:?}");
        let counters = receiver.counters();
        assert_eq!(
            (counters.frames, counters.overruns),
            if whole { (1, 0) } else { (0, 1) },
            "waited {waited}"
        );
    }
}

/// The span only widens what is uncertain: bytes whose `since` is t3.5 or more after the last
/// byte follow a silence that was on the line, and end the frame before them.
#[test]
fn a_silence_seen_before_bytes_that_waited_still_ends_the_frame() {
    let t35 = t3_5(115_200);
    let first = hex("11 03 00 6B 00 03 76 87");
    let second = hex("11 06 00 01 00 03 9A 9B");
    let mut receiver = Receiver::new(115_200).without_gap_check();
    receiver.push_between(Instant(0), Instant(0), &first);
    let looked = Instant(0) + t35;
    receiver.push_between(looked, looked + Duration::from_millis(20), &second);
    let end = looked + Duration::from_millis(20) + t35;
    assert_eq!(receiver.poll(end).unwrap().unwrap().as_bytes(), &second[..]);
    assert_eq!(
        (receiver.counters().frames, receiver.counters().overruns),
        (2, 1),
        "the first frame ended (not polled in time: an overrun)"
    );
}

#[test]
fn frames_closer_than_t1_5_merge_and_fail_the_crc() {
    let mut receiver = Receiver::new(19_200);
    let mut bytes = hex("11 03 00 6B 00 03 76 87");
    bytes.extend(hex("11 06 00 01 00 03 9A 9B"));
    let last = feed(&mut receiver, Instant(0), &bytes, CHAR_19200);
    assert_eq!(
        receiver.poll(last + t3_5(19_200)).unwrap(),
        Err(FrameError::Crc)
    );
    assert_eq!(receiver.counters().crc_errors, 1);
}

#[test]
fn a_gap_between_t1_5_and_t3_5_discards_the_frame() {
    let frame = hex("11 03 00 6B 00 03 76 87");
    let gap = Duration::from_micros(1_500); // t1.5 = 860 µs < 1500 µs < t3.5 = 2006 µs
    let run = |receiver: &mut Receiver| {
        let middle = feed(receiver, Instant(0), &frame[..4], CHAR_19200);
        let last = feed(receiver, middle + gap, &frame[4..], CHAR_19200);
        assert!(receiver.poll(last + Duration::from_micros(2_005)).is_none());
        receiver
            .poll(last + t3_5(19_200))
            .unwrap()
            .map(|adu| adu.as_bytes().to_vec())
    };
    let mut receiver = Receiver::new(19_200);
    assert_eq!(run(&mut receiver), Err(FrameError::BadGap));
    assert_eq!(receiver.counters().bad_gaps, 1);
    // Bytes after the gap are discarded too, until t3.5: then the next frame is fine.
    let start = Instant(100_000);
    let last = feed(&mut receiver, start, &frame, CHAR_19200);
    assert_eq!(
        receiver
            .poll(last + t3_5(19_200))
            .unwrap()
            .unwrap()
            .as_bytes(),
        &frame[..]
    );
    // A gap of exactly t1.5 is allowed.
    let middle = feed(&mut receiver, Instant(200_000), &frame[..4], CHAR_19200);
    let last = feed(
        &mut receiver,
        middle + t1_5(19_200),
        &frame[4..],
        CHAR_19200,
    );
    assert!(receiver.poll(last + t3_5(19_200)).unwrap().is_ok());
    // Without the gap check the same timing gives the frame.
    let mut lenient = Receiver::new(19_200).without_gap_check();
    assert_eq!(lenient.t1_5(), None);
    assert_eq!(run(&mut lenient), Ok(frame.clone()));
}

#[test]
fn garbage_over_256_bytes_is_discarded_then_frames_work() {
    let mut receiver = Receiver::new(115_200);
    let mut slave = Slave::new();
    let mut model = Memory::new(1000);
    let mut reply = ReplyBuffer::new();
    let char_time = Duration::from_micros(96);
    let garbage: Vec<u8> = (0..300u32).map(|n| (n * 37 + 11) as u8).collect();
    let last = feed(&mut receiver, Instant(5), &garbage, char_time);
    let deadline = receiver.next_deadline().unwrap();
    assert_eq!(deadline, last + Duration::from_micros(1_750));
    assert_eq!(
        slave.poll(&mut receiver, deadline, &mut model, &mut reply),
        Some(Err(FrameError::TooLong))
    );
    assert!(reply.is_empty());
    let frame = hex("11 03 00 6B 00 03 76 87");
    let last = feed(&mut receiver, deadline, &frame, char_time);
    let handled = slave.poll(
        &mut receiver,
        last + Duration::from_micros(1_750),
        &mut model,
        &mut reply,
    );
    assert_eq!(handled, Some(Ok(Handled::Reply(11))));
    assert_eq!(
        reply.as_bytes(),
        &with_crc("11 03 06 00 00 00 00 00 00")[..]
    );
    let counters = slave.counters();
    assert_eq!(
        (counters.too_long, counters.frames, counters.replies),
        (1, 1, 1)
    );
    assert_eq!(receiver.counters().too_long, 1);

    // 256 bytes is a frame, 257 is not.
    let mut longest = hex("11 08 00 00");
    longest.extend([0x5A; 250]);
    let longest = with_crc_bytes(longest);
    let last = feed(&mut receiver, Instant(1_000_000), &longest, char_time);
    assert_eq!(
        receiver
            .poll(last + Duration::from_micros(1_750))
            .unwrap()
            .unwrap()
            .as_bytes()
            .len(),
        256
    );
    let mut too_long = longest.clone();
    too_long.push(0);
    let last = feed(&mut receiver, Instant(2_000_000), &too_long, char_time);
    assert_eq!(
        receiver.poll(last + Duration::from_micros(1_750)).unwrap(),
        Err(FrameError::TooLong)
    );
}

#[test]
fn crc_errors_are_counted_and_not_answered() {
    let mut receiver = Receiver::new(19_200);
    let mut slave = Slave::new();
    let mut model = Memory::new(1000);
    let mut reply = ReplyBuffer::new();
    let mut frame = hex("11 06 00 01 00 03 9A 9B");
    frame[5] ^= 0x01;
    let last = feed(&mut receiver, Instant(0), &frame, CHAR_19200);
    let result = slave.poll(&mut receiver, last + t3_5(19_200), &mut model, &mut reply);
    assert_eq!(result, Some(Err(FrameError::Crc)));
    assert!(reply.is_empty());
    assert_eq!(model.holding[1], 0);
    assert_eq!(
        (slave.counters().crc_errors, slave.counters().replies),
        (1, 0)
    );
    // Too short.
    let last = feed(
        &mut receiver,
        Instant(100_000),
        &hex("11 03 76"),
        CHAR_19200,
    );
    let result = slave.poll(&mut receiver, last + t3_5(19_200), &mut model, &mut reply);
    assert_eq!(result, Some(Err(FrameError::TooShort)));
    assert_eq!(
        Adu::new_checked(&hex("11 03 76")),
        Err(FrameError::TooShort)
    );
    assert_eq!(Adu::new_checked(&[0; 257]), Err(FrameError::TooLong));
}

#[test]
fn reset_drops_the_burst_in_progress() {
    let mut receiver = Receiver::new(19_200);
    feed(&mut receiver, Instant(0), &hex("11 03 00"), CHAR_19200);
    assert!(receiver.is_busy());
    receiver.reset();
    assert!(!receiver.is_busy() && receiver.next_deadline().is_none());
    let last = feed(
        &mut receiver,
        Instant(600),
        &hex("11 03 00 6B 00 03 76 87"),
        CHAR_19200,
    );
    assert!(receiver.poll(last + t3_5(19_200)).unwrap().is_ok());
}
