//! The settings at start-up and on SAVE: the store in the flash pages `memory.x` reserves
//! (`settings_store` over the chip's flash), the factory reset, and why the board started.
//!
//! At start-up the stored settings are loaded (the defaults on first start, after a factory
//! reset, or when the stored ones are unreadable: counted, CFGERRORS). Holding HOME and RES ON
//! while the board powers up is a factory reset: the stored settings are forgotten before they
//! are loaded. The flash is written only when the PLC asks (SAVE, FACTORY), as IAI's
//! controllers write their parameters only on request.
//!
//! QEMU models no flash interface: the emulator build has no store (a save fails, SAVESTAT 3).

use protocol::pio::PioInputs;
use protocol::plc::settings::RECORD_LEN;
use protocol::plc::{Boot, GatewayConfig};

use crate::board::SettingsFlash;

/// The inputs that, held ON at power-up, ask for a factory reset.
pub const FACTORY_RESET_INPUTS: PioInputs =
    PioInputs::from_bits(PioInputs::HOME.bits() | PioInputs::RES.bits());

/// The settings store, if the board has one.
pub struct SavedSettings {
    #[cfg(feature = "hw")]
    store: Option<settings_store::Store<SettingsFlash>>,
    /// What the start found: where the settings came from, the saves so far, why the board
    /// started ([`SavedSettings::load`]).
    pub boot: Boot,
}

impl SavedSettings {
    /// The store on `flash` (`None`: the board has none, or its range is not whole pages).
    #[cfg(feature = "hw")]
    pub fn new(flash: Option<SettingsFlash>) -> SavedSettings {
        let store = flash.and_then(|f| settings_store::Store::new(f, crate::board::SETTINGS_RANGE));
        if store.is_none() {
            warn!("settings: no store, the defaults apply");
        }
        SavedSettings {
            store,
            boot: Boot::DEFAULT,
        }
    }

    /// No store (the emulator).
    #[cfg(feature = "emulator")]
    pub fn new(_flash: Option<SettingsFlash>) -> SavedSettings {
        SavedSettings {
            boot: Boot::DEFAULT,
        }
    }

    /// The configuration to start with, into `config` (which holds the defaults): the stored
    /// settings over them, or nothing (after a factory reset if `inputs` ask for one); and
    /// what the start found, into [`SavedSettings::boot`].
    ///
    /// The store's operations block (the chip's flash is blocking): each is run to completion on
    /// the spot, in a function of its own, so that the store's code is in the firmware once
    /// rather than inlined into the gateway task's state machine at every call.
    #[inline(never)]
    pub fn load(&mut self, inputs: PioInputs, config: &mut GatewayConfig) {
        let factory = inputs.contains(FACTORY_RESET_INPUTS);
        #[cfg(feature = "hw")]
        if self.store.is_some() {
            if factory {
                warn!("settings: factory reset (HOME and RES held at power-up)");
                self.factory_reset();
            }
            self.apply_stored(config);
        }
        #[cfg(feature = "emulator")]
        let _ = (factory, config);
        let boot = &mut self.boot;
        boot.reset = crate::board::reset_cause();
        info!(
            "settings: source {}, {} saves, reset cause {}",
            boot.source as u8, boot.save_count, boot.reset as u8
        );
    }

    /// What the store holds, into `config` and [`SavedSettings::boot`]: the settings loaded are
    /// applied here, not returned.
    // Not inlined, like each store operation here: each one's frames (its nested calls, what it
    // returns) are then on the stack only while it runs, not all of them at once under
    // `SavedSettings::load` (the deepest stack at start-up is this one: `scripts/stack_depth.py`).
    #[cfg(feature = "hw")]
    #[inline(never)]
    fn apply_stored(&mut self, config: &mut GatewayConfig) {
        let Some(store) = self.store.as_mut() else {
            return;
        };
        let loaded = store.load();
        if let Some(settings) = loaded.settings {
            settings.apply_to(config);
        }
        self.boot = loaded.boot;
    }

    /// SAVE: store `record`; the saves so far, or `Err` (SAVESTAT 3) if there is no store, it
    /// failed, or the save came too soon after others (`settings_store::SAVE_BURST`: the flash's
    /// wear is paced).
    #[inline(never)]
    pub fn save(&mut self, record: &[u8; RECORD_LEN]) -> Result<u32, ()> {
        #[cfg(feature = "hw")]
        if let Some(store) = self.store.as_mut() {
            // The pace's clock, in units of 2^20 µs (1.05 s; a shift, where seconds would link
            // a 64-bit division): 142 years before u32 runs out.
            let now = (embassy_time::Instant::now().as_micros() >> 20) as u32;
            return store.save(record, now).map_err(|e| {
                // TooSoon: the PLC saved more than the pace allows (SAVESTAT 3 tells it).
                warn!("settings: SAVE not stored: {}", e);
            });
        }
        let _ = record;
        Err(())
    }

    /// The store's flash, for the DFU partition (`dfu`), which lies outside the store's pages;
    /// `None` without a store.
    #[cfg(all(feature = "hw", feature = "update"))]
    pub fn flash(&mut self) -> Option<&mut SettingsFlash> {
        self.store.as_mut().map(|store| store.flash_mut())
    }

    /// FACTORY: forget the stored settings (the caller restarts).
    #[inline(never)]
    pub fn factory_reset(&mut self) {
        #[cfg(feature = "hw")]
        if let Some(store) = self.store.as_mut() {
            if store.factory_reset().is_err() {
                error!("settings: the factory reset could not be written");
            }
        }
    }
}
