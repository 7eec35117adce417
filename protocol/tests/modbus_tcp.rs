//! Modbus TCP (feature `tcp`): MBAP framing over a byte stream, the connection table (allow-list,
//! limit, idle time, turns), and the node answering over TCP with the serial line's map. Every
//! test drives the node as the firmware's network task does, in virtual time.
#![cfg(feature = "tcp")]
#![allow(clippy::inconsistent_digit_grouping)]

mod support;

use protocol::modbus::tcp::{MbapError, SocketHandle, Stream, TcpAdu, SOCKETS};
use protocol::modbus::{Exception, Request as Modbus};
use protocol::net::Ipv4;
use protocol::plc::map::*;
use protocol::plc::WatchdogTime;
use protocol::time::Instant;
use support::*;

const PLC: Ipv4 = Ipv4([192, 168, 1, 10]);

/// Socket `socket`'s handle.
fn h(socket: usize) -> SocketHandle {
    SocketHandle::new(socket).expect("a socket of the node's")
}

/// The MBAP frame of `request` to `unit` with transaction id `tid`.
fn frame(tid: u16, unit: u8, request: &Modbus<'_>) -> Vec<u8> {
    let mut rtu = [0u8; 256];
    let len = request.emit(unit, &mut rtu).unwrap();
    let pdu = &rtu[1..len - 2];
    let mut out = tid.to_be_bytes().to_vec();
    out.extend_from_slice(&[0, 0]);
    out.extend_from_slice(&((pdu.len() + 1) as u16).to_be_bytes());
    out.push(unit);
    out.extend_from_slice(pdu);
    out
}

fn read(address: u16, quantity: u16) -> Modbus<'static> {
    Modbus::ReadHoldingRegisters { address, quantity }
}

/// The registers of an FC03 reply frame, after checking its header echoes `tid` and `unit`.
fn registers(reply: &[u8], tid: u16, unit: u8) -> Result<Vec<u16>, u8> {
    assert_eq!(&reply[0..2], &tid.to_be_bytes(), "transaction id echoed");
    assert_eq!(&reply[2..4], &[0, 0], "protocol id 0");
    assert_eq!(
        usize::from(u16::from_be_bytes([reply[4], reply[5]])),
        reply.len() - 6,
        "length counts the rest"
    );
    assert_eq!(reply[6], unit, "unit id echoed");
    if reply[7] & 0x80 != 0 {
        return Err(reply[8]);
    }
    Ok(reply[9..]
        .chunks(2)
        .map(|p| u16::from_be_bytes([p[0], p[1]]))
        .collect())
}

impl Rig {
    /// Opens `socket` from `peer`: whether the node admitted it.
    fn connect(&mut self, socket: usize, peer: Ipv4) -> bool {
        let admitted = self.node.tcp_opened(Instant(self.now), h(socket), peer);
        self.run_for(100);
        admitted
    }

    /// Sends `bytes` on `socket` and runs 1 ms; the replies that came.
    fn send(&mut self, socket: usize, bytes: &[u8]) -> Vec<(usize, Vec<u8>)> {
        let taken = self.node.tcp_received(Instant(self.now), h(socket), bytes);
        assert_eq!(taken, bytes.len(), "room for what a test sends");
        self.run_for(MS);
        std::mem::take(&mut self.tcp_replies)
    }

    /// One request on `socket`, its reply's registers (or exception code).
    fn tcp_read(
        &mut self,
        socket: usize,
        unit: u8,
        address: u16,
        quantity: u16,
    ) -> Result<Vec<u16>, u8> {
        let replies = self.send(socket, &frame(7, unit, &read(address, quantity)));
        assert_eq!(replies.len(), 1, "one reply");
        assert_eq!(replies[0].0, socket, "on the request's socket");
        registers(&replies[0].1, 7, unit)
    }
}

#[test]
fn a_frame_is_checked_whole() {
    let ok = frame(0x1234, 0xFF, &read(0, 2));
    let adu = TcpAdu::new_checked(&ok).unwrap();
    assert_eq!(
        (adu.transaction(), adu.unit(), adu.function()),
        (0x1234, 0xFF, 3)
    );
    let mut other = ok.clone();
    other[3] = 1;
    assert_eq!(TcpAdu::new_checked(&other), Err(MbapError::Protocol));
    let mut short = ok.clone();
    short.pop();
    assert_eq!(TcpAdu::new_checked(&short), Err(MbapError::Length));
    let mut zero = ok.clone();
    zero[4..6].copy_from_slice(&[0, 1]);
    assert_eq!(TcpAdu::new_checked(&zero[..7]), Err(MbapError::Length));
}

#[test]
fn a_stream_yields_frames_split_or_together_and_skips_another_protocol() {
    let a = frame(1, 1, &read(0, 1));
    let b = frame(2, 2, &read(5, 3));
    let mut foreign = frame(3, 1, &read(0, 1));
    foreign[2] = 0x12;
    // Byte by byte: nothing until the last byte of the first frame.
    let mut s = Stream::new();
    for (i, &byte) in a.iter().enumerate() {
        assert!(s.take().is_none(), "not whole at byte {i}");
        assert_eq!(s.push(&[byte]), 1);
    }
    assert_eq!(s.take().unwrap().unwrap().as_bytes(), &a[..]);
    assert!(s.take().is_none());
    // Three in one segment: in order, the foreign one refused in the middle.
    let all: Vec<u8> = [b.clone(), foreign, a.clone()].concat();
    assert_eq!(s.push(&all), all.len());
    assert_eq!(s.take().unwrap().unwrap().transaction(), 2);
    assert_eq!(s.take().unwrap(), Err(MbapError::Protocol));
    assert_eq!(s.take().unwrap().unwrap().transaction(), 1);
    assert!(s.take().is_none() && !s.is_partial());
    // A length out of range: an error, and the stream is of no more use.
    let mut bad = a.clone();
    bad[4..6].copy_from_slice(&[0x01, 0x00]);
    s.push(&bad);
    assert_eq!(s.take().unwrap(), Err(MbapError::Length));
}

#[test]
fn a_stream_takes_one_frame_s_worth_and_the_rest_waits_with_the_caller() {
    let a = frame(
        1,
        1,
        &Modbus::WriteMultipleRegisters {
            address: 0,
            values: &[0; 240],
        },
    );
    assert_eq!(a.len(), 7 + 6 + 240);
    let two = [a.clone(), a.clone()].concat();
    let mut s = Stream::new();
    let taken = s.push(&two);
    assert_eq!(taken, 260, "one buffer, no more");
    assert!(s.take().unwrap().is_ok());
    assert_eq!(s.push(&two[taken..]), two.len() - taken);
    assert!(s.take().unwrap().is_ok());
}

#[test]
fn units_ff_and_0_are_the_gateway_and_the_reply_echoes_the_header() {
    let mut rig = Rig::ready(2, |_| {});
    assert!(rig.connect(0, PLC));
    let version = rig.tcp_read(0, 63, G_VERSION, 2).unwrap();
    assert_eq!(rig.tcp_read(0, 0xFF, G_VERSION, 2).unwrap(), version);
    assert_eq!(rig.tcp_read(0, 0, G_VERSION, 2).unwrap(), version);
    // An axis unit as on RTU.
    assert!(rig.tcp_read(0, 1, PNOW, 2).is_ok());
    // A unit nobody serves: exception 0A, counted with the other units in PLCLINK.
    assert_eq!(rig.tcp_read(0, 9, G_VERSION, 1), Err(0x0A));
    let link = rig.tcp_read(0, 0xFF, G_PLC, G_PLC_LEN).unwrap();
    assert_eq!(link[9], 1, "PLCLINK: one request for another unit");
    // FC08 is serial-line only.
    let echo = Modbus::ReturnQueryData { data: &[1, 2] };
    let replies = rig.send(0, &frame(9, 0xFF, &echo));
    assert_eq!(
        &replies[0].1[7..],
        &[0x88, Exception::IllegalFunction.code()]
    );
}

#[test]
fn pipelined_requests_are_answered_in_order_and_a_slow_client_holds_no_one_up() {
    let mut rig = Rig::ready(1, |_| {});
    assert!(rig.connect(0, PLC));
    assert!(rig.connect(1, Ipv4([192, 168, 1, 11])));
    // Socket 0 sends half a request and stalls.
    let slow = frame(1, 63, &read(G_VERSION, 1));
    rig.node.tcp_received(Instant(rig.now), h(0), &slow[..5]);
    // Socket 1 pipelines three requests in one segment.
    let three: Vec<u8> = (10..13)
        .flat_map(|tid| frame(tid, 63, &read(G_UNIT_ID, 1)))
        .collect();
    let replies = rig.send(1, &three);
    let tids: Vec<(usize, u16)> = replies
        .iter()
        .map(|(s, r)| (*s, u16::from_be_bytes([r[0], r[1]])))
        .collect();
    assert_eq!(tids, vec![(1, 10), (1, 11), (1, 12)]);
    for (_, reply) in &replies {
        assert_eq!(
            registers(reply, u16::from_be_bytes([reply[0], reply[1]]), 63),
            Ok(vec![63])
        );
    }
    // The slow one's rest, a second later: answered then.
    rig.run_for(1_000 * MS);
    let replies = rig.send(0, &slow[5..]);
    assert_eq!(replies.len(), 1);
    assert_eq!(replies[0].0, 0);
}

#[test]
fn turns_are_taken_between_connections() {
    let mut rig = Rig::ready(1, |_| {});
    for socket in 0..3 {
        assert!(rig.connect(socket, Ipv4([10, 0, 0, socket as u8 + 1])));
    }
    for socket in 0..3 {
        let two: Vec<u8> = (0..2)
            .flat_map(|_| frame(socket as u16, 63, &read(0, 1)))
            .collect();
        rig.node.tcp_received(Instant(rig.now), h(socket), &two);
    }
    rig.run_for(MS);
    let order: Vec<usize> = rig.tcp_replies.iter().map(|(s, _)| *s).collect();
    assert_eq!(order, vec![0, 1, 2, 0, 1, 2]);
}

#[test]
fn a_client_not_allowed_is_refused_and_counted() {
    let mut rig = Rig::ready(1, |c| c.settings.net.policy.allow[1] = PLC);
    assert!(!rig.connect(0, Ipv4([192, 168, 1, 66])));
    assert_eq!(
        rig.node
            .tcp_received(Instant(rig.now), h(0), &frame(1, 63, &read(0, 1))),
        16 - 4
    );
    rig.run_for(MS);
    assert!(rig.tcp_replies.is_empty(), "its bytes never reach the map");
    assert!(rig.connect(0, PLC));
    let counters = rig.tcp_read(0, 63, G_TCP, G_TCP_LEN).unwrap();
    assert_eq!((counters[1], counters[3]), (1, 1), "accepted 1, refused 1");
}

#[test]
fn beyond_the_limit_a_new_client_replaces_the_one_idle_longest() {
    let mut rig = Rig::ready(1, |c| c.settings.net.policy.max_connections = 2);
    assert!(rig.connect(0, PLC));
    rig.run_for(10 * MS);
    assert!(rig.connect(1, PLC));
    rig.run_for(10 * MS);
    // Socket 0 is busy now: socket 1 is the one idle longest.
    assert!(rig.tcp_read(0, 63, G_VERSION, 1).is_ok());
    assert!(rig.connect(2, PLC));
    assert_eq!(
        rig.tcp_closes.iter().map(|c| c.1).collect::<Vec<_>>(),
        vec![1]
    );
    assert_eq!(rig.node.tcp_connections(), 2);
    assert_eq!(rig.node.tcp_counters().replaced, 1);
    assert_eq!(rig.tcp_read(2, 63, G_NET + 7, 1), Ok(vec![2]), "TCPCONN");
}

/// Ten clients connect at one instant and none sends a request: the sockets take them as they
/// free up, and each newcomer replaces the connection idle the longest, the oldest of those idle
/// as long; it is never closed itself, so the last four clients hold the slots.
#[test]
fn in_a_burst_of_connects_each_new_client_replaces_the_one_idle_longest() {
    let mut rig = Rig::ready(1, |_| {});
    let at = Instant(rig.now);
    // The client on each socket (the tenth connects at the same instant as the first).
    let mut on: Vec<Option<u8>> = vec![None; SOCKETS];
    let mut clients = 0u8..10;
    let mut closed = Vec::new();
    while let Some(socket) = on.iter().position(Option::is_none) {
        let Some(client) = clients.next() else { break };
        assert!(rig
            .node
            .tcp_opened(at, h(socket), Ipv4([192, 168, 1, 100 + client])));
        on[socket] = Some(client);
        rig.drain();
        for (_, socket) in rig.tcp_closes.drain(..) {
            let gone = on[socket].take().expect("a close of an open connection");
            assert_ne!(gone, client, "client {client} closed as it connected");
            closed.push(gone);
        }
    }
    assert_eq!(closed, (0..6).collect::<Vec<_>>(), "the oldest idle first");
    let mut open: Vec<u8> = on.into_iter().flatten().collect();
    open.sort_unstable();
    assert_eq!(open, vec![6, 7, 8, 9]);
    assert_eq!(rig.node.tcp_connections(), 4);
    assert_eq!(rig.node.tcp_counters().replaced, 6);
}

#[test]
fn a_silent_connection_is_closed_after_the_idle_time() {
    let mut rig = Rig::ready(1, |c| c.settings.net.policy.idle_s = 2);
    assert!(rig.connect(0, PLC));
    assert!(rig.connect(1, PLC));
    for _ in 0..4 {
        rig.run_for(600 * MS);
        assert!(rig.tcp_read(1, 63, G_VERSION, 1).is_ok());
    }
    // 2.4 s: socket 0 went at 2 s, socket 1 (busy) stays.
    assert_eq!(rig.tcp_closes.len(), 1);
    let (at, socket) = rig.tcp_closes[0];
    assert_eq!(socket, 0);
    assert!(
        (100 * MS + 2_000 * MS..100 * MS + 2_001 * MS + 200).contains(&at),
        "closed at {at}"
    );
    assert_eq!(rig.node.tcp_counters().idle_closed, 1);
    // TCPIDLE 0: never.
    assert!(rig.write(63, G_NET + 6, &[0]).is_ok());
    rig.run_for(10_000 * MS);
    assert_eq!(rig.tcp_closes.len(), 1);
}

#[test]
fn a_bad_length_closes_the_connection_and_another_protocol_is_skipped() {
    let mut rig = Rig::ready(1, |_| {});
    assert!(rig.connect(0, PLC));
    let mut foreign = frame(1, 63, &read(0, 1));
    foreign[2] = 0x55;
    let good = frame(2, 63, &read(0, 1));
    let replies = rig.send(0, &[foreign, good].concat());
    assert_eq!(
        replies.len(),
        1,
        "the foreign frame skipped, the next answered"
    );
    assert_eq!(&replies[0].1[0..2], &[0, 2]);
    let mut bad = frame(3, 63, &read(0, 1));
    bad[4..6].copy_from_slice(&[0x10, 0x00]);
    let replies = rig.send(0, &bad);
    assert!(replies.is_empty());
    assert_eq!(
        rig.tcp_closes.iter().map(|c| c.1).collect::<Vec<_>>(),
        vec![0]
    );
    assert_eq!(rig.node.tcp_counters().mbap_errors, 2);
}

#[test]
fn requests_over_tcp_feed_the_watchdog() {
    let mut rig = Rig::ready(1, |c| {
        c.settings.watchdog = WatchdogTime::from_millis(200).unwrap()
    });
    rig.write(63, G_FAILSAFE, &[0]).unwrap();
    assert!(rig.connect(0, PLC));
    for _ in 0..10 {
        rig.run_for(100 * MS);
        assert!(rig.tcp_read(0, 0xFF, G_FAILSAFE, 1).is_ok());
    }
    assert_eq!(
        rig.node.gateway().failsafe(),
        0,
        "1 s of TCP requests: no trip"
    );
    // An unserved unit's request is no sign of the PLC for the gateway.
    for _ in 0..3 {
        rig.run_for(100 * MS);
        assert_eq!(rig.tcp_read(0, 99, 0, 1), Err(0x0A));
    }
    assert_eq!(rig.node.gateway().failsafe(), protocol::plc::CAUSE_WATCHDOG);
}

#[test]
fn the_network_registers_are_checked_stored_and_read_back() {
    let mut rig = Rig::ready(1, |_| {});
    assert_eq!(
        rig.read(63, G_NET, 7),
        Ok(vec![0xC0A8, 0x0164, 24, 0, 0, 4, 60])
    );
    assert_eq!(
        rig.write(63, G_NET + 5, &[5]),
        Err(Exception::IllegalDataValue)
    );
    assert_eq!(
        rig.write(63, G_NET + 2, &[33]),
        Err(Exception::IllegalDataValue)
    );
    assert_eq!(
        rig.write(63, G_NET + 7, &[1]),
        Err(Exception::IllegalDataValue),
        "TCPCONN is read-only"
    );
    rig.write(63, G_NET, &[0x0A00, 0x0002, 16]).unwrap();
    rig.write(63, G_NET + 8, &[0xC0A8, 0x010A]).unwrap();
    assert_eq!(rig.read(63, G_NET, 3), Ok(vec![0x0A00, 0x0002, 16]));
    let net = rig.node.gateway().config().settings.net;
    assert_eq!(
        (net.ip, net.prefix, net.policy.allow[0]),
        (Ipv4([10, 0, 0, 2]), 16, PLC)
    );
    // SAVE stores them.
    rig.write(63, G_SAVE, &[1]).unwrap();
    rig.run_for(10 * MS);
    let (Some((_, protocol::plc::SettingsRequest::Save)), Some(&record)) =
        (rig.stores.last(), rig.saved.last())
    else {
        panic!("a save");
    };
    let settings = protocol::plc::settings::Settings::decode(&record).unwrap();
    assert_eq!(settings.gateway.net, net);
}

#[test]
fn axis_base_moves_the_axes_units_on_apply_and_never_onto_the_gateway_s() {
    let mut rig = Rig::ready(2, |_| {});
    // Axis 1 would be unit 63, the gateway's.
    assert_eq!(
        rig.write(63, G_AXIS_BASE, &[62]),
        Err(Exception::IllegalDataValue)
    );
    assert_eq!(
        rig.write(63, G_AXIS_BASE, &[233]),
        Err(Exception::IllegalDataValue)
    );
    rig.write(63, G_AXIS_BASE, &[17]).unwrap();
    assert_eq!(rig.read(63, G_AXIS_BASE, 1), Ok(vec![17]));
    assert!(rig.read(1, PNOW, 2).is_ok(), "not before APPLY");
    rig.write(63, G_APPLY, &[1]).unwrap();
    rig.run_for(2_000 * MS);
    assert!(rig.read(18, PNOW, 2).is_ok(), "axis 1 is unit 18");
    assert_eq!(
        rig.modbus(1, &read(PNOW, 2)),
        None,
        "unit 1 is nobody's now"
    );
    // The gateway unit may not move into the new range.
    assert_eq!(
        rig.write(63, G_UNIT_ID, &[17]),
        Err(Exception::IllegalDataValue)
    );
}

/// Found by a review: TCPCONN and TCPLINK read 0 over the serial line.
#[test]
fn tcpconn_and_tcplink_read_the_same_over_the_serial_line() {
    let mut rig = Rig::ready(1, |_| {});
    assert!(rig.connect(0, PLC));
    assert!(rig.connect(1, PLC));
    let over_tcp = rig.tcp_read(0, 63, G_TCP, G_TCP_LEN).unwrap();
    assert_eq!(rig.read(63, G_NET + 7, 1), Ok(vec![2]), "TCPCONN over RTU");
    let over_rtu = rig.read(63, G_TCP, G_TCP_LEN).unwrap();
    assert_eq!(over_rtu[1], 2, "accepted");
    // One more frame counted: the TCP read above.
    assert_eq!(over_rtu[11], over_tcp[11] + 1, "frames");
}

/// A socket whose send side is full gets no replies until it has room; the others are
/// answered meanwhile, and its requests wait, none lost.
#[test]
fn a_socket_without_room_for_a_reply_waits_and_the_others_do_not() {
    let mut rig = Rig::ready(1, |_| {});
    assert!(rig.connect(0, PLC));
    assert!(rig.connect(1, PLC));
    rig.node.tcp_writable(h(0), false);
    let two: Vec<u8> = (1..3)
        .flat_map(|tid| frame(tid, 63, &read(G_UNIT_ID, 1)))
        .collect();
    rig.node.tcp_received(Instant(rig.now), h(0), &two);
    let replies = rig.send(1, &frame(9, 63, &read(G_UNIT_ID, 1)));
    assert_eq!(replies.iter().map(|r| r.0).collect::<Vec<_>>(), vec![1]);
    rig.run_for(100 * MS);
    assert!(rig.tcp_replies.is_empty(), "nothing for the blocked socket");
    rig.node.tcp_writable(h(0), true);
    rig.run_for(MS);
    let tids: Vec<u16> = rig
        .tcp_replies
        .iter()
        .map(|(s, r)| {
            assert_eq!(*s, 0);
            u16::from_be_bytes([r[0], r[1]])
        })
        .collect();
    assert_eq!(tids, vec![1, 2]);
}

// ---------------------------------------------------------------- properties

mod properties {
    use super::*;
    use proptest::prelude::*;

    /// A valid frame: any transaction id, unit and PDU of 1-253 bytes.
    fn frames() -> impl Strategy<Value = Vec<u8>> {
        (
            any::<u16>(),
            any::<u8>(),
            proptest::collection::vec(any::<u8>(), 1..=253),
        )
            .prop_map(|(tid, unit, pdu)| {
                let mut f = tid.to_be_bytes().to_vec();
                f.extend_from_slice(&[0, 0]);
                f.extend_from_slice(&((pdu.len() + 1) as u16).to_be_bytes());
                f.push(unit);
                f.extend_from_slice(&pdu);
                f
            })
    }

    proptest! {
        /// However a stream of valid frames is cut into segments, the same frames come out, in
        /// order, and the bytes the stream cannot take yet are offered again.
        #[test]
        fn frames_survive_any_segmentation(
            frames in proptest::collection::vec(frames(), 1..6),
            cuts in proptest::collection::vec(1usize..300, 1..40),
        ) {
            let bytes: Vec<u8> = frames.concat();
            let mut s = Stream::new();
            let mut out = Vec::new();
            let (mut at, mut cut) = (0, cuts.iter().cycle());
            while at < bytes.len() || s.is_ready() {
                let end = (at + cut.next().copied().unwrap_or(1)).min(bytes.len());
                at += s.push(&bytes[at..end]);
                while let Some(frame) = s.take() {
                    out.push(frame.expect("a valid frame").as_bytes().to_vec());
                }
            }
            prop_assert_eq!(out, frames);
        }

        /// Arbitrary bytes, in arbitrary segments: nothing panics, every item is a frame or a
        /// counted error, and the stream always has room once its front is taken.
        #[test]
        fn any_bytes_never_panic(
            bytes in proptest::collection::vec(any::<u8>(), 0..2000),
            cuts in proptest::collection::vec(1usize..300, 1..40),
        ) {
            let mut s = Stream::new();
            let (mut at, mut cut) = (0, cuts.iter().cycle());
            for _ in 0..10_000 {
                if at >= bytes.len() && !s.is_ready() {
                    break;
                }
                let end = (at + cut.next().copied().unwrap_or(1)).min(bytes.len());
                at += s.push(&bytes[at..end]);
                while let Some(item) = s.take() {
                    if let Ok(frame) = item {
                        prop_assert!(frame.as_bytes().len() >= 8 && frame.as_bytes().len() <= 260);
                    } else {
                        // A length error leaves nothing to resynchronise on: a connection closes.
                        s.clear();
                    }
                }
                prop_assert!(s.room() > 0 || s.is_ready());
            }
        }
    }
}

/// After the client's FIN, what it sent before is still answered; only then is the connection
/// done (and no longer counted), and a fragment it left never holds it open.
#[test]
fn past_the_client_s_fin_its_requests_are_answered_then_the_connection_is_done() {
    let mut rig = Rig::ready(1, |_| {});
    assert!(rig.connect(0, PLC));
    rig.node.tcp_writable(h(0), false);
    let mut bytes = frame(4, 63, &read(G_UNIT_ID, 1));
    bytes.extend_from_slice(&frame(5, 63, &read(G_UNIT_ID, 1))[..3]);
    rig.node.tcp_received(Instant(rig.now), h(0), &bytes);
    rig.node.tcp_eof(h(0));
    rig.run_for(MS);
    assert!(!rig.node.tcp_finish(h(0)), "a request still to answer");
    assert_eq!(rig.node.tcp_connections(), 1);
    rig.node.tcp_writable(h(0), true);
    rig.run_for(MS);
    assert_eq!(std::mem::take(&mut rig.tcp_replies).len(), 1);
    assert!(rig.node.tcp_finish(h(0)), "only a fragment left");
    assert_eq!(rig.node.tcp_connections(), 0);
    assert!(!rig.node.tcp_connected(h(0)));
    assert!(!rig.node.tcp_finish(h(0)), "done once");
}
