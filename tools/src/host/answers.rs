//! What a control command does and answers: alarm injection, the stop input, quit, help, and
//! `stats`: the counters and the state of every axis.

use protocol::engine::Link;
use protocol::Pulses;
use serde_json::{json, Value};

use super::{BusSide, Control, Ended, Host, HELP};

impl Host {
    /// Carry out a control command: its answer, and whether the run ends.
    pub fn control(&mut self, now: u64, command: Control) -> (Value, Option<Ended>) {
        match command {
            Control::Alarm(axis, code) => match &mut self.bus {
                BusSide::Sim(bus) => match bus.inject_alarm(axis, code) {
                    Ok(()) => {
                        self.log.note(
                            now,
                            &format!("alarm {:02X} injected on axis {}", code.0, axis.get()),
                        );
                        (json!({"ok": true, "cmd": "alarm"}), None)
                    }
                    Err(_) => (
                        json!({"ok": false, "error": format!(
                            "no simulated axis {}, or {:02X} is not an error code (80-FF)",
                            axis.get(), code.0)}),
                        None,
                    ),
                },
                BusSide::Device { .. } => (
                    json!({"ok": false, "error": "alarms can be injected on a simulated bus only"}),
                    None,
                ),
            },
            Control::Stats => (self.stats(now), None),
            Control::StopInput(active) => {
                self.node.set_stop_input(self.node_time(now), active);
                (json!({"ok": true, "cmd": "stop-input"}), None)
            }
            Control::Restart => {
                self.restart_due = Some(super::Restart::Reset);
                (json!({"ok": true, "cmd": "restart"}), None)
            }
            Control::Quit => (json!({"ok": true, "cmd": "quit"}), Some(Ended::Quit)),
            Control::Help => (json!({"ok": true, "help": HELP}), None),
        }
    }

    /// What `stats` answers.
    pub fn stats(&self, now: u64) -> Value {
        let slave = self.node.plc_counters();
        let receiver = self.node.receiver_counters();
        let gateway = self.node.gateway();
        let config = gateway.config();
        let axes: Vec<Value> = config
            .bus
            .axes
            .iter()
            .map(|axis| {
                let i = usize::from(axis.get());
                let sent = self.sent.get(i).cloned().unwrap_or_default();
                let commands: u64 = sent
                    .iter()
                    .filter(|(mnemonic, _)| !matches!(**mnemonic, "n" | "R4"))
                    .map(|(_, count)| count)
                    .sum();
                let (state, reason) = gateway.command_state(axis);
                let link = match gateway.engine().axis(axis).link {
                    Link::Unknown => "unknown",
                    Link::Online => "online",
                    Link::Offline => "offline",
                };
                let mut entry = json!({
                    "axis": i,
                    "sent": sent,
                    "commands": commands,
                    "cmst": state as u16,
                    "cmer": reason,
                    "link": link,
                });
                let scale = Some(config.settings.axes[axis].scale);
                if let (Some(c), Some(scale), Value::Object(map)) = (
                    self.sim().and_then(|bus| bus.controller(axis)),
                    scale,
                    &mut entry,
                ) {
                    let position = c.position();
                    let wire = Pulses(i32::try_from(position).unwrap_or(i32::MAX));
                    map.insert("frames_received".into(), c.stats().frames_addressed.into());
                    map.insert("moving".into(), c.moving().into());
                    map.insert("homing".into(), c.homing().into());
                    map.insert("homed".into(), c.homed().into());
                    map.insert("servo".into(), c.servo().into());
                    map.insert("alarm".into(), c.alarm().0.into());
                    map.insert("position".into(), position.into());
                    map.insert(
                        "position_mm100".into(),
                        scale.position_from_wire(wire).0.into(),
                    );
                    map.insert("last_move_start".into(), c.last_move_start().into());
                    let nv = &c.memory().nv;
                    let stores: u64 = nv.point_writes.iter().map(|&n| u64::from(n)).sum();
                    map.insert(
                        "nv_writes".into(),
                        (stores + u64::from(nv.common_writes)).into(),
                    );
                }
                entry
            })
            .collect();
        json!({
            "ok": true,
            "cmd": "stats",
            "time_us": now,
            "failsafe": gateway.failsafe(),
            "modbus": {
                "frames": slave.frames,
                "replies": slave.replies,
                "crc_errors": slave.crc_errors,
                "too_short": slave.too_short,
                "too_long": slave.too_long,
                "bad_gaps": slave.bad_gaps,
                "ignored": slave.ignored,
                "malformed": slave.malformed,
                "broadcasts": slave.broadcasts,
                "exceptions": [
                    slave.illegal_function,
                    slave.illegal_data_address,
                    slave.illegal_data_value,
                    slave.server_device_failure,
                ],
                "overruns": receiver.overruns,
            },
            "axes": axes,
        })
    }
}
