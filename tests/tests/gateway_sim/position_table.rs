//! The position table at 0x1000: rows read on demand and written whole, the row cache against
//! table writes and the command channel, reads that never reach the bus, and what a table write
//! leaves alone.

use protocol::modbus::Exception;
use protocol::plc::map::*;
use protocol::plc::CommandState;
use protocol::units::Length;
use protocol::Command;
use rc_host::node_harness::NodeHarness;

use crate::{
    axis, coil, gateway, gateway_with, home, pnow_mm100, read, scale, settle, unit, write, MS, S,
};

const ROW3: u16 = 0x1000 + 16 * 3;

/// Row registers: `pcmd` (0.01 mm), band 0.10 mm, 80 mm/s, 0.3 G.
fn row_regs(pcmd: u32) -> [u16; 16] {
    let mut v = [0u16; 16];
    v[0] = (pcmd >> 16) as u16;
    v[1] = pcmd as u16;
    v[3] = 10;
    v[5] = 80_00;
    v[10] = 30;
    v[11] = 30;
    v
}

/// The same row in the controller's units, as a point write stores it.
fn row_wire(pcmd: i32) -> [u32; 10] {
    use protocol::units::{Accel, Speed};
    let s = scale();
    let mut r = [0u32; 10];
    r[0] = s.position_to_wire(Length(pcmd)).unwrap().to_wire();
    r[1] = 0xC0;
    r[3] = s.band_to_wire(Length(10)).unwrap();
    r[4] = s.velocity(Speed(80_00)).unwrap().get().into();
    r[5] = s.acceleration(Accel(30)).unwrap().get().into();
    r
}

/// Point `p`'s stored position on the controller, pulses.
fn stored_pos(h: &NodeHarness, a: u8, p: usize) -> i32 {
    h.bus.controller(axis(a)).unwrap().memory().nv.points[p][0] as i32
}

fn stored_mm100(pcmd: i32) -> i32 {
    scale().position_to_wire(Length(pcmd)).unwrap().0
}

#[test]
fn position_table_rows_read_on_demand_and_written_whole() {
    let mut h = gateway(1);
    let row = |n: u16| 0x1000 + 16 * n;
    // Not read yet: exception 04 while the gateway fetches it, then the row.
    assert_eq!(
        read(&mut h, unit(0), row(3), 16),
        Err(Exception::ServerDeviceFailure)
    );
    h.run_until(h.now + 200 * MS);
    let r3 = read(&mut h, unit(0), row(3), 16).unwrap();
    assert_eq!((r3[0], r3[1]), (0, 40_00), "PCMD 40.00 mm");
    // Write row 5: 62.50 mm, band 0.10 mm, 80 mm/s, 0.3 G (DCMD = ACMD).
    let mut values = [0u16; 16];
    values[1] = 62_50;
    values[3] = 10;
    values[5] = 80_00;
    values[10] = 30;
    values[11] = 30;
    write(&mut h, unit(0), row(5), &values).unwrap();
    // A PLC sees the row stored by reading it back (04 until the verified row is there).
    let mut r5 = Err(Exception::ServerDeviceFailure);
    for _ in 0..100 {
        h.run_until(h.now + 20 * MS);
        r5 = read(&mut h, unit(0), row(5), 16);
        if r5.is_ok() {
            break;
        }
    }
    let r5 = r5.unwrap();
    assert_eq!(
        (r5[1], r5[3], r5[5], r5[10], r5[11]),
        (62_50, 10, 80_00, 30, 30),
        "{r5:?}"
    );
    // The same row again: nothing is written (no command taken, no V5).
    let taken = read(&mut h, unit(0), CMCT, 1).unwrap();
    write(&mut h, unit(0), row(5), &values).unwrap();
    assert_eq!(read(&mut h, unit(0), CMCT, 1).unwrap(), taken);
    // CSTR to point 5 goes there.
    home(&mut h, 0);
    write(&mut h, unit(0), POSR, &[5]).unwrap();
    write(&mut h, unit(0), DRG1, &[DRG1_SON | DRG1_CSTR]).unwrap();
    assert_eq!(settle(&mut h, 0, 10 * S), (CommandState::Done, 0));
    assert_eq!(pnow_mm100(&mut h, 0), 62_50);
    // Refused: part of a row, an unsupported field, beyond the stroke.
    assert_eq!(
        write(&mut h, unit(0), row(5) + 2, &[0, 10]),
        Err(Exception::IllegalDataAddress)
    );
    let mut zoned = values;
    zoned[7] = 1;
    assert_eq!(
        write(&mut h, unit(0), row(6), &zoned),
        Err(Exception::IllegalDataValue)
    );
    let mut far = values;
    far[0] = 1;
    assert_eq!(
        write(&mut h, unit(0), row(6), &far),
        Err(Exception::IllegalDataValue)
    );
}

/// A table read that started before a write must not put the old row back in the cache (a
/// later write of the old values would then be skipped).
#[test]
fn a_read_started_before_a_write_does_not_refill_the_cache() {
    let mut h = gateway_with(1, 100_00, Some(row_wire(40_00)), &[]);
    assert_eq!(
        read(&mut h, unit(0), ROW3, 16),
        Err(Exception::ServerDeviceFailure)
    );
    write(&mut h, unit(0), ROW3, &row_regs(60_00)).unwrap();
    h.run_until(h.now + 3 * S);
    let _ = read(&mut h, unit(0), ROW3, 16);
    h.run_until(h.now + 300 * MS);
    write(&mut h, unit(0), ROW3, &row_regs(40_00)).unwrap();
    h.run_until(h.now + 3 * S);
    assert_eq!(
        stored_pos(&h, 0, 3),
        stored_mm100(40_00),
        "the PLC's last write wins"
    );
}

/// A command-channel write the PLC abandons still invalidates the table's cached row.
#[test]
fn an_abandoned_channel_write_invalidates_the_cached_row() {
    let mut h = gateway_with(1, 100_00, Some(row_wire(40_00)), &[]);
    let _ = read(&mut h, unit(0), ROW3, 16);
    h.run_until(h.now + 200 * MS);
    assert!(read(&mut h, unit(0), ROW3, 16).is_ok());
    // 60 mm, in the channel's 0.01 mm.
    write(&mut h, 63, G_REQUEST, &[2, 0, 3, 0, 0, 60_00]).unwrap();
    let sent0 = h.sent.len();
    for _ in 0..200 {
        h.run_until(h.now + MS);
        if h.sent[sent0..]
            .iter()
            .any(|(_, r)| matches!(r.command, protocol::Command::WriteMemory { .. }))
        {
            break;
        }
    }
    write(&mut h, 63, G_REQUEST, &[0]).unwrap();
    h.run_until(h.now + 2 * S);
    assert_eq!(
        stored_pos(&h, 0, 3),
        stored_mm100(60_00),
        "the channel write happened"
    );
    write(&mut h, unit(0), ROW3, &row_regs(40_00)).unwrap();
    h.run_until(h.now + 2 * S);
    assert_eq!(
        stored_pos(&h, 0, 3),
        stored_mm100(40_00),
        "not skipped against a stale row"
    );
}

/// Invalid reads of the table (FC04, or a range starting at an undefined address) get 02 and
/// put nothing on the bus.
#[test]
fn invalid_table_reads_never_reach_the_bus() {
    let mut h = gateway(1);
    h.run_until(h.now + 50 * MS);
    let before = h.sent.len();
    assert_eq!(
        h.read_registers(unit(0), ROW3, 16, true),
        Err(Exception::IllegalDataAddress)
    );
    assert_eq!(
        h.read(unit(0), 0x0FFF, 2),
        Err(Exception::IllegalDataAddress)
    );
    h.run_until(h.now + 200 * MS);
    let q1 = h.sent[before..]
        .iter()
        .filter(|(_, r)| matches!(r.command, protocol::Command::LoadToEdit(_)))
        .count();
    assert_eq!(q1, 0);
}

/// A table write does not take over CMST (nor unmask PEND of a starting move).
#[test]
fn a_table_write_leaves_the_command_status_alone() {
    let mut h = gateway_with(1, 100_00, Some(row_wire(40_00)), &[]);
    home(&mut h, 0);
    write(&mut h, unit(0), POSR, &[3]).unwrap();
    write(&mut h, unit(0), DRG1, &[DRG1_SON | DRG1_CSTR]).unwrap();
    let before = read(&mut h, unit(0), CMST, 4).unwrap();
    write(&mut h, unit(0), 0x1000 + 16 * 5, &row_regs(10_00)).unwrap();
    assert_eq!(read(&mut h, unit(0), CMST, 4).unwrap(), before);
    assert_eq!(
        read(&mut h, unit(0), DSS1, 1).unwrap()[0] >> 3 & 1,
        0,
        "PEND off while starting"
    );
}

/// A row read and written back unchanged costs no write (no V5), whatever the rounding.
#[test]
fn writing_back_a_row_as_read_writes_nothing() {
    let mut h = gateway_with(1, 100_00, Some(row_wire(33_33)), &[]);
    let _ = read(&mut h, unit(0), ROW3, 16);
    h.run_until(h.now + 200 * MS);
    let row = read(&mut h, unit(0), ROW3, 16).unwrap();
    let sent = h.sent.len();
    write(&mut h, unit(0), ROW3, &row).unwrap();
    h.run_until(h.now + 500 * MS);
    let writes = h.sent[sent..]
        .iter()
        .filter(|(_, r)| matches!(r.command, protocol::Command::WriteMemory { .. }))
        .count();
    assert_eq!(writes, 0);
}

/// Reading the table of an offline axis does not put its frames on the bus.
#[test]
fn the_table_of_an_offline_axis_is_not_fetched() {
    let mut h = gateway_with(2, 100_00, None, &[1]);
    h.run_until(2 * S);
    let s0 = h.sent.len();
    for _ in 0..200 {
        h.run_until(h.now + 10 * MS);
        assert_eq!(
            read(&mut h, unit(1), ROW3, 16),
            Err(Exception::ServerDeviceFailure)
        );
    }
    let jobs = h.sent[s0..]
        .iter()
        .filter(|(_, r)| r.axis == axis(1) && r.command != protocol::Command::Status)
        .count();
    assert_eq!(jobs, 0, "no point-table frames to the dead axis");
    let polls0 = h.sent[s0..]
        .iter()
        .filter(|(_, r)| r.axis == axis(0) && r.command == protocol::Command::Status)
        .count();
    assert!(polls0 > 150, "the live axis keeps its cycle: {polls0}");
}

/// Issue 34's soak finding (seed 31337): an axis stopped while the PLC kept writing point rows
/// of the others went 4 s without a position read, so its PNOW showed where the move was, not
/// where it stopped. Job frames (the rows' writes) go before polls; they must not keep a
/// stopped axis' position read off the bus for long.
#[test]
fn a_stopped_axis_is_read_where_it_stopped_while_table_writes_fill_the_bus() {
    const SLOW_MOVE: [u16; 7] = [0, 90_00, 0, 10, 0, 2_00, 30];
    let mut h = gateway(4);
    for a in 0..4 {
        home(&mut h, a);
    }
    write(&mut h, unit(0), DIRECT, &SLOW_MOVE).unwrap();
    let mut pcmd = 10_00;
    // Rows 1-9 of axes 1-3 rewritten as fast as the gateway takes them, for `us`.
    let mut fill = |h: &mut NodeHarness, us: u64| {
        let until = h.now + us;
        while h.now < until {
            for a in 1..4 {
                pcmd = if pcmd >= 90_00 { 10_00 } else { pcmd + 1 };
                let row = 0x1000 + 16 * (1 + pcmd % 9);
                let _ = write(h, unit(a), row, &row_regs(pcmd.into()));
            }
            h.run_for(2 * MS);
        }
    };
    fill(&mut h, S);
    let moving = |h: &NodeHarness| h.bus.controller(axis(0)).unwrap().moving();
    assert!(moving(&h), "axis 0 moves");
    let writes = |h: &NodeHarness| {
        h.sent
            .iter()
            .filter(|(_, r)| r.axis != axis(0) && r.command != Command::Status)
            .count()
    };
    let before = writes(&h);
    coil(&mut h, unit(0), COIL_STOP, true).unwrap();
    let stopped_at = h.now;
    fill(&mut h, 500 * MS);
    assert!(!moving(&h), "axis 0 stopped");
    assert!(
        writes(&h) > before + 40,
        "the rows' writes filled the bus: {} frames",
        writes(&h) - before
    );
    let rest = h.bus.controller(axis(0)).unwrap().position();
    let known = h.node.gateway().engine().axis(axis(0)).position;
    assert_eq!(
        known.map(|p| i64::from(p.0)),
        Some(rest),
        "500 ms after the stop (at {stopped_at} us), the gateway knows where axis 0 rests"
    );
}
