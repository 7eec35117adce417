//! The order of the writes: the gateway admits each write by its own rules (`plc::admit`) on
//! the settings the writes before it left, so UNITID, AXISBASE and the axes enabled are
//! written in an order it takes, or in two phases with an APPLY between.

use protocol::axes::AxisSet;
use protocol::plc::write::{AxisSetting, GatewayWrite};
use protocol::plc::{admit, AxisBase, Conflict, Pending, UnitId};

use super::{Change, Section, Settings};

/// The settings a sequence of writes meets, as the gateway keeps them: every register of a
/// change parsed and admitted by the gateway's own rules (`plc::admit`) on the settings the
/// writes before it left; APPLY puts the enabled axes on the bus.
#[derive(Clone, Copy, Debug)]
struct Admit(Pending);

impl Admit {
    /// The gateway as read: the enabled axes on the bus (nothing pending).
    fn of(now: &Settings) -> Admit {
        let word = |key| {
            now.word(Section::Gateway, key)
                .and_then(|w| u8::try_from(w).ok())
        };
        let enabled = AxisSet(now.enabled().iter().fold(0u16, |m, &n| m | 1 << n));
        Admit(Pending {
            unit: word("unit_id").and_then(UnitId::new).unwrap_or_default(),
            axis_base: word("axis_base")
                .and_then(AxisBase::new)
                .unwrap_or_default(),
            enabled,
            bus: enabled,
        })
    }

    /// One change written: refused with the reason, as the gateway would.
    fn write(&mut self, c: &Change) -> Result<(), String> {
        for (i, &value) in c.regs.iter().enumerate() {
            let address = c.address + i as u16;
            let write = GatewayWrite::parse(address, value).map_err(|e| {
                format!(
                    "{} {} = {}: register {address:#06x} refused ({e:?})",
                    c.section.name(),
                    c.key,
                    c.to
                )
            })?;
            admit(&self.0, write).map_err(|conflict| self.why(write, conflict))?;
            match write {
                GatewayWrite::UnitId(unit) => self.0.unit = unit,
                GatewayWrite::AxisBase(base) => self.0.axis_base = base,
                GatewayWrite::Axis(axis, AxisSetting::Enabled(on)) => {
                    self.0.enabled = if on {
                        self.0.enabled.with(axis)
                    } else {
                        self.0.enabled.without(axis)
                    };
                }
                _ => {}
            }
        }
        Ok(())
    }

    /// Why the gateway refuses `write`, in words.
    fn why(&self, write: GatewayWrite, conflict: Conflict) -> String {
        let Admit(Pending {
            unit, axis_base, ..
        }) = *self;
        match (write, conflict) {
            (GatewayWrite::UnitId(value), Conflict::AxisUnit(axis)) => format!(
                "UNITID {value} while axis {n} (enabled or on the bus until APPLY) is unit {value} (AXISBASE {axis_base} + {n})",
                n = axis.get()
            ),
            (GatewayWrite::AxisBase(value), Conflict::AxisUnit(axis)) => format!(
                "AXISBASE {value} while UNITID is {unit}: axis {n} (enabled or on the bus until APPLY) would be unit {unit}",
                n = axis.get()
            ),
            (GatewayWrite::Axis(..), Conflict::AxisUnit(axis)) => format!(
                "axis {n} enabled while it would be unit {unit} (AXISBASE {axis_base} + {n}), the gateway's UNITID",
                n = axis.get()
            ),
            (write, conflict) => format!("{write:?} refused: {conflict:?}"),
        }
    }

    fn apply(&mut self) {
        self.0.bus = self.0.enabled;
    }
}

/// The changes in phases the gateway admits one write after the other, an APPLY after each
/// phase but the last (which is followed by one only if a change of it is taken on APPLY).
/// Axes disabled come first; UNITID, AXISBASE and the axes enabled in the order that does
/// not collide (UNITID first when the new base would cover the current unit); when every
/// order collides, two phases with an APPLY between. `Err`: no order works (nothing to be
/// written), with the gateway's reason.
pub fn plan(now: &Settings, changes: &[Change]) -> Result<Vec<Vec<Change>>, String> {
    let is = |c: &Change, section: Section, key: &str| c.section == section && c.key == key;
    let disables: Vec<Change> = changes
        .iter()
        .filter(|c| matches!(c.section, Section::Axis(_)) && c.key == "enabled" && c.regs == [0])
        .cloned()
        .collect();
    let enables: Vec<Change> = changes
        .iter()
        .filter(|c| matches!(c.section, Section::Axis(_)) && c.key == "enabled" && c.regs != [0])
        .cloned()
        .collect();
    let unit: Vec<Change> = changes
        .iter()
        .filter(|c| is(c, Section::Gateway, "unit_id"))
        .cloned()
        .collect();
    let base: Vec<Change> = changes
        .iter()
        .filter(|c| is(c, Section::Gateway, "axis_base"))
        .cloned()
        .collect();
    let rest: Vec<Change> = changes
        .iter()
        .filter(|c| {
            c.key != "enabled"
                && !is(c, Section::Gateway, "unit_id")
                && !is(c, Section::Gateway, "axis_base")
        })
        .cloned()
        .collect();
    let groups: Vec<&Vec<Change>> = [&unit, &base, &enables]
        .into_iter()
        .filter(|g| !g.is_empty())
        .collect();
    let orders: Vec<Vec<usize>> = match groups.len() {
        0 => vec![vec![]],
        1 => vec![vec![0]],
        2 => vec![vec![0, 1], vec![1, 0]],
        _ => vec![
            vec![0, 1, 2],
            vec![0, 2, 1],
            vec![1, 0, 2],
            vec![1, 2, 0],
            vec![2, 0, 1],
            vec![2, 1, 0],
        ],
    };
    let run = |state: &mut Admit, phase: &[Change]| -> Result<(), String> {
        phase.iter().try_for_each(|c| state.write(c))
    };
    let mut first_reason = None;
    // One phase if any order admits it, else two (the split after `k` groups, an APPLY there).
    for two in [false, true] {
        for order in &orders {
            let splits: Vec<usize> = if two {
                (0..groups.len()).collect()
            } else {
                vec![groups.len()]
            };
            for k in splits {
                let mut phase1 = disables.clone();
                let mut phase2 = Vec::new();
                for (i, &g) in order.iter().enumerate() {
                    let target = if i < k { &mut phase1 } else { &mut phase2 };
                    target.extend(
                        groups
                            .get(g)
                            .map_or(&[][..], |g| g.as_slice())
                            .iter()
                            .cloned(),
                    );
                }
                if two && phase1.is_empty() {
                    continue;
                }
                let mut state = Admit::of(now);
                let outcome = run(&mut state, &phase1).and_then(|()| {
                    if two {
                        state.apply();
                    }
                    run(&mut state, &phase2)
                });
                match outcome {
                    Ok(()) => {
                        return Ok(if two {
                            phase2.extend(rest.iter().cloned());
                            vec![phase1, phase2]
                        } else {
                            phase1.extend(phase2);
                            phase1.extend(rest.iter().cloned());
                            vec![phase1]
                        });
                    }
                    Err(e) => {
                        first_reason.get_or_insert(e);
                    }
                }
            }
        }
    }
    Err(format!(
        "the gateway would refuse these settings in every order of writing them (with an APPLY between or not): {}; change UNITID, AXISBASE and the axes enabled in separate steps",
        first_reason.unwrap_or_default()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    use protocol::axes::AXES;
    use protocol::modbus::{DataModel, RegisterTable, SlaveCounters};
    use protocol::plc::map::*;
    use protocol::plc::{Gateway, GatewayConfig};
    use protocol::time::Instant;

    /// A gateway started with these settings running: `unit`, `base`, `axes` on the bus.
    fn gateway(unit: u8, base: u8, axes: AxisSet) -> Gateway {
        let mut config = GatewayConfig::new(axes);
        config.settings.unit = UnitId::new(unit).unwrap();
        config.settings.axis_base = AxisBase::new(base).unwrap();
        Gateway::new(
            config,
            &protocol::plc::IDENTITY,
            protocol::plc::Boot::DEFAULT,
        )
    }

    /// What rcgw starts a plan from: the same settings, read.
    fn settings(unit: u8, base: u8, axes: AxisSet) -> Settings {
        let mut values = BTreeMap::new();
        values.insert((Section::Gateway, "unit_id"), vec![u16::from(unit)]);
        values.insert((Section::Gateway, "axis_base"), vec![u16::from(base)]);
        for n in 0..AXES as u8 {
            let on = axes.0 & 1 << n != 0;
            values.insert((Section::Axis(n), "enabled"), vec![u16::from(on)]);
        }
        Settings { values }
    }

    fn change(section: Section, key: &'static str, address: u16, value: u16) -> Change {
        Change {
            section,
            key,
            address,
            from: None,
            to: value.to_string(),
            regs: vec![value],
            on_apply: true,
        }
    }

    /// rcgw plans its writes with the rules the gateway applies to them: random sequences of
    /// UNITID, AXISBASE and axes enabled or disabled (small units and bases, so that they
    /// collide often), with APPLYs between, are written to a gateway and fed to rcgw's model
    /// of it, and each write must be admitted by both or refused by both. (The gateway's APPLY
    /// is a start with the pending settings: the rules APPLY itself has, an idle bus, are not
    /// these.) Fails if rcgw's model of what is pending and what is on the bus, or its rules,
    /// drift from the gateway's.
    #[test]
    fn rcgw_and_the_gateway_admit_the_same_writes() {
        let mut seed = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = |n: u64| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed % n
        };
        let (mut admitted, mut refused) = (0, 0);
        for _ in 0..400 {
            let (mut unit, mut base) = (63u8, 1u8);
            let mut axes = AxisSet(next(1 << 16) as u16 & 0x00FF);
            let mut gw = gateway(unit, base, axes);
            let mut model = Admit::of(&settings(unit, base, axes));
            for _ in 0..12 {
                let c = match next(4) {
                    0 => {
                        // APPLY: the pending settings run, in the gateway as in rcgw.
                        let mut regs = gw.registers(Instant::ZERO, SlaveCounters::default());
                        let mut pending = |a: u16| {
                            let mut out = [0];
                            regs.read_registers(unit, RegisterTable::Holding, a, &mut out)
                                .expect("read");
                            out[0]
                        };
                        let (u, b) = (pending(G_UNIT_ID) as u8, pending(G_AXIS_BASE) as u8);
                        let on = (0..AXES as u16).fold(0, |m, n| {
                            m | pending(G_AXIS_CONFIG + G_AXIS_CONFIG_LEN * n) << n
                        });
                        (unit, base, axes) = (u, b, AxisSet(on));
                        gw = gateway(unit, base, axes);
                        model.apply();
                        continue;
                    }
                    1 => {
                        let u = [1 + next(24), 63][next(2) as usize] as u16;
                        change(Section::Gateway, "unit_id", G_UNIT_ID, u)
                    }
                    2 => change(
                        Section::Gateway,
                        "axis_base",
                        G_AXIS_BASE,
                        1 + next(24) as u16,
                    ),
                    _ => {
                        let n = next(16) as u8;
                        let address = G_AXIS_CONFIG + G_AXIS_CONFIG_LEN * u16::from(n);
                        change(Section::Axis(n), "enabled", address, next(2) as u16)
                    }
                };
                let gateway = gw
                    .registers(Instant::ZERO, SlaveCounters::default())
                    .write_registers(unit, c.address, &c.regs);
                let rcgw = model.write(&c);
                assert_eq!(
                    rcgw.is_ok(),
                    gateway.is_ok(),
                    "{}: rcgw {rcgw:?}, the gateway {gateway:?} (running: unit {unit}, \
                     AXISBASE {base}, axes {:#06x})",
                    c.line(),
                    axes.0
                );
                if gateway.is_ok() {
                    admitted += 1;
                } else {
                    refused += 1;
                }
            }
        }
        // Both outcomes exercised.
        assert!(admitted > 100 && refused > 100, "{admitted} {refused}");
    }
}
