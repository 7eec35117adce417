//! Scenario 7: stop latency through the whole gateway (the `Node`, as the firmware runs it), from
//! a stop's source to its `d` on the bus, with 16 axes polled at 115.2 kbit/s and four of them
//! moving back and forth.
//!
//! Each face in turn, many times, at seeded random moments of the bus schedule: the stop input,
//! the PIO's *STP (on a moving axis), DRG1 STP and the STOP coil (to one moving axis), and a
//! broadcast DRG1 STP (every axis). A sample is one axis' stop: from the source (the input's
//! edge, or the moment the whole Modbus request is at the gateway) to the moment its `d` starts
//! on the wire. Its bound is issue 33's target: the face's own delay (a Modbus frame ends only
//! after t3.5 of silence; a PIO input is debounced and sampled), plus the transaction on the wire
//! when the stop came, plus one transaction per `d` that went ahead of it (the other axes'
//! stops of the same source): `delay + (1 + ahead) x T`.
// Hundredths written as such (40_00 = 40.00 mm), as the register map reads them.
#![allow(clippy::inconsistent_digit_grouping)]

use protocol::engine::timing;
use protocol::line::Baud;
use protocol::modbus::rtu::t3_5;
use protocol::pio::PioInputs;
use protocol::plc::map::*;
use protocol::plc::{AxisConfig, GatewayConfig, PlcLine};
use protocol::time::Instant;
use protocol::units::{Lead, Length, Scale};
use protocol::{Axis, AxisMap, AxisSet, Command, Rtim};
use rc_host::node_harness::NodeHarness;
use rc_tools::sim::realtime::bus_at_line;
use rc_tools::sim::rng::Rng;
use rc_tools::sim::{BusConfig, ControllerConfig};

use crate::measure::{axis, Stats};
use crate::movers::MOVERS;
use crate::{AXES, MS, S};

/// The gateway unit.
const GATEWAY: u8 = 63;
/// The PIO's input sample period in the firmware and the harness.
const SAMPLE_US: u64 = 1_000;

/// Where a stop comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Face {
    StopInput,
    PioStp,
    Drg1Stp,
    StopCoil,
    Broadcast,
}

impl Face {
    pub(crate) const ALL: [Face; 5] = [
        Face::StopInput,
        Face::PioStp,
        Face::Drg1Stp,
        Face::StopCoil,
        Face::Broadcast,
    ];

    pub(crate) fn id(self) -> &'static str {
        match self {
            Face::StopInput => "stop_input",
            Face::PioStp => "pio_stp",
            Face::Drg1Stp => "drg1_stp",
            Face::StopCoil => "stop_coil",
            Face::Broadcast => "broadcast",
        }
    }
}

pub(crate) struct StopResult {
    pub(crate) face: Face,
    /// Source to `d` on the wire, µs, one sample per axis stopped.
    pub(crate) latency: Stats,
    /// The same over each sample's bound (`delay + (1 + ahead) x T`), in thousandths.
    pub(crate) ratio_milli: Stats,
    /// The most `d`s that went ahead of one axis' stop.
    pub(crate) max_ahead: usize,
}

/// The simulator's actuator (8 mm lead), 100 mm stroke.
fn axis_config() -> AxisConfig {
    AxisConfig {
        scale: Scale {
            lead: Lead::from_hundredths(800).unwrap_or(AxisConfig::DEFAULT.scale.lead),
            ..AxisConfig::DEFAULT.scale
        },
        stroke: Length(100_00),
    }
}

fn unit(a: u8) -> u8 {
    a + 1
}

fn write(h: &mut NodeHarness, unit: u8, address: u16, values: &[u16]) -> Result<(), String> {
    h.write(unit, address, values)
        .map_err(|e| format!("write {address:#06x} to unit {unit}: {e:?}"))
}

/// A gateway on 16 axes, its PIO on the first mover, the four movers homed.
fn gateway() -> Result<NodeHarness, String> {
    let axes: Vec<Axis> = (0..AXES).map(axis).collect::<Result<_, _>>()?;
    let mut bus = bus_at_line(BusConfig::default(), &axes, Baud::B115200, Rtim::MIN);
    for &a in &axes {
        bus.add_controller(
            a,
            ControllerConfig {
                stored_line: Some((Baud::B115200, Rtim::MIN)),
                ..ControllerConfig::default()
            },
        );
    }
    let mut config = GatewayConfig::new(AxisSet::first(AXES));
    config.bus.establish = false;
    config.settings.axes = AxisMap::new(axis_config());
    config.settings.watchdog = protocol::plc::WatchdogTime::OFF;
    config.settings.plc = PlcLine::DEFAULT;
    config.settings.pio_axis = Some(axis(MOVERS[0])?);
    let mut h = NodeHarness::new(config, bus);
    h.inputs = Some(PioInputs::from_bits(
        PioInputs::STP_N.bits() | PioInputs::SON.bits(),
    ));
    h.run_until(300 * MS);
    for a in MOVERS {
        write(&mut h, unit(a), DRG1, &[DRG1_SON])?;
    }
    h.run_for(100 * MS);
    for a in MOVERS {
        write(&mut h, unit(a), DRG1, &[DRG1_SON | DRG1_HOME])?;
        write(&mut h, unit(a), DRG1, &[DRG1_SON])?;
    }
    h.run_for(10 * S);
    Ok(h)
}

/// Every mover off to the other end (10 or 90 mm at 100 mm/s), after clearing any stop.
fn start_moves(h: &mut NodeHarness, far: bool) -> Result<(), String> {
    let target: u16 = if far { 90_00 } else { 10_00 };
    for a in MOVERS {
        write(h, unit(a), DRG1, &[DRG1_SON])?;
        write(h, unit(a), DIRECT, &[0, target, 0, 10, 0, 100_00, 30])?;
    }
    Ok(())
}

/// The axes `face` stops when applied to `mover`.
fn stopped_by(face: Face, mover: u8) -> Vec<u8> {
    match face {
        Face::StopInput | Face::Broadcast => (0..AXES).collect(),
        Face::PioStp => vec![MOVERS[0]],
        Face::Drg1Stp | Face::StopCoil => vec![mover],
    }
}

/// Apply the stop at `h.now`; its face's own delay (µs) before the gateway can know of it.
fn apply(h: &mut NodeHarness, face: Face, mover: u8) -> Result<u64, String> {
    let modbus = t3_5(PlcLine::DEFAULT.baud.bits_per_second()).0;
    Ok(match face {
        Face::StopInput => {
            h.node.set_stop_input(Instant(h.now), true);
            0
        }
        Face::PioStp => {
            h.inputs = Some(PioInputs::from_bits(PioInputs::SON.bits()));
            protocol::pio::Config::default().debounce.0 + SAMPLE_US
        }
        Face::Drg1Stp => {
            write(h, unit(mover), DRG1, &[DRG1_SON | DRG1_STP])?;
            modbus
        }
        Face::StopCoil => {
            h.write_coil(unit(mover), COIL_STOP, true)
                .map_err(|e| format!("STOP coil: {e:?}"))?;
            modbus
        }
        Face::Broadcast => {
            write(h, 0, DRG1, &[DRG1_SON | DRG1_STP])?;
            modbus
        }
    })
}

/// Undo `face` so that the movers may move again.
fn release(h: &mut NodeHarness, face: Face) -> Result<(), String> {
    match face {
        Face::StopInput => {
            h.node.set_stop_input(Instant(h.now), false);
            h.run_for(10 * MS);
            write(h, GATEWAY, G_FAILSAFE, &[0])?;
        }
        Face::PioStp => {
            h.inputs = Some(PioInputs::from_bits(
                PioInputs::STP_N.bits() | PioInputs::SON.bits(),
            ));
            h.run_for(20 * MS);
        }
        Face::Broadcast => {
            for a in 0..AXES {
                write(h, unit(a), DRG1, &[DRG1_SON])?;
            }
        }
        Face::Drg1Stp | Face::StopCoil => {}
    }
    Ok(())
}

/// `rounds` stops from `face` at random moments (seed `seed`).
pub(crate) fn stop_latency(face: Face, seed: u64, rounds: u32) -> Result<StopResult, String> {
    let mut h = gateway()?;
    let mut rng = Rng::derive(seed, face as u64);
    let t = timing::transaction_time(Baud::B115200, Rtim::MIN).0;
    let mut latencies = Vec::new();
    let mut ratios = Vec::new();
    let mut max_ahead = 0;
    for round in 0..rounds {
        start_moves(&mut h, round % 2 == 0)?;
        // Somewhere in the moves, at any point of a transaction.
        h.run_for(50 * MS + rng.below(300 * MS));
        let mover = MOVERS[rng.below(MOVERS.len() as u64) as usize];
        let from = h.sent.len();
        let at = h.now;
        let delay = apply(&mut h, face, mover)?;
        let targets = stopped_by(face, mover);
        h.run_for(S);
        let sent = h.sent.get(from..).unwrap_or_default();
        let mut ahead = 0;
        for &a in &targets {
            let first = sent
                .iter()
                .position(|(_, r)| r.axis.get() == a && r.command == Command::CancelMotion)
                .ok_or_else(|| format!("{face:?}: no stop to axis {a} within 1 s"))?;
            // The `d`s of the same source that went ahead of this one.
            let before = sent
                .get(..first)
                .unwrap_or_default()
                .iter()
                .filter(|(_, r)| r.command == Command::CancelMotion)
                .count();
            ahead = ahead.max(before);
            let latency = sent[first].0 - at;
            let bound = delay + (1 + before as u64) * t;
            latencies.push(latency);
            ratios.push(latency * 1000 / bound);
        }
        max_ahead = max_ahead.max(ahead);
        release(&mut h, face)?;
    }
    Ok(StopResult {
        face,
        latency: Stats::of(&latencies)?,
        ratio_milli: Stats::of(&ratios)?,
        max_ahead,
    })
}
