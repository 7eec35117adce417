//! The settings' registers read and written: the write phases with their APPLYs, APPLY itself
//! (and the establishment it starts), SAVE.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use protocol::axes::AXES;
use protocol::modbus::Exception;
use protocol::plc::map::*;

use super::schema::{AXIS, GATEWAY, NETWORK};
use super::{Change, Section, Settings};
use crate::link::{Fail, Gw};

impl Settings {
    /// Every setting of the gateway; the network block if it answers (02 on builds without
    /// TCP).
    pub fn read(gw: &mut Gw) -> Result<Settings, Fail> {
        let unit = gw.unit;
        let mut values = BTreeMap::new();
        let block = gw.read(unit, 0, G_AXIS_BASE + 1)?;
        for field in GATEWAY {
            let at = usize::from(field.address);
            let regs = block
                .get(at..at + usize::from(field.kind.width()))
                .unwrap_or(&[]);
            values.insert((Section::Gateway, field.key), regs.to_vec());
        }
        let half = (AXES as u16 / 2) * G_AXIS_CONFIG_LEN;
        let mut axes = gw.read(unit, G_AXIS_CONFIG, half)?;
        axes.extend(gw.read(unit, G_AXIS_CONFIG + half, half)?);
        for n in 0..AXES as u8 {
            let section = Section::Axis(n);
            for field in AXIS {
                let at = usize::from(section.base() - G_AXIS_CONFIG + field.address);
                let regs = axes
                    .get(at..at + usize::from(field.kind.width()))
                    .unwrap_or(&[]);
                values.insert((section, field.key), regs.to_vec());
            }
        }
        match gw.try_read(unit, G_NET, G_NET_LEN)? {
            Ok(net) => {
                for field in NETWORK {
                    let at = usize::from(field.address - G_NET);
                    let regs = net
                        .get(at..at + usize::from(field.kind.width()))
                        .unwrap_or(&[]);
                    values.insert((Section::Network, field.key), regs.to_vec());
                }
            }
            Err(Exception::IllegalDataAddress) => {}
            Err(e) => return Err(Fail::Device(format!("{}: {e}", gw.at(unit, G_NET)))),
        }
        Ok(Settings { values })
    }

    /// The axes enabled (AXISCFG: pending until APPLY), read.
    pub fn read_enabled(gw: &mut Gw) -> Result<Vec<u8>, Fail> {
        let unit = gw.unit;
        let half = (AXES as u16 / 2) * G_AXIS_CONFIG_LEN;
        let mut all = gw.read(unit, G_AXIS_CONFIG, half)?;
        all.extend(gw.read(unit, G_AXIS_CONFIG + half, half)?);
        Ok((0..AXES as u8)
            .filter(|&n| all.get(usize::from(n) * usize::from(G_AXIS_CONFIG_LEN)) == Some(&1))
            .collect())
    }
}

/// The first enabled axis (bit n of `axes`) that moves or runs a command, or a synchronized
/// start that runs: APPLY is refused then (`bus_idle`), so nothing is written. `None`: idle.
pub fn busy(gw: &mut Gw, axes: &[u8]) -> Result<Option<String>, Fail> {
    if gw.get(G_SYNC_STATUS)? == 1 {
        return Ok(Some("a synchronized start runs (SYNCSTAT 1)".into()));
    }
    for &n in axes {
        let unit = gw.axis_unit(n);
        let Some(ext) = gw.probe(unit, CMST, 1)? else {
            continue;
        };
        if ext.first() == Some(&1) {
            return Ok(Some(format!(
                "axis {n} (unit {unit}) runs a command (CMST 1)"
            )));
        }
        if let Ok(dsse) = gw.try_read(unit, DSSE, 1)? {
            if dsse.first().is_some_and(|d| d & DSSE_MOVE != 0) {
                return Ok(Some(format!("axis {n} (unit {unit}) moves (DSSE MOVE)")));
            }
        }
    }
    Ok(None)
}

/// The changes written, for a message after a failure: those an APPLY already took, those
/// written since, and which of them wait for APPLY.
fn written_text(applied: &[Change], written: &[Change]) -> String {
    let mut out = String::new();
    if !applied.is_empty() {
        out += &format!("applied before the failure ({}):", applied.len());
        for c in applied {
            out += &format!("\n    {}", c.line());
        }
        out += "\n  ";
    }
    if written.is_empty() {
        out += "nothing written since the last APPLY";
        return out;
    }
    out += &format!("written before the failure ({}):", written.len());
    for c in written {
        out += &format!("\n    {}", c.line());
    }
    let pending: Vec<String> = written
        .iter()
        .filter(|c| c.on_apply)
        .map(|c| format!("{} {}", c.section.name(), c.key))
        .collect();
    if !pending.is_empty() {
        out += &format!(
            "\n  pending until APPLY (registers read them, the gateway does not run them yet): {}; `rcgw apply` once nothing moves, or write the file again",
            pending.join(", ")
        );
    }
    out
}

/// Write `phases` ([`plan`](fn@super::plan)), an APPLY after each phase but the last and after the last if a
/// change of it is taken on APPLY, each waited for. Before the first write, when an APPLY
/// will be needed: the bus idle ([`busy`]), or nothing is written. On a failure after the
/// first write, the error says what was written and what waits for APPLY.
/// Returns whether it applied.
pub fn write_changes(gw: &mut Gw, phases: &[Vec<Change>]) -> Result<bool, Fail> {
    let needs_apply = phases.len() > 1 || phases.iter().flatten().any(|c| c.on_apply);
    if needs_apply {
        let unit = gw.unit;
        let enabled = Settings::read_enabled(gw)?;
        if let Some(why) = busy(gw, &enabled)? {
            return Err(Fail::Device(format!(
                "{} unit {unit}: the settings need an APPLY, which the gateway refuses while anything moves or runs: {why}; nothing written (stop the axes, then try again)",
                gw.link.name
            )));
        }
    }
    let mut written: Vec<Change> = Vec::new();
    let mut done: Vec<Change> = Vec::new();
    let mut applied = false;
    let fail = |e: Fail, done: &[Change], written: &[Change]| match e {
        Fail::Device(m) | Fail::Input(m) => {
            Fail::Device(format!("{m}\n  {}", written_text(done, written)))
        }
    };
    for (i, phase) in phases.iter().enumerate() {
        let unit = gw.unit;
        for c in phase {
            let result = if c.key == "tcp_allow" {
                // Each address in one FC10 of two registers.
                (0..4u16).try_for_each(|i| {
                    let at = usize::from(2 * i);
                    gw.write(
                        unit,
                        c.address + 2 * i,
                        c.regs.get(at..at + 2).unwrap_or(&[0, 0]),
                    )
                })
            } else {
                gw.write(unit, c.address, &c.regs)
            };
            result.map_err(|e| fail(e, &done, &written))?;
            written.push(c.clone());
        }
        let last = i + 1 == phases.len();
        if !last || phase.iter().any(|c| c.on_apply) {
            apply(gw).map_err(|e| fail(e, &done, &written))?;
            // Applied: nothing written so far waits any more.
            done.append(&mut written);
            applied = true;
        }
    }
    Ok(applied)
}

/// APPLY, then the PLC line as it now is (RTU), and the establishment awaited.
pub fn apply(gw: &mut Gw) -> Result<(), Fail> {
    let unit = gw.unit;
    let before = gw.read(unit, G_BUS, G_BUS_LEN)?;
    let establishments = |regs: &[u16]| u32::from(regs[6]) << 16 | u32::from(regs[7]);
    let line = gw.read(unit, G_PLC_BAUD, 3)?;
    let (pending_unit, pending_base) = (line[2], gw.get(G_AXIS_BASE)?);
    let enabled = Settings::read_enabled(gw)?;
    // A refusal while nothing the PLC started moves or runs is the gateway's own work: the
    // establishment after a start (its first stops go before it, and a dead axis' cost
    // time-outs), a stop still on the bus. Asked again until it ends, 15 s at most.
    let patience = Instant::now() + Duration::from_secs(15);
    loop {
        match gw.try_write(unit, G_APPLY, &[1])? {
            Ok(()) => break,
            Err(Exception::IllegalDataValue) => {
                let why = busy(gw, &enabled)?;
                if why.is_some() || Instant::now() >= patience {
                    return Err(Fail::Device(format!(
                        "{}: APPLY refused (exception 03): {}",
                        gw.at(unit, G_APPLY),
                        why.unwrap_or_else(|| {
                            "something moves, runs or waits on the bus, or an establishment runs"
                                .into()
                        })
                    )));
                }
                std::thread::sleep(Duration::from_millis(250));
            }
            Err(e) => {
                return Err(Fail::Device(format!(
                    "{}: {e} writing 1",
                    gw.at(unit, G_APPLY)
                )))
            }
        }
    }
    if gw.link.is_rtu() {
        let parity = match line[1] {
            1 => serialport::Parity::Odd,
            2 => serialport::Parity::Even,
            _ => serialport::Parity::None,
        };
        std::thread::sleep(Duration::from_millis(50));
        gw.link.set_line(u32::from(line[0]) * 100, parity)?;
    }
    gw.unit = pending_unit as u8;
    gw.base = pending_base as u8;
    let unit = gw.unit;
    let limit = Duration::from_millis(3000 + 1500 * enabled.len() as u64);
    let deadline = Instant::now() + limit;
    loop {
        // Every axis stops answering while the establishment runs; the gateway unit answers.
        let done = match gw.try_read(unit, G_BUS, G_BUS_LEN) {
            Ok(Ok(now)) => establishments(&now) != establishments(&before),
            _ => false,
        };
        if done {
            break;
        }
        if Instant::now() > deadline {
            return Err(Fail::Device(format!(
                "{}: APPLY written, but no establishment finished within {} ms",
                gw.at(unit, G_BUS + 6),
                limit.as_millis()
            )));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    // Then each enabled axis settles to online or offline.
    for n in enabled {
        let axis_unit = gw.axis_unit(n);
        while Instant::now() < deadline {
            match gw.try_read(axis_unit, LINK, 1)? {
                Ok(v) if v.first().is_some_and(|&l| l != 0) => break,
                _ => std::thread::sleep(Duration::from_millis(50)),
            }
        }
    }
    Ok(())
}

/// SAVE, waiting for SAVESTAT.
pub fn save(gw: &mut Gw) -> Result<u32, Fail> {
    gw.set(G_SAVE, 1)?;
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        match gw.get(G_SAVE_STATUS)? {
            2 => {
                let unit = gw.unit;
                let count = gw.read(unit, G_SAVE_COUNT, 2)?;
                return Ok(u32::from(count[0]) << 16 | u32::from(count[1]));
            }
            3 => {
                return Err(Fail::Device(format!(
                    "{}: the save failed (SAVESTAT 3)",
                    gw.at(gw.unit, G_SAVE_STATUS)
                )))
            }
            _ if Instant::now() > deadline => {
                return Err(Fail::Device(format!(
                    "{}: the save did not finish within 5 s",
                    gw.at(gw.unit, G_SAVE_STATUS)
                )))
            }
            _ => std::thread::sleep(Duration::from_millis(20)),
        }
    }
}
