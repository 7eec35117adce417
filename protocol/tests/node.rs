//! The Node (and the gateway inside it) against scripted controllers and a Modbus master, in
//! virtual time: the firmware's object end to end, down to the bytes on both lines.
//! Regressions for the defects found by driving the PC gateway with other masters and an
//! independently written simulator are marked with the defect they pin.
#![allow(clippy::inconsistent_digit_grouping)]

mod support;

use protocol::engine::Link;
use protocol::line::LineAction;
use protocol::modbus::{Exception, Request as Modbus};
use protocol::node::Node;
use protocol::pio::{Pattern, PioInputs, PioOutputs, Ports};
use protocol::plc::map::*;
use protocol::plc::{GatewayConfig, Reason, WatchdogTime};
use protocol::time::{Duration, Instant};
use protocol::{AxisSet, Command};
use support::*;

// ---------------------------------------------------------------- the Node's contract

#[test]
fn a_modbus_request_gets_its_reply_and_a_broadcast_none() {
    let mut rig = Rig::ready(2, |_| {});
    assert_eq!(rig.read(1, LINK, 1), Ok(vec![1]));
    assert_eq!(rig.read(63, G_VERSION, 1), Ok(vec![0x0001]));
    // A broadcast is applied and never answered.
    assert_eq!(
        rig.modbus(
            0,
            &Modbus::WriteSingleRegister {
                address: POSR,
                value: 4
            }
        ),
        None
    );
    assert_eq!(rig.read(1, POSR, 1), Ok(vec![4]));
    assert_eq!(rig.read(2, POSR, 1), Ok(vec![4]));
    // A unit nobody serves: no answer, counted.
    let ignored = rig.node.plc_counters().ignored;
    assert_eq!(
        rig.modbus(
            7,
            &Modbus::ReadHoldingRegisters {
                address: LINK,
                quantity: 1
            }
        ),
        None
    );
    assert_eq!(rig.node.plc_counters().ignored, ignored + 1);
}

#[test]
fn poll_at_is_the_earliest_deadline_and_harmless_early() {
    let mut rig = Rig::ready(1, |_| {});
    rig.run_for(10 * MS);
    let at = rig.node.poll_at().expect("polling never stops");
    assert!(at.0 > rig.now, "nothing due now after an idle answer");
    // Polling early changes nothing: no frame before the deadline.
    let sent = rig.sent.len();
    assert!(rig.node.poll(Instant(rig.now)).is_none());
    assert_eq!(rig.sent.len(), sent);
    // A Modbus frame arriving moves the deadline to its t3.5.
    let mut adu = [0u8; 16];
    let len = Modbus::ReadHoldingRegisters {
        address: LINK,
        quantity: 1,
    }
    .emit(1, &mut adu)
    .unwrap();
    rig.node.plc_received(Instant(rig.now), &adu[..len]);
    let t35 = Instant(rig.now) + Duration::from_micros(1_750);
    assert!(rig.node.poll_at().is_some_and(|t| t <= t35));
}

/// Item 2: `Gateway::poll` merged the watchdog deadline with `Option::min`, so with no engine
/// deadline (no axis at all) the idle answer was `None` and a firmware sleeping on it never
/// tripped the watchdog.
#[test]
fn the_watchdog_deadline_survives_an_engine_without_one() {
    let mut config = GatewayConfig::new(AxisSet::EMPTY);
    config.bus.establish = false;
    let mut rig = Rig::new(config, &[]);
    rig.run_for(10 * MS);
    // The PLC talks once: the watchdog is armed (1 s).
    assert_eq!(rig.read(63, G_FAILSAFE, 1), Ok(vec![0]));
    let armed_at = rig.now;
    rig.run_for(10 * MS);
    let at = rig.node.poll_at().expect("the watchdog is due");
    assert!(
        at.0 > armed_at + 999 * MS && at.0 <= armed_at + 1_001 * MS,
        "{at:?}"
    );
    // Sleeping exactly as told trips it.
    rig.run_until(at.0 + 1);
    assert_eq!(rig.node.gateway().failsafe(), CAUSE_WATCHDOG_BIT);
}

const CAUSE_WATCHDOG_BIT: u16 = protocol::plc::CAUSE_WATCHDOG;

#[test]
fn the_pio_drives_its_axis_and_shows_safe_outputs_until_it_answers() {
    let mut config = GatewayConfig::new(AxisSet::first(1));
    config.bus.establish = false;
    config.settings.pio_axis = Some(axis(0));
    config.settings.watchdog = WatchdogTime::OFF;
    let mut rig = Rig::new(config, &[0]);
    rig.bus.fake(0).silent = true;
    rig.bus.fake(0).homed = true;
    let run = |rig: &mut Rig, inputs: PioInputs, ms: u64| {
        for _ in 0..ms {
            rig.node.sample_inputs(Instant(rig.now), inputs);
            rig.run_for(MS);
        }
    };
    run(&mut rig, PioInputs::STP_N, 200);
    assert_eq!(rig.node.outputs(), PioOutputs::SAFE, "axis silent: all off");
    assert!(rig.node.indicators().alarm && !rig.node.indicators().link);
    rig.bus.fake(0).silent = false;
    run(&mut rig, PioInputs::STP_N, 600);
    assert!(rig.node.outputs().link() && rig.node.outputs().alm_n());
    assert!(rig.node.indicators().link && !rig.node.indicators().alarm);
    // SON turns the servo on, CSTR moves to the point on PC1-PC8.
    let son = PioInputs::STP_N | PioInputs::SON;
    run(&mut rig, son, 200);
    assert!(rig.bus.fake(0).servo && rig.node.outputs().sv());
    let p3 = son.with_position(point(3));
    run(&mut rig, p3, 20);
    run(&mut rig, p3 | PioInputs::CSTR, 20);
    run(&mut rig, p3, 300);
    assert!(rig.node.outputs().pend(), "in position");
    assert_eq!(rig.node.outputs().pm(), 3, "PM shows the point reached");
    let fake = rig.bus.fake(0);
    assert_eq!(fake.position, fake.points[3][0] as i32);
    assert!(rig
        .commands_to(0, 0)
        .contains(&Command::MoveToPoint(point(3))));
    // The PLC takes the discrete I/O off the axis (PIOAXIS none): every output OFF at once,
    // with no new input sample (the firmware samples only changes then).
    assert_ne!(rig.node.outputs(), PioOutputs::SAFE);
    assert_eq!(rig.write(63, G_PIO_AXIS, &[0xFFFF]), Ok(()));
    rig.run_for(MS);
    assert_eq!(rig.node.outputs(), PioOutputs::SAFE);
}

#[test]
fn break_start_and_end_are_both_actions() {
    let mut config = GatewayConfig::new(AxisSet::first(1));
    config.bus.establish = true;
    let mut rig = Rig::new(config, &[0]);
    rig.run_for(400 * MS);
    let start = rig
        .lines
        .iter()
        .find(|(_, a)| *a == LineAction::BreakStart)
        .expect("a break")
        .0;
    let end = rig
        .lines
        .iter()
        .find(|(_, a)| *a == LineAction::BreakEnd)
        .expect("its end")
        .0;
    assert_eq!(end - start, u64::from(protocol::line::BREAK_MS) * MS);
    assert!(
        rig.sent.iter().all(|(t, _)| *t < start || *t >= end),
        "nothing sent during the break"
    );
}

// ---------------------------------------------------------------- defects (item 5)

/// On a transport without wire time, a controller answers RTIM after the command, sooner than
/// the earliest-answer bound: every answer was discarded and every axis went offline.
#[test]
fn answers_without_wire_time_are_accepted_where_the_bound_is_off() {
    let mut rig = Rig::ready(2, |c| c.bus.wire_timing = false);
    rig.bus.transport = Transport::Instant;
    rig.run_for(500 * MS);
    for a in 0..2 {
        assert_eq!(rig.node.gateway().engine().axis(axis(a)).link, Link::Online);
    }
    // The same transport with the bound on (a UART) loses them: the bound is what the flag
    // switches.
    let mut rig = Rig::ready(1, |_| {});
    rig.bus.transport = Transport::Instant;
    rig.run_for(500 * MS);
    assert_eq!(
        rig.node.gateway().engine().axis(axis(0)).link,
        Link::Offline
    );
}

/// A command for an axis that has not been online since start was taken, showed CMST 1 and ran
/// seconds later when the axis appeared.
#[test]
fn a_command_for_an_axis_not_online_is_refused_and_never_runs_late() {
    let mut rig = Rig::ready(2, |_| {});
    rig.bus.fake(1).silent = true;
    let mut config = GatewayConfig::new(AxisSet::first(2));
    config.bus.establish = false;
    // Start again with axis 1 silent from the beginning.
    let fakes = std::mem::take(&mut rig.bus.axes);
    let mut rig = Rig::new(config, &[]);
    rig.bus.axes = fakes;
    rig.run_for(300 * MS);
    assert_eq!(rig.read(2, LINK, 1), Ok(vec![2]), "offline");
    assert_eq!(
        rig.write(2, DRG1, &[DRG1_SON | DRG1_HOME]),
        Err(Exception::ServerDeviceFailure)
    );
    assert_eq!(rig.read(2, DRG1, 1), Ok(vec![0]), "nothing stored");
    assert_eq!(rig.read(2, CMST, 2), Ok(vec![0, 0]), "nothing taken");
    assert_eq!(
        rig.write(2, DIRECT, &[0, 10_00, 0, 10, 0, 50_00, 30]),
        Err(Exception::ServerDeviceFailure)
    );
    // The axis appears: nothing runs.
    rig.bus.fake(1).silent = false;
    let appeared = rig.now;
    rig.run_for(3 * S);
    assert_eq!(rig.read(2, LINK, 1), Ok(vec![1]), "back online");
    let late: Vec<_> = rig
        .commands_to(1, appeared)
        .into_iter()
        .filter(|c| c.moves() || matches!(c, Command::Servo(_)))
        .collect();
    assert!(late.is_empty(), "ran late: {late:?}");
    // A stop is always taken (it can only help).
    assert_eq!(rig.coil(2, COIL_STOP, true), Ok(()));
}

/// After a restart the gateway had no cached row: writing a row identical to the controller's
/// spent a V5.
#[test]
fn writing_a_row_the_controller_already_holds_spends_no_v5_after_a_restart() {
    let mut rig = Rig::ready(1, |_| {});
    // Point 3 holds 30 mm at 100 mm/s, 0.3 G, band 0.1 mm (what a PLC would write back).
    let row = [0, 30_00, 0, 10, 0, 100_00, 0, 0, 0, 0, 30, 0, 0, 0, 0, 0];
    rig.write(1, 0x1000 + 16 * 3, &row).unwrap();
    rig.run_for(500 * MS);
    assert_eq!(rig.bus.fake(0).v5_writes, 1, "stored once");
    // "Restart": a new node, the same controller.
    let fakes = std::mem::take(&mut rig.bus.axes);
    let mut rig = Rig::ready(1, |_| {});
    rig.bus.axes = fakes;
    rig.run_for(100 * MS);
    rig.write(1, 0x1000 + 16 * 3, &row).unwrap();
    rig.run_for(500 * MS);
    assert_eq!(
        rig.bus.fake(0).v5_writes,
        1,
        "compared first, nothing written"
    );
    assert_eq!(rig.read(1, 0x1000 + 16 * 3, 2), Ok(vec![0, 30_00]));
    // A different row is written (and verified).
    let mut other = row;
    other[1] = 40_00;
    rig.write(1, 0x1000 + 16 * 3, &other).unwrap();
    rig.run_for(500 * MS);
    assert_eq!(rig.bus.fake(0).v5_writes, 2);
}

/// README documents 0x9900-0x9908 as readable; FC03 answered 02.
#[test]
fn the_direct_move_registers_read_back() {
    let mut rig = Rig::ready(1, |_| {});
    assert_eq!(rig.read(1, DIRECT, 9), Ok(vec![0; 9]));
    let mv = [0, 25_00, 0, 10, 0, 50_00, 30];
    rig.write(1, DIRECT, &mv).unwrap();
    assert_eq!(
        rig.read(1, DIRECT, 9),
        Ok(vec![0, 25_00, 0, 10, 0, 50_00, 30, 0, 0])
    );
    // A refused move leaves them as they were.
    assert_eq!(
        rig.write(1, DIRECT, &[0, 250_00, 0, 10, 0, 50_00, 30]),
        Err(Exception::IllegalDataValue)
    );
    assert_eq!(rig.read(1, DIRECT, 2), Ok(vec![0, 25_00]));
    // FC04 is for the status registers only.
    assert_eq!(
        rig.read_input(1, DIRECT, 1),
        Err(Exception::IllegalDataAddress)
    );
}

/// Writes to read-only registers of unit 63 answered 02; the axis units answer 03.
#[test]
fn read_only_gateway_registers_refuse_writes_with_03() {
    let mut rig = Rig::ready(1, |_| {});
    for address in [
        G_VERSION,
        G_UPTIME,
        G_FAILSAFE_COUNT,
        G_SYNC_STATUS,
        G_RESPONSE,
        G_DIAG,
        G_BUS,
        G_PLC,
    ] {
        assert_eq!(
            rig.write(63, address, &[1]),
            Err(Exception::IllegalDataValue),
            "{address:#06X}"
        );
    }
    assert_eq!(rig.write(1, PNOW, &[1]), Err(Exception::IllegalDataValue));
    // Addresses that do not exist stay 02.
    assert_eq!(
        rig.write(63, 0x0050, &[1]),
        Err(Exception::IllegalDataAddress)
    );
    // AXISCFG: a zero lead or pulses/rev would divide by zero: refused.
    assert_eq!(
        rig.write(63, G_AXIS_CONFIG + 1, &[0]),
        Err(Exception::IllegalDataValue)
    );
    assert_eq!(
        rig.write(63, G_AXIS_CONFIG + 3, &[0]),
        Err(Exception::IllegalDataValue)
    );
}

/// FC08 (diagnostics echo) did not feed the PLC watchdog.
#[test]
fn an_echo_request_feeds_the_watchdog() {
    let mut rig = Rig::ready(1, |c| {
        c.settings.watchdog = WatchdogTime::from_millis(200).unwrap()
    });
    assert_eq!(rig.read(63, G_FAILSAFE, 1), Ok(vec![0]));
    for _ in 0..10 {
        rig.run_for(100 * MS);
        let echo = Modbus::ReturnQueryData {
            data: &[0x12, 0x34],
        };
        assert_eq!(rig.modbus(63, &echo), Some(Ok(vec![0, 0, 0x12, 0x34])));
    }
    assert_eq!(
        rig.node.gateway().failsafe(),
        0,
        "1 s of echoes only: no trip"
    );
    // Silence trips it.
    rig.run_for(300 * MS);
    assert_eq!(rig.node.gateway().failsafe(), protocol::plc::CAUSE_WATCHDOG);
    // So does an exception reply count as activity (a valid request all the same).
    rig.write(63, G_FAILSAFE, &[0]).unwrap();
    for _ in 0..5 {
        rig.run_for(100 * MS);
        assert_eq!(
            rig.write(63, 0x0050, &[1]),
            Err(Exception::IllegalDataAddress)
        );
    }
    assert_eq!(rig.node.gateway().failsafe(), 0);
}

/// A synchronized start left each axis' CMST/CMCT unchanged.
#[test]
fn a_synchronized_start_shows_on_each_axis_of_the_mask() {
    let mut rig = Rig::ready(3, |_| {});
    rig.write(1, POSR, &[2]).unwrap();
    rig.write(3, POSR, &[4]).unwrap();
    let cmct = |rig: &mut Rig, a: u8| rig.read(a + 1, CMCT, 1).unwrap()[0];
    let before = [cmct(&mut rig, 0), cmct(&mut rig, 1), cmct(&mut rig, 2)];
    rig.write(63, G_SYNC_MASK, &[0b101]).unwrap();
    rig.write(63, G_SYNC_START, &[1]).unwrap();
    for a in [0, 2] {
        assert_eq!(rig.read(a + 1, CMST, 1), Ok(vec![1]), "axis {a} taken");
        assert_eq!(cmct(&mut rig, a), before[usize::from(a)] + 1);
    }
    assert_eq!(cmct(&mut rig, 1), before[1], "axis 1 is not in the mask");
    for a in [0, 2] {
        assert_eq!(rig.settle(a, 2 * S), (2, 0), "axis {a} done");
    }
    assert_eq!(rig.read(63, G_SYNC_STATUS, 1), Ok(vec![2]));
    assert_eq!(rig.bus.fake(0).position, -2000);
    assert_eq!(rig.bus.fake(2).position, -4000);
    // A stop during the next start fails it on every axis of the mask, with reason 6.
    rig.write(1, POSR, &[9]).unwrap();
    rig.write(3, POSR, &[9]).unwrap();
    rig.write(63, G_SYNC_START, &[1]).unwrap();
    rig.coil(1, COIL_STOP, true).unwrap();
    for a in [0, 2] {
        assert_eq!(
            rig.read(a + 1, CMST, 2),
            Ok(vec![3, Reason::Cancelled.code(0)]),
            "axis {a}"
        );
    }
}

/// DSSE GHMS read "homing" during the motor initialisation after a servo-on.
#[test]
fn ghms_shows_homing_only() {
    let mut rig = Rig::ready(1, |_| {});
    rig.bus.fake(0).servo = false;
    rig.bus.fake(0).homed = false;
    rig.run_for(50 * MS);
    const GHMS: u16 = 1 << 11;
    const MOVE: u16 = 1 << 5;
    rig.write(1, DRG1, &[DRG1_SON]).unwrap();
    // During the motor initialisation: not in position, but not homing either.
    let mut saw_init = false;
    for _ in 0..10 {
        rig.run_for(3 * MS);
        let dsse = rig.read(1, DSSE, 1).unwrap()[0];
        assert_eq!(dsse & GHMS, 0, "GHMS during initialisation");
        saw_init |= dsse & MOVE != 0;
    }
    assert!(saw_init, "the initialisation showed as not in position");
    rig.run_for(100 * MS);
    rig.write(1, DRG1, &[DRG1_SON | DRG1_HOME]).unwrap();
    rig.run_for(30 * MS);
    assert_ne!(
        rig.read(1, DSSE, 1).unwrap()[0] & GHMS,
        0,
        "GHMS while homing"
    );
    rig.settle(0, S);
    assert_eq!(rig.read(1, DSSE, 1).unwrap()[0] & GHMS, 0, "homed");
}

// ---------------------------------------------------------------- size

/// All protocol state for 16 axes fits a small MCU (with TCP, the Ethernet board's budget). (On the host `usize` is 8 bytes, so these
/// figures bound the thumbv7em ones from above; the firmware build checks its own.)
#[test]
fn the_whole_state_fits_12_kib() {
    let sizes = [
        ("Node", std::mem::size_of::<Node>()),
        ("Gateway", std::mem::size_of::<protocol::plc::Gateway>()),
        ("Engine", std::mem::size_of::<protocol::engine::Engine>()),
        ("Slave", std::mem::size_of::<protocol::modbus::Slave>()),
        (
            "Receiver",
            std::mem::size_of::<protocol::modbus::Receiver>(),
        ),
        ("Pio", std::mem::size_of::<protocol::pio::Pio>()),
        #[cfg(feature = "tcp")]
        (
            "TcpServer",
            std::mem::size_of::<protocol::modbus::tcp::Server>(),
        ),
    ];
    for (name, size) in sizes {
        println!("{name:>9}: {size:>6} bytes");
    }
    assert!(std::mem::size_of::<Node>() <= protocol::node::RAM_BUDGET);
}

/// A request whose bytes come in two bursts further apart than t3.5 (a socket, not a wire):
/// split in two, it gets no answer; with `plc_frame_gap` longer than the pause, it is one
/// request and answered.
#[test]
fn a_frame_gap_longer_than_t3_5_keeps_a_request_read_in_two_bursts_whole() {
    for (gap, answered) in [(None, false), (Some(Duration::from_millis(20)), true)] {
        let mut rig = Rig::ready(1, |c| c.plc_frame_gap = gap);
        let request = Modbus::ReadHoldingRegisters {
            address: LINK,
            quantity: 1,
        };
        let mut adu = [0u8; 256];
        let len = request.emit(1, &mut adu).unwrap();
        let replies = rig.node.plc_counters().replies;
        rig.node.plc_received(Instant(rig.now), &adu[..3]);
        rig.run_for(5 * MS); // 5 ms: longer than t3.5 at 115.2 kbit/s (1.75 ms)
        rig.node.plc_received(Instant(rig.now), &adu[3..len]);
        rig.run_for(50 * MS);
        assert_eq!(
            rig.node.plc_counters().replies > replies,
            answered,
            "gap {gap:?}"
        );
    }
}

/// The firmware reads a request's first bytes, then sends a bus frame (16.7 ms at 9.6 kbit/s,
/// not polling the node meanwhile), then reads the rest, which waited in the UART. Handed over
/// with when the task last found the line empty (`plc_received_between`), the request is whole
/// and answered; stamped with the time of the read alone, it was cut in two (no reply, a CRC
/// error: rcgw's "no reply" against the firmware in QEMU).
#[test]
fn a_request_whose_rest_waited_through_a_bus_send_is_answered() {
    for waited in [true, false] {
        let mut rig = Rig::ready(1, |_| {});
        let request = Modbus::ReadHoldingRegisters {
            address: LINK,
            quantity: 1,
        };
        let mut adu = [0u8; 256];
        let len = request.emit(1, &mut adu).unwrap();
        let (replies, crc_errors) = (
            rig.node.plc_counters().replies,
            rig.node.plc_counters().crc_errors,
        );
        let looked = Instant(rig.now);
        rig.node.plc_received(looked, &adu[..3]);
        rig.now += 16_700;
        let read = Instant(rig.now);
        let since = if waited { looked } else { read };
        rig.node.plc_received_between(since, read, &adu[3..len]);
        rig.run_for(50 * MS);
        let counters = rig.node.plc_counters();
        assert_eq!(
            (counters.replies > replies, counters.crc_errors > crc_errors),
            (waited, !waited),
            "waited {waited}"
        );
    }
}

/// PIOPAT: a pattern whose ports the board lacks is refused (03) and PIOPAT stays; one it has
/// is in force at once, and a strobe the PIO refuses shows in CMST (3, reason 13, the inputs).
#[test]
fn a_pio_pattern_needs_the_boards_ports_and_a_refused_strobe_shows_in_cmst() {
    let mut rig = Rig::ready(1, |c| {
        c.settings.pio_axis = Some(axis(0));
        c.settings.watchdog = WatchdogTime::OFF;
        c.pio_ports = Ports {
            inputs: Pattern::Positioning.inputs(),
            outputs: Pattern::Positioning.outputs(),
        };
    });
    let run = |rig: &mut Rig, inputs: PioInputs, ms: u64| {
        for _ in 0..ms {
            rig.node.sample_inputs(Instant(rig.now), inputs);
            rig.run_for(MS);
        }
    };
    assert_eq!(
        rig.write(63, G_PIO_PATTERN, &[4]),
        Err(Exception::IllegalDataValue),
        "no IN6, OUT4, OUT5"
    );
    assert_eq!(rig.read(63, G_PIO_PATTERN, 1), Ok(vec![0]));
    // Pattern 0: CSTR with PC16 ON selects no point of the RC's 16.
    let base = PioInputs::STP_N | PioInputs::SON;
    run(&mut rig, base, 50);
    let pc = base.with_position(point(3)) | PioInputs::PC16;
    run(&mut rig, pc, 20);
    run(&mut rig, pc | PioInputs::CSTR, 20);
    assert_eq!(rig.read(1, CMST, 2), Ok(vec![3, 13 << 8 | 0x13]));
    // Pattern 5 runs on pattern 0's pins: two ST inputs at once are refused.
    assert_eq!(rig.write(63, G_PIO_PATTERN, &[5]), Ok(()));
    assert_eq!(rig.read(63, G_PIO_PATTERN, 1), Ok(vec![5]));
    run(&mut rig, base, 50);
    let two = base | PioInputs::PC1 | PioInputs::PC4;
    run(&mut rig, two, 30);
    assert_eq!(rig.read(1, CMST, 2), Ok(vec![3, 13 << 8 | 0b101]));
    assert!(rig.node.outputs().alarm(), "*ALM OFF until RES");
    assert!(
        !rig.commands_to(0, 0)
            .iter()
            .any(|c| matches!(c, Command::MoveToPoint(_))),
        "nothing moved"
    );
}

/// PIOPAT changed while a move the PIO started runs (level mode, its ST input held): the axis
/// is stopped, since the input's release would no longer stop it.
#[test]
fn a_pattern_change_stops_a_move_the_pio_holds() {
    let mut rig = Rig::ready(1, |c| {
        c.settings.pio_axis = Some(axis(0));
        c.settings.watchdog = WatchdogTime::OFF;
        c.settings.pio_pattern = Pattern::Solenoid7;
    });
    rig.bus.fake(0).homed = true;
    let run = |rig: &mut Rig, inputs: PioInputs, ms: u64| {
        for _ in 0..ms {
            rig.node.sample_inputs(Instant(rig.now), inputs);
            rig.run_for(MS);
        }
    };
    let base = PioInputs::STP_N | PioInputs::SON;
    run(&mut rig, base, 300);
    let st2 = base | PioInputs::PC4;
    run(&mut rig, st2, 20);
    assert!(rig
        .commands_to(0, 0)
        .contains(&Command::MoveToPoint(point(2))));
    assert!(!rig.commands_to(0, 0).contains(&Command::CancelMotion));
    // Mid-move (a move takes 80 ms here): another pattern.
    assert_eq!(rig.write(63, G_PIO_PATTERN, &[5]), Ok(()));
    run(&mut rig, st2, 5);
    assert!(rig.commands_to(0, 0).contains(&Command::CancelMotion));
}
