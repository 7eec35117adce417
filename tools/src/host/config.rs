//! The gateway's configuration and the simulated controllers for a set of [`Options`].

use std::io;

use protocol::plc::{AxisConfig, GatewayConfig, PlcBaud, UnitId, WatchdogTime, PLC_BAUDS};
use protocol::units::{Lead, Length, Scale};
use protocol::AxisSet;
use protocol::{Axis, PositionNo, Rtim};

use super::{BusLine, Options};
use crate::sim::memory::{Actuator, PointRow, POINT_LEN};
use crate::sim::{Bus, BusConfig, ControllerConfig};

pub(super) fn invalid(text: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, text)
}

/// The gateway's configuration for `options`.
pub fn gateway_config(options: &Options) -> io::Result<GatewayConfig> {
    let (axes, establish, echo) = match &options.bus {
        BusLine::Sim { axes, .. } => {
            if !(1..=16).contains(axes) {
                return Err(invalid(format!("{axes}: 1 to 16 simulated axes")));
            }
            (AxisSet::first(*axes), false, false)
        }
        BusLine::Device {
            axes,
            establish,
            echo,
            ..
        } => (*axes, *establish, *echo),
    };
    if axes.0 == 0 {
        return Err(invalid("no axis".into()));
    }
    let mut config = GatewayConfig::new(axes);
    let baud = PlcBaud::new(options.plc_baud).ok_or_else(|| {
        invalid(format!(
            "PLC line {} bit/s: the gateway takes {PLC_BAUDS:?}",
            options.plc_baud
        ))
    })?;
    config.settings.plc = protocol::plc::PlcLine {
        baud,
        parity: options.plc_parity,
    };
    if let Some(tcp) = &options.tcp {
        if tcp.allow.len() > config.settings.net.policy.allow.len() {
            return Err(invalid(format!(
                "{} clients to allow: at most {}",
                tcp.allow.len(),
                config.settings.net.policy.allow.len()
            )));
        }
        for (slot, &ip) in config.settings.net.policy.allow.iter_mut().zip(&tcp.allow) {
            *slot = ip;
        }
    }
    config.bus.baud = options.bus_baud;
    config.bus.rtim = Rtim::MIN;
    config.bus.establish = establish;
    config.bus.echo = echo;
    // Bytes are stamped when read: a pseudo-terminal or a USB adapter has no wire time.
    config.bus.wire_timing = false;
    let unit = UnitId::new(options.unit).filter(|_| config.axis_of_unit(options.unit).is_none());
    config.settings.unit = unit.ok_or_else(|| {
        invalid(format!(
            "unit {}: 1-247 and not an axis unit (axis n is unit n + 1)",
            options.unit
        ))
    })?;
    let watchdog = WatchdogTime::from_millis(options.watchdog_ms).ok_or_else(|| {
        invalid(format!(
            "watchdog {} ms: 0 (off) or 50-60000",
            options.watchdog_ms
        ))
    })?;
    config.settings.watchdog = watchdog;
    if options.stroke.0 <= 0 {
        return Err(invalid("the stroke must be positive".into()));
    }
    let scale = gateway_scale(options.lead, options.home);
    config.settings.axes = protocol::AxisMap::new(AxisConfig {
        scale,
        stroke: options.stroke,
    });
    Ok(config)
}

/// The gateway's default conventions with this lead and home end.
fn gateway_scale(lead: Lead, home: protocol::HomeDirection) -> Scale {
    Scale {
        lead,
        home,
        ..AxisConfig::default().scale
    }
}

/// Simulated controllers for `options` (which must be [`BusLine::Sim`]): each at the line rate
/// and RTIM 3 ms, with the lead, stroke and home end given.
pub fn simulated_bus(options: &Options, axes: u8, points: bool) -> io::Result<Bus> {
    let lead = options.lead;
    let lead_type = (0..16u32)
        .find(|&t| Lead::from_lead_type(t) == Some(lead))
        .ok_or_else(|| {
            invalid(format!(
                "lead {}.{:02} mm: the simulator knows the REG1 lead types 2.5, 3, 4, 5, 6, 8, \
                 10, 12, 16 and 20 mm",
                lead.hundredths() / 100,
                lead.hundredths() % 100
            ))
        })?;
    let scale = gateway_scale(lead, options.home);
    let stroke = u32::try_from(scale.pulses(options.stroke))
        .map_err(|_| invalid("the stroke is out of range".into()))?;
    let mut rows: Vec<(PositionNo, PointRow)> = Vec::new();
    if points {
        for (point, position) in [(1u8, 2_000), (3, 4_000)] {
            if position > options.stroke.0 {
                continue;
            }
            let (Some(point), Ok(pcmd)) = (
                PositionNo::new(point),
                scale.position_to_wire(Length(position)),
            ) else {
                continue;
            };
            let mut row = [0u32; POINT_LEN];
            if let Some(slot) = row.first_mut() {
                *slot = pcmd.to_wire();
            }
            rows.push((point, row));
        }
    }
    let baud = options.bus_baud;
    let mut bus = Bus::new(BusConfig {
        host_baud: baud,
        ..BusConfig::default()
    });
    let defaults = ControllerConfig::default();
    for axis in (0..axes).filter_map(Axis::new) {
        bus.add_controller(
            axis,
            ControllerConfig {
                actuator: Actuator { stroke, lead_type },
                start_from_motor_end: defaults.start_from_motor_end.min(stroke / 5),
                home_direction: options.home,
                stored_line: Some((baud, Rtim::MIN)),
                points: rows.clone(),
                ..defaults.clone()
            },
        );
    }
    Ok(bus)
}
