//! The PLC side against simulated controllers, in virtual time: the register map, command
//! edges and their status, validation (exceptions, and nothing reaches the bus), the fail-safe,
//! the synchronized start, the command channel, the position table and the gateway's settings.
//! Requests are Modbus RTU frames to the calls the Modbus slave makes. One file per subject.
#![allow(clippy::inconsistent_digit_grouping)]

mod axis_map;
mod command_channel;
mod commands;
mod direct_move;
mod gateway_settings;
mod held_son;
mod position_table;
mod stops;
mod sync_start;

use protocol::line::Baud;
use protocol::modbus::Exception;
use protocol::plc::map::*;
use protocol::plc::{AxisConfig, CommandState, GatewayConfig};
use protocol::units::{Lead, Length};
use protocol::{Axis, PositionNo, Rtim};
use protocol::{AxisMap, AxisSet};
use rc_host::node_harness::NodeHarness;
use rc_tools::sim::realtime::bus_at_line;
use rc_tools::sim::{BusConfig, ControllerConfig};

const MS: u64 = 1000;
const S: u64 = 1_000_000;

fn axis(n: u8) -> Axis {
    Axis::new(n).unwrap()
}

/// Axes 0..n at 115.2 kbit/s / RTIM 3 (no establishment), lead 8 mm like the simulator's
/// actuator, 100 mm stroke; point 3 of every axis stored at 40 mm.
fn gateway(n: u8) -> NodeHarness {
    gateway_with(n, 100_00, None, &[])
}

/// [`gateway`] with another stroke, another stored point 3 (wire values), and silent axes.
fn gateway_with(n: u8, stroke: i32, row3: Option<[u32; 10]>, silent: &[u8]) -> NodeHarness {
    let axes: Vec<Axis> = (0..n).map(axis).collect();
    let mut bus = bus_at_line(BusConfig::default(), &axes, Baud::B115200, Rtim::MIN);
    let mut config = GatewayConfig::new(AxisSet::first(n));
    config.bus.establish = false;
    config.settings.axes = AxisMap::new(AxisConfig {
        scale: scale(),
        stroke: Length(stroke),
    });
    let mut row = [0u32; 10];
    row[0] = scale().position_to_wire(Length(40_00)).unwrap().to_wire();
    for &a in &axes {
        let mut controller = ControllerConfig {
            stored_line: Some((Baud::B115200, Rtim::MIN)),
            ..ControllerConfig::default()
        };
        controller.points = vec![(PositionNo::new(3).unwrap(), row3.unwrap_or(row))];
        bus.add_controller(a, controller);
    }
    for &a in silent {
        bus.set_silent(axis(a), true);
    }
    let mut h = NodeHarness::new(config, bus);
    h.run_until(300 * MS);
    h
}

/// The simulator's actuator (8 mm lead) with the gateway's default conventions.
fn scale() -> protocol::units::Scale {
    protocol::units::Scale {
        lead: Lead::from_hundredths(800).unwrap(),
        ..AxisConfig::default().scale
    }
}

fn unit(a: u8) -> u8 {
    a + 1
}

fn write(h: &mut NodeHarness, unit: u8, address: u16, values: &[u16]) -> Result<(), Exception> {
    h.write(unit, address, values)
}

fn read(h: &mut NodeHarness, unit: u8, address: u16, n: usize) -> Result<Vec<u16>, Exception> {
    h.read(unit, address, n as u16)
}

fn coil(h: &mut NodeHarness, unit: u8, address: u16, on: bool) -> Result<(), Exception> {
    h.write_coil(unit, address, on)
}

/// Keep "polling" like a PLC (so the watchdog stays quiet) until the command of `a` settles.
fn settle(h: &mut NodeHarness, a: u8, timeout: u64) -> (CommandState, u16) {
    let until = h.now + timeout;
    while h.now < until {
        h.run_until(h.now + 50 * MS);
        let _ = read(h, unit(a), CMST, 1);
        let state = h.node.gateway().command_state(axis(a));
        if matches!(state.0, CommandState::Done | CommandState::Failed) {
            return state;
        }
    }
    panic!(
        "axis {a}: command did not settle: {:?}",
        h.node.gateway().command_state(axis(a))
    );
}

fn pnow_mm100(h: &mut NodeHarness, a: u8) -> i32 {
    let r = read(h, unit(a), PNOW, 2).unwrap();
    ((u32::from(r[0]) << 16) | u32::from(r[1])) as i32
}

fn home(h: &mut NodeHarness, a: u8) {
    write(h, unit(a), DRG1, &[DRG1_SON]).unwrap();
    settle(h, a, S);
    write(h, unit(a), DRG1, &[DRG1_SON | DRG1_HOME]).unwrap();
    assert_eq!(settle(h, a, 10 * S), (CommandState::Done, 0));
    write(h, unit(a), DRG1, &[DRG1_SON]).unwrap();
}

/// One command-channel exchange (ROBONET's five steps): write the request, wait for the
/// response, clear the request, and check that the gateway cleared the response.
fn exchange(h: &mut NodeHarness, request: [u16; 6]) -> Vec<u16> {
    write(h, 63, G_REQUEST, &request).unwrap();
    let until = h.now + 5 * S;
    let mut response = vec![0; 5];
    while h.now < until {
        h.run_until(h.now + 20 * MS);
        response = read(h, 63, G_RESPONSE, 5).unwrap();
        if response[0] != 0 {
            break;
        }
    }
    write(h, 63, G_REQUEST, &[0]).unwrap();
    assert_eq!(
        read(h, 63, G_RESPONSE, 1).unwrap(),
        [0],
        "step 5: response cleared"
    );
    response
}
