//! The one-register commands: APPLY, ack, SAVE, RESTART and FACTORY, each written and its
//! outcome said.

use protocol::modbus::Exception;
use protocol::plc::map::*;
use serde_json::json;

use crate::link::{Fail, Gw};
use crate::print_json;
use crate::settings::{self, Settings};

/// `rcgw apply`: APPLY, once nothing moves, and the establishment awaited.
pub fn apply(gw: &mut Gw, json: bool) -> Result<(), Fail> {
    let enabled = Settings::read_enabled(gw)?;
    if let Some(why) = settings::busy(gw, &enabled)? {
        return Err(Fail::Device(format!(
            "{} unit {}: APPLY not written: the gateway refuses it while anything moves or runs: {why}",
            gw.link.name, gw.unit
        )));
    }
    settings::apply(gw)?;
    let enabled = Settings::read_enabled(gw)?;
    let units: Vec<u8> = enabled.iter().map(|&n| gw.axis_unit(n)).collect();
    if json {
        print_json(
            &json!({"applied": true, "unit": gw.unit, "axis_base": gw.base, "axes": enabled, "axis_units": units}),
        );
    } else {
        outln!(
            "APPLY done: gateway unit {}, axes {:?} at units {:?}; the bus was established again",
            gw.unit,
            enabled,
            units
        );
    }
    Ok(())
}

/// `rcgw ack`: FAILSAFE acknowledged, or why the gateway refuses.
pub fn ack(gw: &mut Gw, json: bool) -> Result<(), Fail> {
    let before = gw.get(G_FAILSAFE)?;
    if before == 0 {
        if json {
            print_json(&json!({"failsafe": 0, "acknowledged": false, "latched": false}));
        } else {
            outln!("FAILSAFE is clear: nothing to acknowledge");
        }
        return Ok(());
    }
    let unit = gw.unit;
    match gw.try_write(unit, G_FAILSAFE, &[0])? {
        Ok(()) => {}
        Err(Exception::IllegalDataValue) => {
            return Err(Fail::Device(format!(
                "{}: not acknowledged (exception 03): the cause is still there{}",
                gw.at(unit, G_FAILSAFE),
                if before & 2 != 0 {
                    ": the stop input is open; close the stop chain, then ack again"
                } else {
                    ": the stop input is open"
                }
            )))
        }
        Err(e) => return Err(Fail::Device(format!("{}: {e}", gw.at(unit, G_FAILSAFE)))),
    }
    let after = gw.get(G_FAILSAFE)?;
    if json {
        print_json(
            &json!({"failsafe": after, "was": before, "acknowledged": true, "latched": after != 0}),
        );
    } else {
        outln!("FAILSAFE acknowledged (was {before:#04x}, now {after:#04x})");
    }
    Ok(())
}

/// `rcgw save`: SAVE, and the save count once stored.
pub fn save(gw: &mut Gw, json: bool) -> Result<(), Fail> {
    let count = settings::save(gw)?;
    if json {
        print_json(&json!({"saved": true, "save_count": count}));
    } else {
        outln!("saved (SAVECOUNT {count})");
    }
    Ok(())
}

/// `rcgw restart`: RESTART written.
pub fn restart(gw: &mut Gw, json: bool) -> Result<(), Fail> {
    gw.set(G_RESTART, 1)?;
    if json {
        print_json(&json!({"restart": true}));
    } else {
        outln!("restart requested: the gateway restarts with its saved settings");
    }
    Ok(())
}

/// `rcgw factory-reset --yes`: the key written to FACTORY.
pub fn factory_reset(gw: &mut Gw, json: bool) -> Result<(), Fail> {
    gw.set(G_FACTORY, FACTORY_KEY)?;
    if json {
        print_json(&json!({"factory_reset": true}));
    } else {
        outln!(
            "factory reset: the stored settings are erased, the gateway restarts with the defaults"
        );
    }
    Ok(())
}
