//! Settings that survive a power cycle: the stored record (round trip, and a damaged or
//! incompatible one refused whole), and the PLC's side of it (pending settings, SAVE, APPLY,
//! factory reset, restart, what a start reports).
#![allow(clippy::inconsistent_digit_grouping)]

mod support;

use proptest::prelude::*;
use protocol::modbus::Exception;
use protocol::pio::{Pattern, Ports, StartMode};
use protocol::plc::map::*;
use protocol::plc::settings::{
    Settings, SettingsError, FORMAT_1, FORMAT_2, RECORD_LEN, RECORD_LEN_1, RECORD_LEN_2,
};
use protocol::plc::{
    AxisBase, Boot, ConfigSource, GatewayConfig, InchStep, JogSpeed, Parity, PlcBaud, ResetCause,
    SettingsRequest, UnitId,
};
use protocol::units::Lead;
use protocol::AxisSet;
use support::*;

fn config() -> GatewayConfig {
    let mut c = GatewayConfig::new(AxisSet::first(3));
    c.settings.axes[axis(2)].scale.lead = Lead::from_hundredths(1200).unwrap();
    c.settings.axes[axis(2)].stroke = protocol::units::Length(350_00);
    c.settings.pio_axis = Some(axis(1));
    c.settings.pio_pattern = Pattern::Solenoid3;
    c.settings.pio_start = StartMode::Edge;
    c.settings.pio_jog = JogSpeed::from_hundredths(25_00).unwrap();
    c.settings.pio_inch = InchStep::from_hundredths(5).unwrap();
    c.settings.axis_base = AxisBase::new(17).unwrap();
    c.settings.unit = UnitId::new(63).unwrap();
    c.settings.net.ip = protocol::net::Ipv4([10, 1, 2, 3]);
    c.settings.net.prefix = 16;
    c.settings.net.router = protocol::net::Ipv4([10, 1, 0, 1]);
    c.settings.net.policy.allow[2] = protocol::net::Ipv4([10, 1, 2, 9]);
    c.settings.net.policy.max_connections = 2;
    c.settings.net.policy.idle_s = 600;
    c
}

/// A record of format 2 (before the unit base and the network) is read: axis 0 is unit 1, the
/// network's defaults, everything else as stored.
#[test]
fn a_format_2_record_is_read() {
    let mut old = config();
    old.settings.axis_base = AxisBase::DEFAULT;
    old.settings.net = protocol::net::NetConfig::DEFAULT;
    let record = Settings::of(&old).encode();
    let mut v2 = record[..RECORD_LEN_2].to_vec();
    v2[0] = FORMAT_2;
    let sum = protocol::modbus::crc::checksum(&v2[..RECORD_LEN_2 - 2]);
    v2[RECORD_LEN_2 - 2..].copy_from_slice(&sum.to_le_bytes());
    assert_eq!(Settings::decode(&v2), Ok(Settings::of(&old)));
    let mut long = record;
    long[0] = FORMAT_2;
    assert_eq!(Settings::decode(&long), Err(SettingsError::Length));
}

/// A record of format 1 (before the PIO patterns), as the firmware before them stored it, is
/// read: pattern 0, level mode, everything else as stored.
#[test]
fn a_format_1_record_is_read() {
    let mut old = config();
    old.settings.axis_base = AxisBase::DEFAULT;
    old.settings.net = protocol::net::NetConfig::DEFAULT;
    old.settings.pio_pattern = Pattern::Positioning;
    old.settings.pio_start = StartMode::Level;
    old.settings.pio_jog = JogSpeed::from_hundredths(protocol::plc::DEFAULT_PIO_JOG).unwrap();
    old.settings.pio_inch = InchStep::from_hundredths(protocol::plc::DEFAULT_PIO_INCH).unwrap();
    let record = Settings::of(&old).encode();
    let mut v1 = record[..RECORD_LEN_1].to_vec();
    v1[0] = FORMAT_1;
    let sum = protocol::modbus::crc::checksum(&v1[..RECORD_LEN_1 - 2]);
    v1[RECORD_LEN_1 - 2..].copy_from_slice(&sum.to_le_bytes());
    assert_eq!(Settings::decode(&v1), Ok(Settings::of(&old)));
    // Its length and its version go together.
    assert_eq!(
        Settings::decode(&v1[..RECORD_LEN_1 - 1]),
        Err(SettingsError::Length)
    );
    let mut long = record;
    long[0] = FORMAT_1;
    assert_eq!(Settings::decode(&long), Err(SettingsError::Length));
}

/// A pattern the board lacks ports for is not applied from a record (settings carried over
/// from another board): the gateway keeps pattern 0.
#[test]
fn a_pattern_the_board_cannot_run_is_not_applied() {
    let mut seven = config();
    seven.settings.pio_pattern = Pattern::Solenoid7;
    let settings = Settings::of(&seven);
    let mut small = GatewayConfig::new(AxisSet::EMPTY);
    small.pio_ports = Ports {
        inputs: Pattern::Positioning.inputs(),
        outputs: Pattern::Positioning.outputs(),
    };
    settings.apply_to(&mut small);
    assert_eq!(small.settings.pio_pattern, Pattern::Positioning);
    assert_eq!(small.settings.pio_axis, Some(axis(1)));
    // Pattern 5 needs no port pattern 0 lacks.
    Settings::of(&config()).apply_to(&mut small);
    assert_eq!(small.settings.pio_pattern, Pattern::Solenoid3);
}

#[test]
fn a_record_round_trips() {
    let settings = Settings::of(&config());
    let record = settings.encode();
    assert_eq!(Settings::decode(&record), Ok(settings));
    let applied = settings.apply(GatewayConfig::new(AxisSet::EMPTY));
    let mut in_place = GatewayConfig::new(AxisSet::EMPTY);
    settings.apply_to(&mut in_place);
    assert_eq!(in_place, applied);
    assert_eq!(Settings::of(&applied), settings);
    assert_eq!(applied.settings.axes[axis(2)].scale.lead.hundredths(), 1200);
}

#[test]
fn a_damaged_record_is_refused_whole() {
    let record = Settings::of(&config()).encode();
    // Every single-bit flip is caught (the CRC, or the version byte).
    for i in 0..RECORD_LEN {
        for bit in 0..8 {
            let mut bad = record;
            bad[i] ^= 1 << bit;
            assert!(Settings::decode(&bad).is_err(), "byte {i} bit {bit}");
        }
    }
    assert_eq!(
        Settings::decode(&record[..RECORD_LEN - 1]),
        Err(SettingsError::Length)
    );
    let mut other = record;
    other[0] = 4;
    assert_eq!(Settings::decode(&other), Err(SettingsError::Version));
    assert_eq!(
        Settings::decode(&[0xFF; RECORD_LEN]),
        Err(SettingsError::Version)
    );
}

/// A record with a valid CRC but a field out of range (written by a buggy or newer firmware)
/// is refused too, naming the field.
#[test]
fn a_field_out_of_range_is_refused() {
    let record = Settings::of(&config()).encode();
    let with = |at: usize, bytes: &[u8]| {
        let mut r = record;
        r[at..at + bytes.len()].copy_from_slice(bytes);
        let sum = protocol::modbus::crc::checksum(&r[..RECORD_LEN - 2]);
        r[RECORD_LEN - 2..].copy_from_slice(&sum.to_le_bytes());
        Settings::decode(&r)
    };
    let cases: [(usize, &[u8]); 22] = [
        (1, &[0]),                        // unit 0
        (1, &[248]),                      // unit past 247
        (1, &[18]),                       // unit 18 = axis 1's (base 17), which is on the bus
        (2, &1234u32.to_le_bytes()),      // PLC rate
        (6, &[3]),                        // parity
        (7, &10u16.to_le_bytes()),        // watchdog below 50 ms
        (9, &[2]),                        // watchdog action
        (10, &[0x15]),                    // BRSL
        (11, &[2]),                       // RTIM below 3
        (12, &[4]),                       // resends
        (16, &0u16.to_le_bytes()),        // axis 0 lead 0
        (16 + 4, &[9]),                   // axis 0 home end
        (16 + 6, &(-1i32).to_le_bytes()), // axis 0 stroke below 0
        (176, &[2]),                      // PIO pattern 2 (256 points: not the gateway's)
        (177, &[2]),                      // PIO start mode
        (178, &[0, 0]),                   // jog speed 0
        (180, &[101, 0]),                 // inching step past 1.00 mm
        (182, &[0]),                      // axis base 0
        (182, &[233]),                    // axis base: axis 15 past unit 247
        (187, &[33]),                     // prefix past 32
        (192, &[5]),                      // more than 4 connections
        (193, &3601u16.to_le_bytes()),    // idle past an hour
    ];
    for (at, bytes) in cases {
        assert_eq!(
            with(at, bytes),
            Err(SettingsError::Field(at as u8)),
            "byte {at} = {bytes:?}"
        );
    }
}

fn settings() -> impl Strategy<Value = Settings> {
    (
        any::<u16>(),
        0u8..=3,
        prop_oneof![Just(0u16), 50u16..=60_000],
        3u8..=255,
        proptest::sample::select(vec![1_200u32, 9_600, 19_200, 115_200]),
        any::<[(u16, u16, bool, bool, u16); 16]>(),
    )
        .prop_map(|(axes, retries, wd, rtim, plc_baud, per_axis)| {
            let mut c = GatewayConfig::new(AxisSet(axes & 0x7FFF));
            c.settings.unit = UnitId::new(63).unwrap();
            c.bus.retries = retries;
            c.settings.watchdog = protocol::plc::WatchdogTime::from_millis(wd).unwrap();
            c.bus.rtim = protocol::Rtim::new(rtim).unwrap();
            c.settings.plc.baud = PlcBaud::new(plc_baud).unwrap();
            c.settings.plc.parity = Parity::Even;
            for (axis, (lead, ppr, home, twos, stroke)) in protocol::Axis::all().zip(per_axis) {
                let a = &mut c.settings.axes[axis];
                a.scale.lead = Lead::from_hundredths(lead.max(1)).unwrap();
                a.scale.pulses_per_rev = std::num::NonZeroU16::new(ppr.max(1)).unwrap();
                a.scale.home = if home {
                    protocol::HomeDirection::MotorEnd
                } else {
                    protocol::HomeDirection::NonMotorEnd
                };
                a.scale.complement = if twos {
                    protocol::units::Complement::Twos
                } else {
                    protocol::units::Complement::Ones
                };
                a.stroke = protocol::units::Length(i32::from(stroke));
            }
            Settings::of(&c)
        })
}

proptest! {
    #[test]
    fn any_settings_round_trip(s in settings()) {
        prop_assert_eq!(Settings::decode(&s.encode()), Ok(s));
    }

    #[test]
    fn decoding_any_bytes_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
        let _ = Settings::decode(&bytes);
    }
}

// ---------------------------------------------------------------- the PLC's side

#[test]
fn save_stores_the_settings_with_the_pending_ones() {
    let mut rig = Rig::ready(2, |_| {});
    rig.write(63, G_PLC_BAUD, &[192]).unwrap();
    rig.write(63, G_PLC_PARITY, &[2]).unwrap();
    rig.write(63, G_UNIT_ID, &[100]).unwrap();
    rig.write(63, G_WATCHDOG, &[500]).unwrap();
    // Taken at once by the engine, and saved with the rest.
    rig.write(63, G_RETRIES, &[0]).unwrap();
    // Pending: read back as written, not in force (unit 63 still answers).
    assert_eq!(rig.read(63, G_PLC_BAUD, 3), Ok(vec![192, 2, 100]));
    assert_eq!(rig.read(63, G_SAVE_STATUS, 3), Ok(vec![0, 0, 0]));
    rig.write(63, G_SAVE, &[1]).unwrap();
    rig.run_for(10 * MS);
    let record = match (rig.stores.as_slice(), rig.saved.as_slice()) {
        ([(_, SettingsRequest::Save)], [record]) => *record,
        other => panic!("one save expected: {other:?}"),
    };
    let saved = Settings::decode(&record).unwrap();
    assert_eq!(
        (
            saved.gateway.plc.baud.bits_per_second(),
            saved.gateway.plc.parity,
            saved.gateway.unit.get()
        ),
        (19_200, Parity::Even, 100)
    );
    assert_eq!(
        saved.gateway.watchdog,
        protocol::plc::WatchdogTime::from_millis(500).unwrap()
    );
    assert_eq!(saved.retries, 0, "RETRIES, written at once, is saved");
    assert_eq!(saved.axes, AxisSet::first(2));
    // The rig's flash said "saved, 1 so far".
    assert_eq!(rig.read(63, G_SAVE_STATUS, 3), Ok(vec![2, 0, 1]));
    // Invalid values are refused and change nothing.
    for (address, value) in [
        (G_PLC_BAUD, 1000),
        (G_PLC_PARITY, 3),
        (G_UNIT_ID, 0),
        (G_UNIT_ID, 2), // axis 1's unit
        (G_UNIT_ID, 248),
        (G_SAVE, 2),
        (G_FACTORY, 1),
        (G_RESTART, 2),
    ] {
        assert_eq!(
            rig.write(63, address, &[value]),
            Err(Exception::IllegalDataValue),
            "{address:#06X} = {value}"
        );
    }
    assert_eq!(rig.stores.len(), 1, "nothing else asked of the flash");
}

/// Whatever the registers accept, a save stores and the next start loads: a stroke of 0 (only
/// direct moves to 0 allowed) is one the PLC can set, so a record with it must not be refused
/// as damaged (which would drop every setting for the defaults).
#[test]
fn a_saved_stroke_of_zero_loads() {
    let mut rig = Rig::ready(1, |_| {});
    // Axis 1's AXISCFG: stroke high and low words (offsets 4 and 5).
    rig.write(63, G_AXIS_CONFIG + 8 + 4, &[0, 0]).unwrap();
    rig.write(63, G_SAVE, &[1]).unwrap();
    rig.run_for(10 * MS);
    let record = match (rig.stores.as_slice(), rig.saved.as_slice()) {
        ([(_, SettingsRequest::Save)], [record]) => *record,
        other => panic!("one save expected: {other:?}"),
    };
    let saved = Settings::decode(&record).expect("the saved record loads");
    assert_eq!(
        saved.gateway.axes[axis(1)].stroke,
        protocol::units::Length(0)
    );
}

#[test]
fn apply_switches_the_plc_line_after_its_reply_and_the_unit_at_once() {
    let mut rig = Rig::ready(1, |_| {});
    rig.write(63, G_PLC_BAUD, &[384]).unwrap();
    rig.write(63, G_UNIT_ID, &[50]).unwrap();
    rig.write(63, G_APPLY, &[1]).unwrap();
    assert_eq!(rig.plc_lines.len(), 1);
    assert_eq!(rig.plc_lines[0].1.baud.bits_per_second(), 38_400);
    // Unit 63 is gone, 50 answers; the bus is being established again.
    assert_eq!(
        rig.modbus(
            63,
            &protocol::modbus::Request::ReadHoldingRegisters {
                address: G_VERSION,
                quantity: 1
            }
        ),
        None
    );
    assert!(rig.read(50, G_VERSION, 1).is_ok());
    rig.run_for(300 * MS);
    assert!(
        rig.lines
            .iter()
            .any(|(_, a)| *a == protocol::line::LineAction::BreakStart),
        "{:?}",
        rig.lines
    );
}

#[test]
fn factory_reset_and_restart_need_their_keys() {
    let mut rig = Rig::ready(1, |_| {});
    rig.write(63, G_RESTART, &[1]).unwrap();
    rig.run_for(MS);
    rig.write(63, G_FACTORY, &[FACTORY_KEY]).unwrap();
    rig.run_for(MS);
    let asked: Vec<SettingsRequest> = rig.stores.iter().map(|(_, s)| *s).collect();
    assert_eq!(
        asked,
        [SettingsRequest::Restart, SettingsRequest::FactoryReset]
    );
    // Writing 0 is harmless.
    rig.write(63, G_FACTORY, &[0]).unwrap();
    rig.write(63, G_RESTART, &[0]).unwrap();
    rig.run_for(MS);
    assert_eq!(rig.stores.len(), 2);
}

#[test]
fn a_start_reports_where_its_settings_came_from_and_why() {
    let rig = |boot: Boot| {
        let mut rig = Rig::ready_after(boot, 1, |_| {});
        rig.read(63, G_SAVE_COUNT, 6).unwrap()
    };
    let damaged = Boot {
        source: ConfigSource::Damaged,
        load_errors: 3,
        save_count: 70_000,
        reset: ResetCause::Watchdog,
    };
    // SAVECOUNT (2), FACTORY (reads 0), CFGSOURCE, CFGERRORS, RESETCAUSE
    assert_eq!(
        rig(damaged),
        vec![1, (70_000u32 - 65_536) as u16, 0, 2, 3, 1]
    );
    assert_eq!(rig(Boot::DEFAULT), vec![0, 0, 0, 0, 0, 0]);
}

#[test]
fn enabling_an_axis_takes_effect_on_apply() {
    // The scripted controllers answer at once whatever the rate and RTIM (they do not model
    // the establishment's 9.6 kbit/s and 255 ms): no earliest-answer bound.
    let mut rig = Rig::ready(2, |c| c.bus.wire_timing = false);
    let enabled = G_AXIS_CONFIG + 8 * 2;
    assert_eq!(rig.read(63, enabled, 1), Ok(vec![0]));
    rig.write(63, enabled, &[1]).unwrap();
    assert_eq!(rig.read(63, enabled, 1), Ok(vec![1]), "pending");
    let link = protocol::modbus::Request::ReadHoldingRegisters {
        address: LINK,
        quantity: 1,
    };
    assert_eq!(rig.modbus(3, &link), None, "unit 3 is not served yet");
    rig.bus.axes.insert(2, Fake::default());
    rig.write(63, G_APPLY, &[1]).unwrap();
    rig.run_for(3 * S);
    for unit in 1..=3 {
        assert_eq!(rig.read(unit, LINK, 1), Ok(vec![1]), "unit {unit}");
    }
}

/// The register map's word on when each setting is taken (its row's `on_apply`, which rcgw and
/// docs/plc.md read) is what the gateway does: a value other than the default written to the
/// gateway unit changes the settings in force at once, or only on APPLY.
#[test]
fn each_setting_is_taken_when_its_map_row_says() {
    let settings = MAP
        .iter()
        .filter(|e| e.unit == Unit::Gateway && e.table == Table::Holding && e.writable)
        .filter(|e| !e.allowed.is_empty());
    let mut checked = 0;
    for entry in settings {
        let default = entry.default.expect("a setting's row has a default");
        // Values the row allows other than the default, the spans' ends first.
        let candidates = entry
            .allowed
            .iter()
            .flat_map(|&(low, high)| [low, high, low.saturating_add(1)])
            .filter(|&v| v != default && entry.allows(v));
        let mut taken = None;
        for value in candidates {
            let mut rig = Rig::ready(2, |c| c.bus.wire_timing = false);
            let before = Settings::of(rig.node.gateway().config());
            if rig.write(63, entry.address, &[value]).is_err() {
                continue; // refused against the others (a unit id of an axis'...): the next
            }
            let written = Settings::of(rig.node.gateway().config());
            rig.write(63, G_APPLY, &[1]).unwrap();
            rig.run_for(S);
            let applied = Settings::of(rig.node.gateway().config());
            taken = Some((value, before != written, before != applied));
            break;
        }
        let (value, at_once, by_apply) =
            taken.unwrap_or_else(|| panic!("{}: no value but the default admitted", entry.name));
        assert!(
            by_apply,
            "{} = {value}: not in force after APPLY",
            entry.name
        );
        assert_eq!(
            at_once, !entry.on_apply,
            "{} = {value}: in force at once: {at_once}; the map says on APPLY: {}",
            entry.name, entry.on_apply
        );
        checked += 1;
    }
    assert!(checked >= 14, "only {checked} settings checked");
}

/// A configuration with more retries than the engine makes (it clamps them) stores what the
/// engine uses: a record holding more would be refused whole at the next start.
#[test]
fn more_retries_than_the_engine_makes_are_stored_as_its_most() {
    let mut c = config();
    c.bus.retries = 9;
    let record = Settings::of(&c).encode();
    let stored = Settings::decode(&record).expect("a readable record");
    assert_eq!(stored.retries, protocol::engine::MAX_RETRIES);
}
