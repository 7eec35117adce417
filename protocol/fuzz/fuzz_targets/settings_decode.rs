//! The stored settings record's decoder on any bytes (issue 24: the record comes back from flash
//! after power cuts, worn pages and firmware updates).
//!
//! Checks: nothing panics; a current-format record the decoder takes is one the encoder writes,
//! byte for byte (so nothing outside the encoder's ranges is ever applied at start-up); an older
//! format's record (2, 1) the decoder takes re-encodes to a current record that decodes to the
//! same settings (the first SAVE after an update writes that); and the input as a whole record of
//! each format with its checksum fixed, the likelier case of a field out of range, goes through
//! the same checks.
#![no_main]

use libfuzzer_sys::fuzz_target;
use protocol::modbus::crc;
use protocol::plc::settings::{
    Settings, FORMAT, FORMAT_1, FORMAT_2, RECORD_LEN, RECORD_LEN_1, RECORD_LEN_2,
};

fn check(record: &[u8]) {
    let Ok(settings) = Settings::decode(record) else {
        return;
    };
    let encoded = settings.encode();
    if record.first() == Some(&FORMAT) {
        assert_eq!(
            &encoded[..],
            record,
            "decode then encode is the same record"
        );
    } else {
        let again =
            Settings::decode(&encoded).expect("an older record re-encodes to one that decodes");
        assert_eq!(
            again, settings,
            "an older record keeps its settings in the current format"
        );
    }
}

fuzz_target!(|data: &[u8]| {
    check(data);
    // The same bytes as a whole record of each format, with a valid format byte and checksum.
    for (format, len) in [
        (FORMAT, RECORD_LEN),
        (FORMAT_2, RECORD_LEN_2),
        (FORMAT_1, RECORD_LEN_1),
    ] {
        let mut record = [0u8; RECORD_LEN];
        for (slot, byte) in record.iter_mut().zip(data) {
            *slot = *byte;
        }
        let record = &mut record[..len];
        record[0] = format;
        let sum = crc::checksum(&record[..len - 2]);
        record[len - 2..].copy_from_slice(&sum.to_le_bytes());
        check(record);
    }
});
