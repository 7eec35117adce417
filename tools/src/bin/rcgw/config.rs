//! `rcgw config`: the settings as TOML, shown, compared with a file, or a file applied.

use protocol::plc::map::G_NET;
use serde_json::json;

use crate::link::{Fail, Gw};
use crate::settings::{self, Settings};
use crate::{bad_file, print_json, read_toml, ConfigCmd};

/// `rcgw config show | diff | apply`.
pub fn config(gw: &mut Gw, json: bool, action: &ConfigCmd) -> Result<(), Fail> {
    let now = Settings::read(gw)?;
    match action {
        ConfigCmd::Show => {
            if json {
                print_json(&now.to_json());
            } else {
                outln!(
                    "# rcgw config show: gateway unit {} on {}",
                    gw.unit,
                    gw.link.name
                );
                out!("{}", now.to_toml());
            }
            Ok(())
        }
        ConfigCmd::Diff { file } | ConfigCmd::Apply { file, .. } => {
            let doc = read_toml(file)?;
            let wanted = Settings::from_toml(&doc, &[], false).map_err(|e| bad_file(file, e))?;
            if wanted.has_network() && !now.has_network() {
                return Err(Fail::Input(format!(
                    "{file}: [network]: this gateway has no network settings ({} answers exception 02: a build without TCP)",
                    gw.at(gw.unit, G_NET)
                )));
            }
            let whole = now.merged(&wanted).check_whole();
            if !whole.is_empty() {
                return Err(bad_file(file, whole));
            }
            let changes = now.diff(&wanted);
            let phases = settings::plan(&now, &changes).map_err(|e| bad_file(file, vec![e]))?;
            let apply = matches!(action, ConfigCmd::Apply { .. });
            let save = matches!(action, ConfigCmd::Apply { save: true, .. });
            let applied = if apply {
                settings::write_changes(gw, &phases)?
            } else {
                false
            };
            let saved = if save {
                Some(settings::save(gw)?)
            } else {
                None
            };
            if json {
                print_json(&json!({
                    "changes": changes,
                    "phases": phases.len(),
                    "written": apply,
                    "applied": applied,
                    "saved": saved.is_some(),
                }));
            } else {
                if changes.is_empty() {
                    outln!("no change");
                }
                for c in &changes {
                    outln!("{}", c.line());
                }
                if let [first, _] = phases.as_slice() {
                    outln!(
                        "in two steps: {} first, then APPLY, then the rest (the gateway refuses them in one)",
                        keys(first)
                    );
                }
                if changes.iter().any(|c| c.on_restart()) {
                    outln!("[network] addresses take effect after SAVE and RESTART (--save, then rcgw restart)");
                }
                if apply && !changes.is_empty() {
                    outln!("{} setting(s) written", changes.len());
                }
                if applied {
                    outln!("APPLY done: the bus was established again");
                }
                if let Some(count) = saved {
                    outln!("saved (SAVECOUNT {count})");
                }
            }
            Ok(())
        }
    }
}

/// The settings of a write's first phase, as the file names them: `[gateway] unit_id, ...`.
pub fn keys(changes: &[settings::Change]) -> String {
    changes
        .iter()
        .map(|c| format!("{} {}", settings::section_name(c.section), c.key))
        .collect::<Vec<_>>()
        .join(", ")
}
