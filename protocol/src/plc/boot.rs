//! What the firmware says about this start ([`Boot`]): where the settings came from and why the
//! board started. A leaf: `config` holds a [`Boot`], `persist` and `settings` read the config,
//! and none of them is needed here.

/// Where the running settings came from (CFGSOURCE).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ConfigSource {
    /// The defaults: nothing stored yet (first start, or after a factory reset).
    #[default]
    Defaults = 0,
    /// The stored settings.
    Flash = 1,
    /// The defaults, because the stored settings could not be read (damaged, or written by an
    /// incompatible firmware): counted in [`Boot::load_errors`].
    Damaged = 2,
}

/// Why the board last started (RESETCAUSE), as the firmware read it from the chip.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetCause {
    /// Power-on (or brown-out).
    #[default]
    PowerOn = 0,
    /// The independent hardware watchdog: the gateway task stopped making progress.
    Watchdog = 1,
    /// A software reset (RESTART, a factory reset, a panic).
    Software = 2,
    /// The reset pin.
    Pin = 3,
    /// Anything else (low power, option bytes, ...).
    Other = 4,
}

/// What the firmware knows about this start.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Boot {
    /// Where the settings came from.
    pub source: ConfigSource,
    /// Stored settings found unreadable so far (kept in flash apart from the settings).
    pub load_errors: u16,
    /// Saves so far (kept in flash with the settings).
    pub save_count: u32,
    /// Why the board started.
    pub reset: ResetCause,
}

impl Boot {
    /// A start with nothing known (the PC gateway, tests).
    pub const DEFAULT: Boot = Boot {
        source: ConfigSource::Defaults,
        load_errors: 0,
        save_count: 0,
        reset: ResetCause::PowerOn,
    };
}
