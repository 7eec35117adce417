//! The stored settings record's decoder on any bytes (issue 24: the record comes back from flash
//! after power cuts, worn pages and firmware updates).
//!
//! Checks: nothing panics; a record the decoder takes is one the encoder writes, byte for byte
//! (so nothing outside the encoder's ranges is ever applied at start-up); and the input with its
//! checksum fixed, the likelier case of a field out of range, goes through the same check.
#![no_main]

use libfuzzer_sys::fuzz_target;
use protocol::modbus::crc;
use protocol::plc::settings::{Settings, RECORD_LEN};

fn check(record: &[u8]) {
    if let Ok(settings) = Settings::decode(record) {
        assert_eq!(&settings.encode()[..], record, "decode then encode is the same record");
    }
}

fuzz_target!(|data: &[u8]| {
    check(data);
    // The same bytes as a whole record with a valid checksum and format byte.
    let mut record = [0u8; RECORD_LEN];
    for (slot, byte) in record.iter_mut().zip(data) {
        *slot = *byte;
    }
    record[0] = protocol::plc::settings::FORMAT;
    let sum = crc::checksum(&record[..RECORD_LEN - 2]);
    record[RECORD_LEN - 2..].copy_from_slice(&sum.to_le_bytes());
    check(&record);
});
