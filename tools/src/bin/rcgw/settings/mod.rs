//! The gateway's settings as registers of the gateway unit, and as TOML with the units in the
//! key names: read, shown, checked (every value, before anything is written), compared and
//! written.
//!
//! [`schema`]: every setting, its registers and its form; [`file`](mod@file): the TOML text, parsed and
//! printed; [`plan`](mod@plan): the order the gateway admits the writes in; [`io`]: the registers read
//! and written, APPLY and SAVE.

mod file;
mod io;
mod plan;
mod schema;

use std::collections::BTreeMap;

use protocol::axes::AXES;
use protocol::plc::map::*;

use file::render;
pub use file::{axis_number, hundredths, parse_hundredths};
pub use io::{apply, busy, save, write_changes};
pub use plan::plan;
use schema::{field, on_apply, AXIS};
pub use schema::{section_name, Section};

/// Settings: each setting's registers, by section and key (a file may hold some only).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Settings {
    pub values: BTreeMap<(Section, &'static str), Vec<u16>>,
}

impl Settings {
    /// Axis `n`'s AXISCFG block as registers (enabled, lead, home, pulses/rev, stroke (2),
    /// complement), 0 for a setting not held.
    pub fn axis_cfg(&self, n: u8) -> Vec<u16> {
        let section = Section::Axis(n);
        let mut regs = vec![0u16; usize::from(G_AXIS_CONFIG_LEN)];
        for field in AXIS {
            if let Some(v) = self.values.get(&(section, field.key)) {
                for (i, &w) in v.iter().enumerate() {
                    if let Some(slot) = regs.get_mut(usize::from(field.address) + i) {
                        *slot = w;
                    }
                }
            }
        }
        regs
    }

    /// Whether the gateway has the network block.
    pub fn has_network(&self) -> bool {
        self.values.keys().any(|(s, _)| *s == Section::Network)
    }

    /// The raw registers of a setting.
    pub fn word(&self, section: Section, key: &str) -> Option<u16> {
        self.values
            .iter()
            .find(|((s, k), _)| *s == section && *k == key)
            .and_then(|(_, v)| v.first().copied())
    }

    /// The axes enabled.
    pub fn enabled(&self) -> Vec<u8> {
        (0..AXES as u8)
            .filter(|&n| self.word(Section::Axis(n), "enabled") == Some(1))
            .collect()
    }

    /// `self` with `file`'s settings over it.
    pub fn merged(&self, file: &Settings) -> Settings {
        let mut out = self.clone();
        for (k, v) in &file.values {
            out.values.insert(*k, v.clone());
        }
        out
    }

    /// The checks across settings, on the settings as they would be: the gateway's unit not an
    /// enabled axis' unit; enabled axes within the unit range.
    pub fn check_whole(&self) -> Vec<String> {
        let mut errors = Vec::new();
        let unit = self.word(Section::Gateway, "unit_id").unwrap_or(63);
        let base = self.word(Section::Gateway, "axis_base").unwrap_or(1);
        for n in self.enabled() {
            let axis_unit = base + u16::from(n);
            if axis_unit == unit {
                errors.push(format!(
                    "[gateway] unit_id = {unit}: axis {n} is enabled and would be unit {axis_unit} (axis_base {base} + {n}); choose a unit outside the axes' range"
                ));
            }
            if axis_unit > 247 {
                errors.push(format!(
                    "[axis.{n}] enabled: its unit would be {axis_unit} (axis_base {base} + {n}), past 247"
                ));
            }
        }
        errors
    }

    /// The settings of `target` that differ from `self`: (section, key, now, then).
    pub fn diff(&self, target: &Settings) -> Vec<Change> {
        target
            .values
            .iter()
            .filter(|(k, v)| self.values.get(k) != Some(v))
            .filter_map(|((section, key), to)| {
                let field = field(*section, key)?;
                let from = self.values.get(&(*section, *key));
                Some(Change {
                    section: *section,
                    key,
                    address: section.base() + field.address,
                    from: from.map(|r| render(field.kind, r)),
                    to: render(field.kind, to),
                    regs: to.clone(),
                    on_apply: on_apply(*section, field),
                })
            })
            .collect()
    }
}

/// One setting to change.
#[derive(Clone, Debug)]
pub struct Change {
    pub section: Section,
    pub key: &'static str,
    pub address: u16,
    pub from: Option<String>,
    pub to: String,
    pub regs: Vec<u16>,
    pub on_apply: bool,
}

impl Change {
    pub fn line(&self) -> String {
        format!(
            "{} {}: {} -> {}{}",
            self.section.name(),
            self.key,
            self.from.as_deref().unwrap_or("(none)"),
            self.to,
            if self.on_apply {
                " (on APPLY)"
            } else if self.on_restart() {
                " (after SAVE and RESTART)"
            } else {
                ""
            }
        )
    }

    /// Taken only at the next start (the network address settings).
    pub fn on_restart(&self) -> bool {
        self.section == Section::Network && self.key.starts_with("ip_")
    }
}

/// A change in JSON: `{"section": "[gateway]", "key", "register": "0x0001", "from", "to",
/// "on_apply", "on_restart"}`.
impl serde::Serialize for Change {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        #[derive(serde::Serialize)]
        struct Json<'a> {
            section: String,
            key: &'a str,
            register: String,
            from: &'a Option<String>,
            to: &'a str,
            on_apply: bool,
            on_restart: bool,
        }
        Json {
            section: self.section.name(),
            key: self.key,
            register: format!("{:#06x}", self.address),
            from: &self.from,
            to: &self.to,
            on_apply: self.on_apply,
            on_restart: self.on_restart(),
        }
        .serialize(serializer)
    }
}
