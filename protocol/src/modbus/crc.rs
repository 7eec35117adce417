//! CRC-16/MODBUS (Serial Line §2.5.1.2 and Appendix B §6.2.2): polynomial 0xA001 (reflected
//! 0x8005), initial value 0xFFFF, no final XOR. The CRC is the last field of an RTU frame,
//! **low byte first** (the only little-endian field in Modbus).
//!
//! ```
//! use protocol::modbus::crc;
//!
//! assert_eq!(crc::checksum(b"123456789"), 0x4B37);
//! assert_eq!(crc::to_wire(crc::checksum(&[0x01, 0x03, 0x00, 0x00, 0x00, 0x0A])), [0xC5, 0xCD]);
//! ```

/// A table-driven CRC-16/MODBUS (one 256-entry table, 512 bytes of flash).
const MODBUS: ::crc::Crc<u16> = ::crc::Crc::<u16>::new(&::crc::CRC_16_MODBUS);

/// The CRC of `bytes`.
pub const fn checksum(bytes: &[u8]) -> u16 {
    MODBUS.checksum(bytes)
}

/// The two CRC bytes as sent: low byte first.
pub const fn to_wire(crc: u16) -> [u8; 2] {
    crc.to_le_bytes()
}

/// Whether `frame` ends with the CRC of what precedes it (false if it is shorter than 2 bytes).
pub fn is_valid(frame: &[u8]) -> bool {
    match frame.len().checked_sub(2).map(|at| frame.split_at(at)) {
        Some((body, crc)) => crc == to_wire(checksum(body)),
        None => false,
    }
}
