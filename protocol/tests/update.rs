//! The firmware image's transfer over the PLC link (feature `update`, `plc::update`): through
//! the whole node, over Modbus RTU and TCP, into a DFU partition in RAM (`support::Dfu`, which
//! fails a test on a write outside it or over bytes not erased), with the bus served meanwhile.
#![cfg(feature = "update")]
#![allow(clippy::inconsistent_digit_grouping)]

mod support;

use proptest::prelude::*;
use protocol::modbus::tcp::SocketHandle;
use protocol::modbus::Request as Modbus;
use protocol::net::Ipv4;
use protocol::plc::map::*;
use protocol::plc::update::{
    begin_registers, chunk_registers, crc32, BootState, Target, UpdateError, UpdateState,
    UpdateStatus, ABORT, FINISH, MAX_CHUNK,
};
use protocol::time::Instant;
use protocol::Command;
use support::*;

const GW: u8 = 63;
const BOARD: u16 = 0x0475;
const PARTITION: usize = 64 * 1024;
const PLC: Ipv4 = Ipv4([192, 168, 1, 10]);

/// Two axes at rest on the bus, a 64 KiB DFU partition.
fn rig() -> Rig {
    let mut rig = Rig::ready(2, |_| {});
    rig.dfu = Dfu::new(PARTITION);
    rig.node.set_update_target(Target {
        board: BOARD,
        partition: PARTITION as u32,
    });
    rig
}

/// An image of `len` bytes that no shift of a chunk leaves the same.
fn image(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i * 7 + i / 251 + 3) as u8).collect()
}

/// The PLC link a tool uses.
#[derive(Clone, Copy, Debug)]
enum Link {
    Rtu,
    /// On this socket of the node's.
    Tcp(usize),
}

fn h(socket: usize) -> SocketHandle {
    SocketHandle::new(socket).unwrap()
}

/// The MBAP frame of `request` to `unit`.
fn mbap(tid: u16, unit: u8, request: &Modbus<'_>) -> Vec<u8> {
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

impl Link {
    /// Connects a TCP link.
    fn open(self, rig: &mut Rig) -> Link {
        if let Link::Tcp(socket) = self {
            assert!(rig.node.tcp_opened(Instant(rig.now), h(socket), PLC));
            rig.run_for(100);
        }
        self
    }

    /// One request: its reply's body after the function code, or the exception code.
    fn request(self, rig: &mut Rig, request: &Modbus<'_>) -> Result<Vec<u8>, u8> {
        match self {
            Link::Rtu => rig
                .modbus(GW, request)
                .expect("an answer")
                .map_err(|e| e.code()),
            Link::Tcp(socket) => {
                let frame = mbap(9, GW, request);
                let taken = rig.node.tcp_received(Instant(rig.now), h(socket), &frame);
                assert_eq!(taken, frame.len());
                rig.run_for(MS);
                let replies = std::mem::take(&mut rig.tcp_replies);
                assert_eq!(replies.len(), 1, "one reply");
                let reply = &replies[0].1;
                assert_eq!(&reply[0..2], &9u16.to_be_bytes(), "transaction id echoed");
                if reply[7] & 0x80 != 0 {
                    Err(reply[8])
                } else {
                    Ok(reply[8..].to_vec())
                }
            }
        }
    }

    fn write(self, rig: &mut Rig, address: u16, values: &[u16]) -> Result<(), u8> {
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
        let request = match values {
            [value] => Modbus::WriteSingleRegister {
                address,
                value: *value,
            },
            _ => Modbus::WriteMultipleRegisters {
                address,
                values: &bytes,
            },
        };
        self.request(rig, &request).map(|_| ())
    }

    fn status(self, rig: &mut Rig) -> UpdateStatus {
        let request = Modbus::ReadHoldingRegisters {
            address: G_UPDATE_STATUS,
            quantity: G_UPDATE_STATUS_LEN,
        };
        let body = self.request(rig, &request).expect("UPDSTAT reads");
        let registers: Vec<u16> = body[1..]
            .chunks(2)
            .map(|p| u16::from_be_bytes([p[0], p[1]]))
            .collect();
        UpdateStatus::parse(&registers).expect("16 registers")
    }

    fn begin(self, rig: &mut Rig, image: &[u8], board: u16) -> Result<(), u8> {
        self.write(
            rig,
            G_UPDATE,
            &begin_registers(image.len() as u32, crc32(image), board),
        )
    }

    /// The chunk of `image` at `offset`.
    fn chunk(self, rig: &mut Rig, image: &[u8], offset: u32) -> Result<(), u8> {
        let start = offset as usize;
        let end = (start + MAX_CHUNK).min(image.len());
        self.write(
            rig,
            G_UPDATE_CHUNK,
            &chunk_registers(offset, &image[start..end]),
        )
    }

    /// What `rcgw update` does: from wherever the gateway is (BEGIN only when it has no
    /// transfer of this image), every chunk at the next offset it shows, FINISH. Stops at the
    /// first refusal.
    fn send(self, rig: &mut Rig, image: &[u8]) -> Result<UpdateStatus, u8> {
        let status = self.status(rig);
        let ours = status.size == image.len() as u32
            && status.crc32 == crc32(image)
            && status.state == UpdateState::Receiving as u16;
        if !ours {
            self.begin(rig, image, BOARD)?;
        }
        loop {
            let status = self.status(rig);
            assert_eq!(status.state, UpdateState::Receiving as u16, "{status:?}");
            if status.next == image.len() as u32 {
                break;
            }
            self.chunk(rig, image, status.next)?;
        }
        self.write(rig, G_UPDATE, &[FINISH])?;
        Ok(self.status(rig))
    }
}

fn refusals(rig: &mut Rig) -> u32 {
    Link::Rtu.status(rig).refusals
}

fn assert_in_partition(rig: &Rig, image: &[u8]) {
    assert_eq!(&rig.dfu.flash[..image.len()], image);
    assert_eq!(
        rig.dfu.marked,
        Some((image.len() as u32, crc32(image))),
        "checked and marked for the bootloader"
    );
}

/// The whole transfer over `link`; the bus polled all along.
fn whole_image_over(link: Link) {
    let mut rig = rig();
    let link = link.open(&mut rig);
    let image = image(10_000 + 5);
    let start = rig.now;
    let status = link.send(&mut rig, &image).unwrap();
    assert_eq!(status.state, UpdateState::Ready as u16);
    assert_eq!(status.error, UpdateError::None as u16);
    assert_eq!(
        (status.received, status.next, status.size),
        (10_005, 10_005, 10_005)
    );
    assert_eq!(
        (status.board, status.partition, status.refusals),
        (BOARD, PARTITION as u32, 0)
    );
    assert_in_partition(&rig, &image);
    // One erase, 44 writes, one finish, in that order.
    let jobs: Vec<&Job> = rig.dfu.jobs.iter().map(|(_, j)| j).collect();
    assert_eq!(jobs.len(), 1 + 10_005usize.div_ceil(MAX_CHUNK) + 1);
    assert_eq!(jobs[0], &Job::Erase(10_005));
    assert!(matches!(jobs.last(), Some(Job::Finish(10_005, _))));
    // The gateway kept polling its axes while the image came, as often as without it.
    let end = rig.now;
    for a in 0..2 {
        let polls: Vec<u64> = rig
            .sent
            .iter()
            .filter(|(t, r)| *t > start && r.axis.get() == a && r.command == Command::Status)
            .map(|(t, _)| *t)
            .collect();
        let gap = polls
            .windows(2)
            .map(|w| w[1] - w[0])
            .chain([polls[0] - start, end - polls[polls.len() - 1]])
            .max()
            .unwrap();
        assert!(gap <= 40 * MS, "axis {a}: a gap of {gap} µs between polls");
    }
}

#[test]
fn a_whole_image_goes_over_rtu_into_the_partition() {
    whole_image_over(Link::Rtu);
}

#[test]
fn a_whole_image_goes_over_tcp_into_the_partition() {
    whole_image_over(Link::Tcp(0));
}

#[test]
fn an_image_as_large_as_the_partition_fits() {
    let mut rig = rig();
    let image = image(PARTITION);
    let status = Link::Rtu.send(&mut rig, &image).unwrap();
    assert_eq!(status.state, UpdateState::Ready as u16);
    assert_in_partition(&rig, &image);
}

#[test]
fn a_cut_rtu_link_resumes_where_it_stopped() {
    let mut rig = rig();
    let image = image(5_000);
    Link::Rtu.begin(&mut rig, &image, BOARD).unwrap();
    for n in 0..5 {
        Link::Rtu
            .chunk(&mut rig, &image, (n * MAX_CHUNK) as u32)
            .unwrap();
    }
    // The cable is pulled in the middle of a chunk: half its frame arrives, then nothing.
    let registers = chunk_registers(5 * MAX_CHUNK as u32, &image[5 * MAX_CHUNK..6 * MAX_CHUNK]);
    let bytes: Vec<u8> = registers.iter().flat_map(|v| v.to_be_bytes()).collect();
    let mut adu = [0u8; 256];
    let request = Modbus::WriteMultipleRegisters {
        address: G_UPDATE_CHUNK,
        values: &bytes,
    };
    let len = request.emit(GW, &mut adu).unwrap();
    rig.node.plc_received(Instant(rig.now), &adu[..len / 2]);
    rig.run_for(2_000 * MS);
    // Plugged in again: the next chunk is taken but its reply is lost.
    rig.node.plc_received(Instant(rig.now), &adu[..len]);
    rig.run_for(100 * MS);
    let status = Link::Rtu.status(&mut rig);
    assert_eq!(status.state, UpdateState::Receiving as u16);
    assert_eq!(
        status.next,
        6 * MAX_CHUNK as u32,
        "the chunk whose reply was lost is in"
    );
    // The tool, not knowing, sends it again: refused, nothing written twice.
    assert_eq!(
        Link::Rtu.chunk(&mut rig, &image, 5 * MAX_CHUNK as u32),
        Err(3)
    );
    assert_eq!(
        Link::Rtu.status(&mut rig).error,
        UpdateError::OutOfOrder as u16
    );
    // It reads where the gateway is and goes on from there, without a BEGIN.
    let writes = rig.dfu.jobs.len();
    let status = Link::Rtu.send(&mut rig, &image).unwrap();
    assert_eq!(status.state, UpdateState::Ready as u16);
    assert_in_partition(&rig, &image);
    assert!(!rig.dfu.jobs[writes..]
        .iter()
        .any(|(_, j)| matches!(j, Job::Erase(_))));
}

#[test]
fn a_closed_tcp_connection_resumes_on_the_next() {
    let mut rig = rig();
    let image = image(3_000);
    let first = Link::Tcp(0).open(&mut rig);
    first.begin(&mut rig, &image, BOARD).unwrap();
    for n in 0..4 {
        first
            .chunk(&mut rig, &image, (n * MAX_CHUNK) as u32)
            .unwrap();
    }
    rig.node.tcp_closed(h(0));
    rig.run_for(500 * MS);
    let second = Link::Tcp(1).open(&mut rig);
    assert_eq!(second.status(&mut rig).next, 4 * MAX_CHUNK as u32);
    let status = second.send(&mut rig, &image).unwrap();
    assert_eq!(status.state, UpdateState::Ready as u16);
    assert_in_partition(&rig, &image);
}

#[test]
fn a_corrupted_chunk_is_refused_counted_and_taken_when_sent_again() {
    let mut rig = rig();
    let image = image(1_000);
    Link::Rtu.begin(&mut rig, &image, BOARD).unwrap();
    Link::Rtu.chunk(&mut rig, &image, 0).unwrap();
    let jobs = rig.dfu.jobs.len();
    let mut registers = chunk_registers(MAX_CHUNK as u32, &image[MAX_CHUNK..2 * MAX_CHUNK]);
    registers[10] ^= 0x0100;
    assert_eq!(
        Link::Rtu.write(&mut rig, G_UPDATE_CHUNK, &registers),
        Err(3)
    );
    let status = Link::Rtu.status(&mut rig);
    assert_eq!(
        (status.state, status.error, status.next, status.refusals),
        (
            UpdateState::Receiving as u16,
            UpdateError::ChunkCheck as u16,
            MAX_CHUNK as u32,
            1
        )
    );
    assert_eq!(rig.dfu.jobs.len(), jobs, "nothing written");
    assert_eq!(
        Link::Rtu.send(&mut rig, &image).unwrap().state,
        UpdateState::Ready as u16
    );
    assert_in_partition(&rig, &image);
}

#[test]
fn a_chunk_out_of_order_or_misshapen_is_refused() {
    let mut rig = rig();
    let image = image(2_000);
    // Before BEGIN: no transfer under way, which asking again does not change.
    assert_eq!(Link::Rtu.chunk(&mut rig, &image, 0), Err(3));
    Link::Rtu.begin(&mut rig, &image, BOARD).unwrap();
    Link::Rtu.chunk(&mut rig, &image, 0).unwrap();
    let jobs = rig.dfu.jobs.len();
    // Ahead, and back.
    assert_eq!(
        Link::Rtu.chunk(&mut rig, &image, 2 * MAX_CHUNK as u32),
        Err(3)
    );
    assert_eq!(Link::Rtu.chunk(&mut rig, &image, 0), Err(3));
    assert_eq!(
        Link::Rtu.status(&mut rig).error,
        UpdateError::OutOfOrder as u16
    );
    // A length that leaves the next offset off a flash word; a length its data does not fill;
    // status registers written (past the image's end: below).
    let at = MAX_CHUNK as u32;
    let mut odd = chunk_registers(at, &image[MAX_CHUNK..MAX_CHUNK + 13]);
    assert_eq!(Link::Rtu.write(&mut rig, G_UPDATE_CHUNK, &odd), Err(3));
    odd[2] = 40;
    assert_eq!(Link::Rtu.write(&mut rig, G_UPDATE_CHUNK, &odd), Err(3));
    assert_eq!(
        Link::Rtu.status(&mut rig).error,
        UpdateError::Malformed as u16
    );
    assert_eq!(Link::Rtu.write(&mut rig, G_UPDATE_STATUS, &[0, 0]), Err(3));
    assert_eq!(Link::Rtu.write(&mut rig, G_UPDATE + 1, &[0, 0]), Err(3));
    assert_eq!(Link::Rtu.write(&mut rig, G_UPDATE, &[9]), Err(3));
    assert_eq!(rig.dfu.jobs.len(), jobs, "nothing written");
    assert_eq!(Link::Rtu.status(&mut rig).refusals, 8);
    // FINISH before the last byte.
    assert_eq!(Link::Rtu.write(&mut rig, G_UPDATE, &[FINISH]), Err(3));
    assert_eq!(
        Link::Rtu.status(&mut rig).error,
        UpdateError::Incomplete as u16
    );
    assert_eq!(
        Link::Rtu.send(&mut rig, &image).unwrap().state,
        UpdateState::Ready as u16
    );
    assert_in_partition(&rig, &image);
    // Past the image's end: 24 bytes at 0 for an image of 20.
    let mut small = self::rig();
    let twenty = self::image(20);
    Link::Rtu.begin(&mut small, &twenty, BOARD).unwrap();
    let long = chunk_registers(0, &self::image(24));
    assert_eq!(Link::Rtu.write(&mut small, G_UPDATE_CHUNK, &long), Err(3));
    assert_eq!(
        Link::Rtu.status(&mut small).error,
        UpdateError::Malformed as u16
    );
}

#[test]
fn another_board_s_image_is_refused() {
    let mut rig = rig();
    let image = image(1_000);
    assert_eq!(Link::Rtu.begin(&mut rig, &image, 0x0429), Err(3));
    let status = Link::Rtu.status(&mut rig);
    assert_eq!(
        (status.state, status.error, status.refusals),
        (UpdateState::Idle as u16, UpdateError::WrongBoard as u16, 1)
    );
    assert!(rig.dfu.jobs.is_empty(), "nothing erased");
}

#[test]
fn an_image_larger_than_the_partition_is_refused() {
    let mut rig = rig();
    let image = image(PARTITION + 1);
    assert_eq!(Link::Rtu.begin(&mut rig, &image, BOARD), Err(3));
    assert_eq!(Link::Rtu.begin(&mut rig, &[], BOARD), Err(3));
    let status = Link::Rtu.status(&mut rig);
    assert_eq!(
        (status.state, status.error, status.refusals),
        (UpdateState::Idle as u16, UpdateError::TooLarge as u16, 2)
    );
    assert!(rig.dfu.jobs.is_empty(), "nothing erased");
}

#[test]
fn no_transfer_while_an_axis_moves() {
    let mut rig = rig();
    let image = image(1_500);
    // A direct move of axis 1 (80 ms on this bench).
    rig.write(2, DIRECT, &[0, 10_00, 0, 10, 0, 50_00, 30])
        .unwrap();
    rig.run_for(5 * MS);
    assert_eq!(Link::Rtu.begin(&mut rig, &image, BOARD), Err(4));
    assert_eq!(Link::Rtu.status(&mut rig).error, UpdateError::Moving as u16);
    assert!(rig.dfu.jobs.is_empty());
    rig.run_for(200 * MS);
    Link::Rtu.begin(&mut rig, &image, BOARD).unwrap();
    Link::Rtu.chunk(&mut rig, &image, 0).unwrap();
    // A move in the middle: chunks wait for it, then the transfer goes on.
    rig.write(1, DIRECT, &[0, 20_00, 0, 10, 0, 50_00, 30])
        .unwrap();
    rig.run_for(5 * MS);
    assert_eq!(Link::Rtu.chunk(&mut rig, &image, MAX_CHUNK as u32), Err(4));
    assert_eq!(Link::Rtu.write(&mut rig, G_UPDATE, &[FINISH]), Err(4));
    rig.run_for(200 * MS);
    assert_eq!(
        Link::Rtu.send(&mut rig, &image).unwrap().state,
        UpdateState::Ready as u16
    );
    assert_in_partition(&rig, &image);
    assert_eq!(refusals(&mut rig), 3);
}

#[test]
fn no_transfer_while_a_save_is_pending() {
    let mut rig = rig();
    let image = image(700);
    rig.hold_saves = true;
    rig.write(GW, G_SAVE, &[1]).unwrap();
    assert_eq!(Link::Rtu.begin(&mut rig, &image, BOARD), Err(4));
    assert_eq!(
        Link::Rtu.status(&mut rig).error,
        UpdateError::SavePending as u16
    );
    rig.node.stored(Ok(1));
    Link::Rtu.begin(&mut rig, &image, BOARD).unwrap();
    assert_eq!(
        Link::Rtu.send(&mut rig, &image).unwrap().state,
        UpdateState::Ready as u16
    );
}

#[test]
fn no_save_nor_factory_reset_while_a_flash_job_is_under_way() {
    let mut rig = rig();
    let image = image(1_000);
    rig.dfu.hold = true;
    rig.hold_saves = true;
    Link::Rtu.begin(&mut rig, &image, BOARD).unwrap();
    assert_eq!(rig.dfu.held, Some(Job::Erase(1_000)));
    // The erase runs (on the F429 by itself, seconds): the settings pages wait (04, ask again).
    assert_eq!(Link::Rtu.write(&mut rig, G_SAVE, &[1]), Err(4));
    assert_eq!(Link::Rtu.write(&mut rig, G_FACTORY, &[FACTORY_KEY]), Err(4));
    rig.release_job();
    rig.run_for(5 * MS);
    // The erase done, a SAVE is taken again (and then holds the transfer off in turn).
    Link::Rtu.write(&mut rig, G_SAVE, &[1]).unwrap();
    assert_eq!(Link::Rtu.chunk(&mut rig, &image, 0), Err(4));
    assert_eq!(
        Link::Rtu.status(&mut rig).error,
        UpdateError::SavePending as u16
    );
}

#[test]
fn the_bus_and_the_stop_input_are_served_while_a_flash_job_is_under_way() {
    let mut rig = rig();
    let image = image(1_000);
    rig.dfu.hold = true;
    Link::Rtu.begin(&mut rig, &image, BOARD).unwrap();
    assert_eq!(rig.dfu.held, Some(Job::Erase(1_000)));
    assert_eq!(
        Link::Rtu.status(&mut rig).state,
        UpdateState::Erasing as u16
    );
    // Not done yet: the next chunk waits, as does an ABORT.
    assert_eq!(Link::Rtu.chunk(&mut rig, &image, 0), Err(4));
    assert_eq!(Link::Rtu.write(&mut rig, G_UPDATE, &[ABORT]), Err(4));
    assert_eq!(Link::Rtu.status(&mut rig).error, UpdateError::Busy as u16);
    assert_eq!(refusals(&mut rig), 0, "flow control, not counted");
    // Meanwhile the axes are polled and a stop goes out at once.
    let since = rig.now;
    rig.run_for(300 * MS);
    for a in 0..2 {
        assert!(rig.commands_to(a, since).contains(&Command::Status));
    }
    let stop_at = rig.now;
    rig.node.set_stop_input(Instant(rig.now), true);
    rig.run_for(50 * MS);
    for a in 0..2 {
        let first = rig
            .sent
            .iter()
            .find(|(t, r)| *t >= stop_at && r.axis.get() == a && r.command == Command::CancelMotion)
            .map(|(t, _)| t - stop_at);
        assert!(
            first.is_some_and(|t| t < 20 * MS),
            "axis {a} stopped after {first:?} µs"
        );
    }
    rig.node.set_stop_input(Instant(rig.now), false);
    rig.release_job();
    rig.dfu.hold = false;
    assert_eq!(
        Link::Rtu.send(&mut rig, &image).unwrap().state,
        UpdateState::Ready as u16
    );
    assert_in_partition(&rig, &image);
}

#[test]
fn flash_work_waits_while_an_axis_moves_or_is_owed_a_stop() {
    let mut rig = rig();
    let image = image(1_000);
    // The erase handed out: the firmware takes it in steps while the bus is quiet.
    rig.dfu.hold = true;
    Link::Rtu.begin(&mut rig, &image, BOARD).unwrap();
    assert!(rig.node.quiet_for_flash());
    // A move the PLC starts meanwhile is carried out; the steps wait for its end.
    rig.write(2, DIRECT, &[0, 10_00, 0, 10, 0, 50_00, 30])
        .unwrap();
    rig.run_for(5 * MS);
    assert!(!rig.node.quiet_for_flash(), "an axis moves");
    rig.run_for(200 * MS);
    assert!(rig.node.quiet_for_flash(), "the move is over");
    rig.release_job();
    rig.dfu.hold = false;
    // Axis 0's wire cut, the stop input on: a stop is owed to it.
    rig.bus.fake(0).silent = true;
    rig.node.set_stop_input(Instant(rig.now), true);
    rig.run_for(300 * MS);
    assert!(!rig.node.quiet_for_flash(), "a stop is owed");
    // A chunk taken now is not written while the stop is owed.
    let jobs = rig.dfu.jobs.len();
    Link::Rtu.chunk(&mut rig, &image, 0).unwrap();
    rig.run_for(100 * MS);
    assert_eq!(rig.dfu.jobs.len(), jobs, "a flash job while a stop is owed");
    assert_eq!(
        Link::Rtu.status(&mut rig).state,
        UpdateState::Writing as u16
    );
    // The wire mended, the stop taken: the write goes on.
    rig.bus.fake(0).silent = false;
    rig.run_for(300 * MS);
    assert!(rig.node.quiet_for_flash());
    assert_eq!(rig.dfu.jobs.len(), jobs + 1);
    rig.node.set_stop_input(Instant(rig.now), false);
    rig.run_for(20 * MS);
    rig.write(GW, G_FAILSAFE, &[0]).unwrap();
    assert_eq!(
        Link::Rtu.send(&mut rig, &image).unwrap().state,
        UpdateState::Ready as u16
    );
    assert_in_partition(&rig, &image);
}

/// From the stop input to the first stop of the last axis, µs.
fn stop_latency(rig: &mut Rig) -> u64 {
    let at = rig.now;
    rig.node.set_stop_input(Instant(at), true);
    let latency = loop {
        rig.run_for(100);
        let first = |a: u8| {
            rig.sent
                .iter()
                .find(|(t, r)| *t >= at && r.axis.get() == a && r.command == Command::CancelMotion)
                .map(|(t, _)| t - at)
        };
        if let (Some(a), Some(b)) = (first(0), first(1)) {
            break a.max(b);
        }
        assert!(rig.now < at + 100 * MS, "no stop");
    };
    rig.node.set_stop_input(Instant(rig.now), false);
    rig.run_for(20 * MS);
    rig.write(GW, G_FAILSAFE, &[0]).unwrap();
    latency
}

#[test]
fn the_stop_latency_is_the_same_during_a_transfer() {
    // Without a transfer, the stop input at ten moments of the poll cycle.
    let mut idle = rig();
    let mut without = Vec::new();
    for k in 0..10 {
        idle.run_for(1_700 * (k + 1));
        without.push(stop_latency(&mut idle));
    }
    // During one: right after a chunk was taken, its write still under way (held) or done.
    let mut busy = rig();
    let image = image(30 * MAX_CHUNK);
    Link::Rtu.begin(&mut busy, &image, BOARD).unwrap();
    let mut during = Vec::new();
    for k in 0..10u64 {
        busy.run_for(1_700 * (k + 1));
        let next = busy.node.update().next_offset();
        busy.dfu.hold = k % 2 == 0;
        Link::Rtu.chunk(&mut busy, &image, next).unwrap();
        during.push(stop_latency(&mut busy));
        if busy.dfu.hold {
            busy.release_job();
            busy.dfu.hold = false;
        }
    }
    let (without, during) = (
        *without.iter().max().unwrap(),
        *during.iter().max().unwrap(),
    );
    assert!(
        during <= without,
        "the longest stop latency {during} µs during a transfer, {without} µs without"
    );
    assert_eq!(
        Link::Rtu.send(&mut busy, &image).unwrap().state,
        UpdateState::Ready as u16
    );
    assert_in_partition(&busy, &image);
}

#[test]
fn a_flash_failure_fails_the_transfer_until_begin() {
    let mut rig = rig();
    let image = image(1_000);
    Link::Rtu.begin(&mut rig, &image, BOARD).unwrap();
    rig.dfu.fail_next = Some(UpdateError::Flash);
    Link::Rtu.chunk(&mut rig, &image, 0).unwrap();
    let status = Link::Rtu.status(&mut rig);
    assert_eq!(
        (status.state, status.error, status.next),
        (UpdateState::Failed as u16, UpdateError::Flash as u16, 0)
    );
    // A chunk now is refused for good (03), and the failure's cause stays in UPDSTAT.
    assert_eq!(Link::Rtu.chunk(&mut rig, &image, 0), Err(3));
    let status = Link::Rtu.status(&mut rig);
    assert_eq!(
        (status.state, status.error),
        (UpdateState::Failed as u16, UpdateError::Flash as u16)
    );
    // `send` begins again, since the gateway has no transfer under way.
    assert_eq!(
        Link::Rtu.send(&mut rig, &image).unwrap().state,
        UpdateState::Ready as u16
    );
    assert_in_partition(&rig, &image);
}

#[test]
fn an_image_whose_crc_is_not_begin_s_is_not_marked() {
    let mut rig = rig();
    let image = image(600);
    Link::Rtu
        .write(
            &mut rig,
            G_UPDATE,
            &begin_registers(600, crc32(&image) ^ 1, BOARD),
        )
        .unwrap();
    for n in 0..3 {
        Link::Rtu
            .chunk(&mut rig, &image, (n * MAX_CHUNK) as u32)
            .unwrap();
    }
    assert_eq!(Link::Rtu.write(&mut rig, G_UPDATE, &[FINISH]), Err(3));
    let status = Link::Rtu.status(&mut rig);
    assert_eq!(
        (status.state, status.error),
        (UpdateState::Failed as u16, UpdateError::ImageCheck as u16)
    );
    assert_eq!(rig.dfu.marked, None);
}

#[test]
fn a_board_without_a_partition_answers_02() {
    let mut rig = Rig::ready(1, |_| {});
    let image = image(100);
    assert_eq!(Link::Rtu.begin(&mut rig, &image, BOARD), Err(2));
    let status = Link::Rtu.status(&mut rig);
    assert_eq!((status.board, status.partition), (0, 0));
    assert_eq!(status.error, UpdateError::NoPartition as u16);
}

/// One thing a PLC or a tool may do, or the flash.
#[derive(Clone, Debug)]
enum Op {
    Begin {
        size: u32,
        board_ok: bool,
    },
    /// A chunk of `len` bytes at the next offset plus `skew`, its CRC right or not.
    Chunk {
        skew: i32,
        len: u16,
        good: bool,
    },
    Raw {
        address: u16,
        values: Vec<u16>,
    },
    /// Every chunk from the next offset to the end, as a tool sends them.
    Rest,
    Finish,
    Abort,
    FailNext,
    Wait(u16),
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        (0u32..80_000, prop::bool::weighted(0.8))
            .prop_map(|(size, board_ok)| Op::Begin { size, board_ok }),
        (
            prop_oneof![Just(0), -300i32..300],
            prop_oneof![Just(MAX_CHUNK as u16), 0u16..260],
            prop::bool::weighted(0.9)
        )
            .prop_map(|(skew, len, good)| Op::Chunk { skew, len, good }),
        (
            G_UPDATE..G_UPDATE + 0x98,
            prop::collection::vec(any::<u16>(), 1..123)
        )
            .prop_map(|(address, values)| Op::Raw { address, values }),
        Just(Op::Rest),
        Just(Op::Finish),
        Just(Op::Abort),
        Just(Op::FailNext),
        (0u16..50).prop_map(Op::Wait),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// No sequence of requests and flash failures panics the node or makes it write outside
    /// the partition or over bytes not erased (`Dfu::carry_out` would panic), and whatever
    /// the gateway marks is the image BEGIN declared.
    #[test]
    fn no_sequence_of_writes_panics_or_writes_outside_the_partition(
        ops in prop::collection::vec(op(), 1..40)
    ) {
        let mut rig = Rig::ready(1, |_| {});
        rig.dfu = Dfu::new(PARTITION);
        rig.node.set_update_target(Target { board: BOARD, partition: PARTITION as u32 });
        let source = image(80_000);
        for op in ops {
            match op {
                Op::Begin { size, board_ok } => {
                    let board = if board_ok { BOARD } else { BOARD + 1 };
                    let image = &source[..size as usize];
                    let _ = Link::Rtu.begin(&mut rig, image, board);
                }
                Op::Chunk { skew, len, good } => {
                    let next = rig.node.update().next_offset();
                    let offset = (i64::from(next) + i64::from(skew)).clamp(0, 79_000) as u32;
                    let start = offset as usize;
                    let end = (start + usize::from(len)).min(source.len());
                    let mut registers = chunk_registers(offset, &source[start..end]);
                    registers[2] = len;
                    if !good {
                        registers[3] ^= 1;
                    }
                    let _ = Link::Rtu.write(&mut rig, G_UPDATE_CHUNK, &registers);
                }
                Op::Raw { address, values } => {
                    let _ = Link::Rtu.write(&mut rig, address, &values);
                }
                Op::Rest => {
                    let size = Link::Rtu.status(&mut rig).size;
                    loop {
                        let next = rig.node.update().next_offset();
                        if next >= size
                            || Link::Rtu.chunk(&mut rig, &source[..size as usize], next).is_err()
                        {
                            break;
                        }
                    }
                }
                Op::Finish => {
                    let _ = Link::Rtu.write(&mut rig, G_UPDATE, &[FINISH]);
                }
                Op::Abort => {
                    let _ = Link::Rtu.write(&mut rig, G_UPDATE, &[ABORT]);
                }
                Op::FailNext => rig.dfu.fail_next = Some(UpdateError::Flash),
                Op::Wait(ms) => rig.run_for(u64::from(ms) * MS),
            }
            let status = Link::Rtu.status(&mut rig);
            prop_assert!(status.next <= status.received && status.received <= status.size);
            prop_assert!(status.size as usize <= PARTITION);
            if let Some((len, crc)) = rig.dfu.marked {
                prop_assert_eq!(crc32(&rig.dfu.flash[..len as usize]), crc);
            }
            if status.state == UpdateState::Ready as u16 {
                prop_assert_eq!(rig.dfu.marked, Some((status.size, status.crc32)));
            }
        }
    }
}

#[test]
fn updstat_codes_decode_to_their_states_and_errors() {
    for (code, state) in UpdateState::ALL.into_iter().enumerate() {
        assert_eq!(state as usize, code);
        assert_eq!(UpdateState::from_code(code as u16), Some(state));
    }
    for (code, error) in UpdateError::ALL.into_iter().enumerate() {
        assert_eq!(error as usize, code);
        assert_eq!(UpdateError::from_code(code as u16), Some(error));
    }
    assert_eq!(UpdateState::from_code(UpdateState::ALL.len() as u16), None);
    assert_eq!(UpdateError::from_code(UpdateError::ALL.len() as u16), None);
    let names: std::collections::BTreeSet<_> = UpdateState::ALL.iter().map(|s| s.name()).collect();
    let texts: std::collections::BTreeSet<_> = UpdateError::ALL.iter().map(|e| e.text()).collect();
    assert_eq!(
        names.len(),
        UpdateState::ALL.len(),
        "names tell states apart"
    );
    assert_eq!(
        texts.len(),
        UpdateError::ALL.len(),
        "texts tell errors apart"
    );
}

#[test]
fn a_finish_the_caller_refuses_keeps_its_reason_and_bootstat_tells_what_runs() {
    let mut rig = rig();
    // Not told: no bootloader.
    assert_eq!(
        rig.read(GW, G_BOOT_STATUS, G_BOOT_STATUS_LEN),
        Ok(vec![0, 0, 0])
    );
    rig.node.set_boot_state(BootState::Trial);
    assert_eq!(
        rig.read(GW, G_BOOT_STATUS, 1),
        Ok(vec![BootState::Trial as u16])
    );
    // An unsigned image: the chunks go in, FINISH's check of the trailer or the signature fails.
    let image = image(3_000);
    Link::Rtu.begin(&mut rig, &image, BOARD).unwrap();
    for offset in (0..image.len()).step_by(MAX_CHUNK) {
        Link::Rtu.chunk(&mut rig, &image, offset as u32).unwrap();
    }
    for refusal in [
        UpdateError::Signature,
        UpdateError::NotAnImage,
        UpdateError::OnTrial,
    ] {
        rig.dfu.fail_next = Some(refusal);
        Link::Rtu.write(&mut rig, G_UPDATE, &[FINISH]).unwrap();
        let status = Link::Rtu.status(&mut rig);
        assert_eq!(
            (status.state, status.error),
            (UpdateState::Failed as u16, refusal as u16)
        );
        assert_eq!(rig.dfu.marked, None);
        // BEGIN again and send it whole, for the next refusal.
        Link::Rtu.begin(&mut rig, &image, BOARD).unwrap();
        for offset in (0..image.len()).step_by(MAX_CHUNK) {
            Link::Rtu.chunk(&mut rig, &image, offset as u32).unwrap();
        }
    }
    // Signed: marked, and its version in BOOTSTAT.
    Link::Rtu.write(&mut rig, G_UPDATE, &[FINISH]).unwrap();
    rig.node.set_image_version(0x0102_0003);
    assert_eq!(Link::Rtu.status(&mut rig).state, UpdateState::Ready as u16);
    assert_eq!(
        rig.read(GW, G_BOOT_STATUS, G_BOOT_STATUS_LEN),
        Ok(vec![BootState::Trial as u16, 0x0102, 0x0003])
    );
    // Read-only.
    assert_eq!(
        Link::Rtu.write(&mut rig, G_BOOT_STATUS, &[1]),
        Err(3),
        "BOOTSTAT written"
    );
    for code in 0..4u16 {
        assert_eq!(BootState::from_code(code).map(|s| s as u16), Some(code));
    }
    assert_eq!(BootState::from_code(4), None);
}

#[test]
fn a_trial_passes_once_the_bus_is_established_and_the_plc_answered() {
    let config = protocol::plc::GatewayConfig::new(protocol::AxisSet::first(2));
    assert!(config.bus.establish, "this test needs the establishment");
    let mut rig = Rig::started(config, protocol::plc::Boot::DEFAULT, &[0, 1]);
    rig.drain();
    assert!(rig.node.gateway().engine().establishing());
    // The PLC answered while the bus is still being established: not yet.
    rig.read(GW, G_UPDATE_STATUS, 1).unwrap();
    assert!(!rig.node.trial_passed(), "passed during the establishment");
    rig.run_for(10_000 * MS);
    assert!(!rig.node.gateway().engine().establishing());
    assert!(rig.node.trial_passed());
    // Established, but nobody on the PLC link yet: not yet.
    let mut quiet = Rig::ready(2, |_| {});
    assert!(
        !quiet.node.trial_passed(),
        "passed with no PLC request answered"
    );
    quiet.read(GW, G_BOOT_STATUS, 1).unwrap();
    assert!(quiet.node.trial_passed());
}
