//! One set of logging macros for both builds: defmt over RTT on the board (`hw`), semihosting in
//! the emulator (QEMU prints it on its standard output, where the test harness reads it).
//!
//! Use plain `{}` placeholders with integers and `&str` only: the same format string must be valid
//! for defmt and for `core::fmt`, and `Debug` formatting would cost flash on the board.

#[cfg(feature = "hw")]
macro_rules! info {
    ($($arg:tt)*) => { defmt::info!($($arg)*) };
}
#[cfg(feature = "hw")]
macro_rules! warn {
    ($($arg:tt)*) => { defmt::warn!($($arg)*) };
}
#[cfg(feature = "hw")]
macro_rules! error {
    ($($arg:tt)*) => { defmt::error!($($arg)*) };
}

#[cfg(feature = "emulator")]
macro_rules! info {
    ($($arg:tt)*) => { cortex_m_semihosting::hprintln!("INFO  {}", format_args!($($arg)*)) };
}
#[cfg(feature = "emulator")]
macro_rules! warn {
    ($($arg:tt)*) => { cortex_m_semihosting::hprintln!("WARN  {}", format_args!($($arg)*)) };
}
#[cfg(feature = "emulator")]
macro_rules! error {
    ($($arg:tt)*) => { cortex_m_semihosting::hprintln!("ERROR {}", format_args!($($arg)*)) };
}
