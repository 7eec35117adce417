//! What the driver does to the line itself, besides sending frames (complete edition §2, §6-1).

/// Baud rates and their BRSL selection codes (complete edition §7-2-1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Baud {
    /// 9.6 kbit/s, code 04: the rate after a break.
    B9600,
    /// 14.4 kbit/s, code 11.
    B14400,
    /// 19.2 kbit/s, code 05.
    B19200,
    /// 28.8 kbit/s, code 12.
    B28800,
    /// 38.4 kbit/s, code 06: the brief edition's default.
    B38400,
    /// 57.6 kbit/s, code 13.
    B57600,
    /// 76.8 kbit/s, code 07.
    B76800,
    /// 115.2 kbit/s, code 14.
    B115200,
}

impl Baud {
    /// Every rate, slowest first.
    pub const ALL: [Baud; 8] = [
        Baud::B9600,
        Baud::B14400,
        Baud::B19200,
        Baud::B28800,
        Baud::B38400,
        Baud::B57600,
        Baud::B76800,
        Baud::B115200,
    ];

    /// Bits per second.
    pub const fn bits_per_second(self) -> u32 {
        match self {
            Baud::B9600 => 9_600,
            Baud::B14400 => 14_400,
            Baud::B19200 => 19_200,
            Baud::B28800 => 28_800,
            Baud::B38400 => 38_400,
            Baud::B57600 => 57_600,
            Baud::B76800 => 76_800,
            Baud::B115200 => 115_200,
        }
    }

    /// The BRSL code written at common parameter 0x009.
    pub const fn brsl(self) -> u8 {
        match self {
            Baud::B9600 => 0x04,
            Baud::B14400 => 0x11,
            Baud::B19200 => 0x05,
            Baud::B28800 => 0x12,
            Baud::B38400 => 0x06,
            Baud::B57600 => 0x13,
            Baud::B76800 => 0x07,
            Baud::B115200 => 0x14,
        }
    }

    /// The rate of a BRSL code.
    pub fn from_brsl(code: u32) -> Option<Baud> {
        Baud::ALL.into_iter().find(|b| u32::from(b.brsl()) == code)
    }

    /// The rate in bits per second, if it is one the controllers support.
    pub fn from_bits_per_second(bps: u32) -> Option<Baud> {
        Baud::ALL.into_iter().find(|b| b.bits_per_second() == bps)
    }
}

/// After a break every axis is at this rate (and RTIM 255 ms) (complete edition §7-2-1 note).
pub const BAUD_AFTER_BREAK: Baud = Baud::B9600;
/// How long the line is held low for a break: the §6-1 figure shows 200 ms (the definition in §2
/// needs only more than 10 bit times of 0).
pub const BREAK_MS: u32 = 200;
/// The communication-change broadcast is sent this many times (§6-1 step 8)...
pub const COMM_CHANGE_REPEATS: u8 = 3;
/// ...within this many milliseconds (§6-1 figure)...
pub const COMM_CHANGE_WINDOW_MS: u32 = 100;
/// ...and the new settings are in force this long after it (§6-1 step 9).
pub const COMM_CHANGE_SETTLE_MS: u32 = 150;
/// The host waits at least this long after a response before the next command (§2 (2)).
pub const HOST_GAP_MS: u32 = 1;

/// Something other than a frame that the driver must do to the line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LineAction {
    /// Start holding the line low (a break): every axis returns to 9.6 kbit/s and RTIM 255 ms.
    /// [`LineAction::BreakEnd`] follows [`BREAK_MS`] later.
    BreakStart,
    /// Release the line: the break is over.
    BreakEnd,
    /// Send [`COMM_CHANGE`](crate::frame::COMM_CHANGE) (STX + 14 ENQ + ETX); nobody answers.
    CommChange,
    /// Switch the gateway's own UART to this rate.
    SetBaud(Baud),
}
