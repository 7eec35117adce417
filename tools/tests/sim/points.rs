//! The point table and the memory map: writes, read-back, auto-increment, illegal addresses.

use protocol::engine::point_jobs as jobs;
use protocol::frame::Frame;
use protocol::memory::{self, PointField};
use protocol::{Address, AlarmCode, Command, Transfer};
use rc_tools::sim::wire::ms;

use crate::{
    accept, axis, brief_point, controller, fast_host, home, point, read, reject, send, wait_pfin,
};

// ----- point table -----

#[test]
fn point_table_write_5_3_then_q3_and_read_back() {
    let mut host = fast_host(&[5]);
    let data = brief_point();
    let steps = jobs::write_point(axis(5), point(14), &data);
    // The brief edition's fourteen frames (§5-3 2; its W4 position frame has one F too many).
    let brief = [
        "5Q1010E0000083",
        "5T40000040008F",
        "5W4FFFFF352018",
        "5T40000040408B",
        "5W400000EA6064",
        "5T40000040508A",
        "5W400000093084",
        "5T40000040108E",
        "5W4000000C007D",
        "5T40000040308C",
        "5W40000000A07F",
        "5T400000409086",
        "5W400000000090",
        "5V5010E000007A",
    ];
    for (step, text) in steps.iter().zip(brief) {
        assert_eq!(
            step.request.emit(),
            Frame::from_text(text.as_bytes()).unwrap()
        );
    }
    let values = host.run_job(&steps).expect("write job");
    assert_eq!(values[13], Some(1), "first V5 of point 14");
    assert_eq!(controller(&host, 5).memory().nv.point_writes[14], 1);

    home(&mut host, 5);
    accept(&mut host, 5, Command::MoveToPoint(point(14)));
    let (_, done) = wait_pfin(&mut host, 5);
    assert_eq!(done.outputs.pm(), 14);
    host.wait(ms(20));
    assert_eq!(read(&mut host, 5, memory::PNOW.0), 0xFFFF_F352);
    // The move used the row's velocity and acceleration (FLGP 0xC0).
    assert_eq!(read(&mut host, 5, 0x7C04), 0xEA6);
    assert_eq!(read(&mut host, 5, 0x7C05), 0x93);

    let values = host
        .run_job(&jobs::read_point(axis(5), point(14)))
        .expect("read job");
    let readback = jobs::PointReadback(core::array::from_fn(|i| values[i + 1].unwrap()));
    assert!(readback.matches(&data), "{readback:?}");

    // Each V5 counts exactly once.
    let again = host.run_job(&jobs::write_field(axis(5), point(14), PointField::Band, 12));
    assert_eq!(again.expect("write field")[3], Some(2));
    let common_v5 = accept(
        &mut host,
        5,
        Command::StoreFromEdit(Transfer::CommonParameters),
    );
    assert_eq!(common_v5.reply.memory_value(), Some(1));
    // V5 answers later than other commands (the non-volatile write).
    assert!(common_v5.first_byte_at - common_v5.sent_end >= ms(3) + ms(20));
}

#[test]
fn w4_auto_increments_the_write_address() {
    let mut host = fast_host(&[2]);
    accept(&mut host, 2, Command::LoadToEdit(Transfer::Point(point(1))));
    let t4 = accept(
        &mut host,
        2,
        Command::SetWriteAddress {
            address: Address(0x404),
        },
    );
    assert_eq!(t4.reply.memory_value(), Some(0x404));
    let w1 = accept(&mut host, 2, Command::WriteMemory { value: 1_000 });
    assert_eq!(w1.reply.memory_value(), Some(0x405));
    let w2 = accept(&mut host, 2, Command::WriteMemory { value: 50 });
    assert_eq!(w2.reply.memory_value(), Some(0x406));
    assert_eq!(read(&mut host, 2, 0x404), 1_000);
    assert_eq!(read(&mut host, 2, 0x405), 50);
    // Past the row: illegal address.
    accept(
        &mut host,
        2,
        Command::SetWriteAddress {
            address: Address(0x409),
        },
    );
    accept(&mut host, 2, Command::WriteMemory { value: 0 });
    assert_eq!(
        reject(&mut host, 2, Command::WriteMemory { value: 0 }),
        0x61
    );
}

#[test]
fn memory_map_reads_and_illegal_addresses() {
    let mut host = fast_host(&[0]);
    assert_eq!(read(&mut host, 0, 0x780C), 3, "execution RTIM");
    assert_eq!(read(&mut host, 0, 0x7809), 0x14, "execution BRSL");
    assert_eq!(read(&mut host, 0, 0x00C), 3, "edit RTIM written by §6-1");
    assert_eq!(read(&mut host, 0, 0x6800), 0x104, "ROM version");
    assert_eq!(read(&mut host, 0, 0x017), 5, "lead type 8 mm");
    for address in [0x1234, 0x402, 0x780E, 0x7C01, 0x8000_0000] {
        let r = send(
            &mut host,
            0,
            Command::ReadMemory {
                address: Address(address),
            },
        );
        // A rejected memory command answers in the direct format, Func-Num slot 8-F (§4-3).
        assert_eq!(r.reply.rejection(), Some(AlarmCode(0x61)), "{address:X}");
        let text = r.reply.emit().to_text();
        assert_eq!(&text[..3], b"U0R");
        assert!((b'8'..=b'F').contains(&text[3]));
    }
    assert_eq!(
        reject(
            &mut host,
            0,
            Command::SetWriteAddress {
                address: memory::PNOW
            }
        ),
        0x61
    );
}
