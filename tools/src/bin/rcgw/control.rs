//! The one-register commands: APPLY, ack, SAVE, RESTART and FACTORY, each written and its
//! outcome said.

use std::time::{Duration, Instant};

use protocol::modbus::Exception;
use protocol::plc::map::*;
use protocol::plc::update::BootState;
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

/// What the gateway runs, as read after a restart: VERSION, UPTIME and BOOTSTAT.
pub struct Running {
    /// "major.minor.patch".
    pub version: String,
    /// Seconds since its start.
    pub uptime: u32,
    /// BOOTSTAT's state.
    pub boot: BootState,
    /// The version marked for the next start (0: none).
    pub marked: u32,
}

/// BOOTSTAT, then VERSION and UPTIME. Any Modbus reply of a gateway whose new firmware is on
/// trial is what confirms the trial (`Node::trial_passed`, once the bus's establishment is
/// over), so BOOTSTAT is read first: it shows the state the start left.
pub fn running(gw: &mut Gw) -> Result<Running, Fail> {
    let unit = gw.unit;
    // A gateway built without the update (an F103) has no BOOTSTAT: no bootloader.
    let b = gw
        .try_read(unit, G_BOOT_STATUS, G_BOOT_STATUS_LEN)?
        .unwrap_or_else(|_| vec![0; usize::from(G_BOOT_STATUS_LEN)]);
    let v = gw.read(unit, G_VERSION, 4)?;
    let (vmaj, patch, up_hi, up_lo) = (v[0], v[1], v[2], v[3]);
    Ok(Running {
        version: format!("{}.{}.{patch}", vmaj >> 8, vmaj & 0xFF),
        uptime: u32::from(up_hi) << 16 | u32::from(up_lo),
        boot: BootState::from_code(b[0]).unwrap_or_default(),
        marked: u32::from(b[1]) << 16 | u32::from(b[2]),
    })
}

/// What BOOTSTAT's state says after a restart.
pub fn boot_text(boot: BootState) -> &'static str {
    match boot {
        BootState::Unknown => "no bootloader",
        BootState::Confirmed => "confirmed",
        BootState::Trial => "on trial",
        BootState::RolledBack => "rolled back: the new image did not confirm",
    }
}

/// `rcgw restart`: RESTART written; unless `wait` is `None`, then waits until the gateway
/// answers again (over TCP: connects again), checks from its UPTIME that it did restart, and
/// says what it runs.
pub fn restart(
    gw: &mut Gw,
    cli: &crate::Cli,
    json: bool,
    wait: Option<Duration>,
) -> Result<(), Fail> {
    let asked = Instant::now();
    gw.set(G_RESTART, 1)?;
    let Some(limit) = wait else {
        if json {
            print_json(&json!({"restart": true}));
        } else {
            outln!("restart requested: the gateway restarts with its saved settings");
        }
        return Ok(());
    };
    let deadline = asked + limit;
    let tcp = !gw.link.is_rtu();
    // A moment for the gateway to go (and for a TCP connection to be dropped).
    std::thread::sleep(Duration::from_millis(200));
    let mut last = String::from("no answer");
    let mut reconnect = tcp;
    loop {
        if Instant::now() > deadline {
            return Err(Fail::Device(format!(
                "{}: the gateway did not answer within {:.0} s of RESTART ({last})",
                gw.link.name,
                limit.as_secs_f64()
            )));
        }
        if reconnect {
            // Only the link: the first request must be BOOTSTAT's read (`running`).
            match crate::open_link(cli) {
                Ok(link) => {
                    gw.link = link;
                    reconnect = false;
                }
                Err(e) => {
                    last = e.to_string();
                    std::thread::sleep(Duration::from_millis(200));
                    continue;
                }
            }
        }
        match running(gw) {
            Ok(now) => {
                let since = asked.elapsed().as_secs_f64();
                if f64::from(now.uptime) > since + 1.0 {
                    // The same run still answers (its uptime is older than the request).
                    last = format!(
                        "it answers with an uptime of {} s: not restarted",
                        now.uptime
                    );
                    if tcp {
                        reconnect = true;
                    }
                    std::thread::sleep(Duration::from_millis(200));
                    continue;
                }
                // A trial is confirmed by the gateway once it has answered (these reads) after
                // its bus's establishment: wait a little to say so.
                let confirmed = if now.boot == BootState::Trial {
                    Some(wait_confirmed(gw, CONFIRM_PATIENCE)?)
                } else {
                    None
                };
                if json {
                    print_json(&json!({
                        "restart": true,
                        "seconds": since,
                        "version": now.version,
                        "uptime": now.uptime,
                        "boot": now.boot.name(),
                        "confirmed": confirmed,
                        "marked": marked_text(now.marked),
                    }));
                } else {
                    let after = match confirmed {
                        Some(true) => ", confirmed now (the gateway answered after its start)",
                        Some(false) => {
                            ", not confirmed yet: a restart before the confirmation rolls it back"
                        }
                        None => "",
                    };
                    outln!(
                        "restarted in {since:.1} s: running {}, {}{after}",
                        now.version,
                        boot_text(now.boot)
                    );
                }
                return Ok(());
            }
            Err(e) => {
                last = e.to_string();
                if tcp {
                    reconnect = true;
                }
                std::thread::sleep(Duration::from_millis(200));
            }
        }
    }
}

/// How long `rcgw restart` waits for a trial's confirmation.
const CONFIRM_PATIENCE: Duration = Duration::from_secs(10);

/// Whether BOOTSTAT turns from on trial to confirmed within `limit`.
fn wait_confirmed(gw: &mut Gw, limit: Duration) -> Result<bool, Fail> {
    let deadline = Instant::now() + limit;
    let unit = gw.unit;
    loop {
        let b = gw.read(unit, G_BOOT_STATUS, 1)?;
        if BootState::from_code(b.first().copied().unwrap_or(0)) == Some(BootState::Confirmed) {
            return Ok(true);
        }
        if Instant::now() > deadline {
            return Ok(false);
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// BOOTSTAT's marked version, "1.2.3", or `None` for none.
pub fn marked_text(v: u32) -> Option<String> {
    (v != 0).then(|| {
        let v = rc_boot::image::Version::from_u32(v);
        format!("{}.{}.{}", v.major, v.minor, v.patch)
    })
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
