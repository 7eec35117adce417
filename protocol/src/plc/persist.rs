//! What survives a power cycle, as the PLC sees it: the settings that take effect only on APPLY
//! or at the next start (the lines and the axes on the bus), SAVE and factory reset. What the
//! firmware says about the start itself is [`Boot`](super::Boot), in `boot`.
//!
//! The gateway never writes flash by itself: a SAVE (or a factory reset) becomes a [`SettingsRequest`]
//! request the firmware carries out ([`Node`](crate::node::Node) hands it over as an action)
//! and reports back, as IAI's controllers write their parameters to flash only on request.

use super::boot::Boot;
use super::config::{AxisBase, GatewayConfig, PlcLine, UnitId};
use super::settings::{Settings, RECORD_LEN};
use crate::axes::AxisSet;
use crate::line::Baud;
use crate::Rtim;

/// What the PLC asked of the stored settings (SAVE, FACTORY, RESTART): the firmware writes
/// them, erases them, or restarts with them. (Not `Store`: that is the flash store, and `V5`
/// stores a point on a controller.)
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SettingsRequest {
    /// Store the settings record [`Node::settings_record`](crate::node::Node::settings_record)
    /// gives now.
    // Not carried here: 213 bytes in every action and in the node, on a stack with a hundred
    // bytes to spare on the F103.
    Save,
    /// Erase the stored settings, then restart (with the defaults).
    FactoryReset,
    /// Restart (the saved settings take effect).
    Restart,
}

/// SAVESTAT.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(u16)]
pub(super) enum SaveStatus {
    #[default]
    Idle = 0,
    Saving = 1,
    Saved = 2,
    Failed = 3,
}

/// The settings written but not in force yet (they take effect on APPLY or at the next
/// start), and the state of a save.
#[derive(Clone, Copy, Debug)]
pub(super) struct Persist {
    /// BUSBAUD, BUSRTIM.
    pub(super) baud: Baud,
    pub(super) rtim: Rtim,
    /// PLCBAUD, PLCPARITY.
    pub(super) plc: PlcLine,
    /// UNITID.
    pub(super) unit: UnitId,
    /// AXISBASE.
    pub(super) axis_base: AxisBase,
    /// AXISCFG's "enabled" bits.
    pub(super) axes: AxisSet,
    pub(super) status: SaveStatus,
    /// How this start found the stored settings, and the saves so far (counted on).
    pub(super) boot: Boot,
    /// A request for the firmware, not taken yet.
    pub(super) request: Option<SettingsRequest>,
}

impl Persist {
    /// The settings of `config` in force, after a start `boot` reports.
    pub(super) const fn new(config: &GatewayConfig, boot: Boot) -> Persist {
        Persist {
            baud: config.bus.baud,
            rtim: config.bus.rtim,
            plc: config.settings.plc,
            unit: config.settings.unit,
            axis_base: config.settings.axis_base,
            axes: config.bus.axes,
            status: SaveStatus::Idle,
            boot,
            request: None,
        }
    }

    /// The pending settings into `config`: what APPLY does, and what SAVE stores with the rest
    /// of `config`.
    pub(super) fn apply_to(&self, config: &mut GatewayConfig) {
        config.bus.baud = self.baud;
        config.bus.rtim = self.rtim;
        config.settings.plc = self.plc;
        config.settings.unit = self.unit;
        config.settings.axis_base = self.axis_base;
        config.bus.axes = self.axes;
    }

    /// SAVE: ask the firmware to store the settings (with the pending ones: [`record`]).
    ///
    /// [`record`]: Persist::record
    pub(super) fn save(&mut self) {
        self.request = Some(SettingsRequest::Save);
        self.status = SaveStatus::Saving;
    }

    /// The settings record of `config` with the pending settings in force: what SAVE stores.
    pub(super) fn record(&self, config: &GatewayConfig) -> [u8; RECORD_LEN] {
        let mut config = *config;
        self.apply_to(&mut config);
        Settings::of(&config).encode()
    }

    /// The firmware's answer to a save: the new save count, or a failure.
    pub(super) fn saved(&mut self, result: Result<u32, ()>) {
        match result {
            Ok(count) => {
                self.boot.save_count = count;
                self.status = SaveStatus::Saved;
            }
            Err(()) => self.status = SaveStatus::Failed,
        }
    }
}
