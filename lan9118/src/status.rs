//! Pure decoding of the LAN9118's status words and the FIFO word arithmetic: no register access,
//! so all of it is unit-tested on the host.

/// The largest Ethernet frame the driver hands to or takes from the stack: 1500 bytes of payload
/// and the 14-byte header, without the 4-byte FCS (the MAC appends the FCS on TX and delivers it
/// on RX; the driver strips it).
pub const MAX_FRAME: usize = 1514;

/// Length of the Ethernet FCS (CRC-32) the RX data FIFO delivers after each frame (§3.13.3:
/// "Packet Length ... includes the 4-byte CRC").
pub const FCS_LEN: usize = 4;

/// One RX status word, popped from the RX Status FIFO (datasheet §3.13.3, "RX Status Format").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RxStatus(pub u32);

impl RxStatus {
    /// Bit 30, Filtering Fail: the frame failed the address filter (delivered only with
    /// MAC_CR.RXALL).
    pub const FILTER_FAIL: u32 = 1 << 30;
    /// Bit 15, Error Status: the OR of the error bits below.
    pub const ERROR: u32 = 1 << 15;
    /// Bit 12, Length Error.
    pub const LENGTH_ERROR: u32 = 1 << 12;
    /// Bit 11, Runt Frame (shorter than 64 bytes).
    pub const RUNT: u32 = 1 << 11;
    /// Bit 7, Frame Too Long.
    pub const TOO_LONG: u32 = 1 << 7;
    /// Bit 6, Collision Seen.
    pub const COLLISION: u32 = 1 << 6;
    /// Bit 4, Receive Watchdog time-out.
    pub const WATCHDOG: u32 = 1 << 4;
    /// Bit 3, MII Error.
    pub const MII_ERROR: u32 = 1 << 3;
    /// Bit 1, CRC Error.
    pub const CRC_ERROR: u32 = 1 << 1;

    /// Bits 29:16, Packet Length: bytes of the frame in the RX data FIFO, FCS included.
    pub fn packet_len(self) -> usize {
        ((self.0 >> 16) & 0x3FFF) as usize
    }

    /// The frame's length without the FCS, as the stack sees it.
    pub fn frame_len(self) -> usize {
        self.packet_len().saturating_sub(FCS_LEN)
    }

    /// Whether the frame is to be delivered: no error, passed the filter, not empty, and no
    /// larger than [`MAX_FRAME`].
    pub fn is_good(self) -> bool {
        let bad = Self::ERROR
            | Self::LENGTH_ERROR
            | Self::RUNT
            | Self::TOO_LONG
            | Self::COLLISION
            | Self::WATCHDOG
            | Self::MII_ERROR
            | Self::CRC_ERROR
            | Self::FILTER_FAIL;
        self.0 & bad == 0 && self.frame_len() > 0 && self.frame_len() <= MAX_FRAME
    }

    /// How many 32-bit words the frame takes in the RX data FIFO, with RX_CFG's end alignment of
    /// 4 bytes and data offset 0, as the driver sets them (§3.13.1, "RX Data FIFO Direct PIO
    /// Reads"): every word must be read (or the frame fast-forwarded) before the next frame.
    pub fn fifo_words(self) -> usize {
        words(self.packet_len())
    }
}

/// One TX status word, popped from the TX Status FIFO (datasheet §3.12.6, "TX Status Format").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TxStatus(pub u32);

impl TxStatus {
    /// Bit 15, Error Status: the OR of bits 11, 10, 9, 8, 2 and 1.
    pub const ERROR: u32 = 1 << 15;

    /// Bits 31:16, Packet TAG: the tag written in TX command B of the frame.
    pub fn tag(self) -> u16 {
        (self.0 >> 16) as u16
    }

    /// Whether the frame was sent without error.
    pub fn is_ok(self) -> bool {
        self.0 & Self::ERROR == 0
    }
}

/// TX command A, the first word of a buffer written to the TX data FIFO (§3.12.2, "TX Command
/// A"): one buffer holding the whole frame (First and Last Segment), 4-byte end alignment, data
/// offset 0, no interrupt on completion.
pub fn tx_command_a(len: usize) -> u32 {
    const LAST_SEGMENT: u32 = 1 << 12;
    const FIRST_SEGMENT: u32 = 1 << 13;
    FIRST_SEGMENT | LAST_SEGMENT | (len as u32 & 0x7FF)
}

/// TX command B, the second word (§3.12.3, "TX Command B"): the packet tag (bits 31:16, echoed
/// in the TX status word) and the frame's length (bits 10:0). The MAC appends the FCS and pads
/// frames shorter than 64 bytes itself (bits 12-13 clear).
pub fn tx_command_b(tag: u16, len: usize) -> u32 {
    (u32::from(tag) << 16) | (len as u32 & 0x7FF)
}

/// Bytes of TX data FIFO space a frame of `len` bytes needs: its data words and the two command
/// words (§3.12, "Transmit Data FIFO").
pub fn tx_fifo_bytes(len: usize) -> usize {
    4 * (words(len) + 2)
}

/// Whole 32-bit FIFO words holding `bytes` bytes (the last one padded).
pub fn words(bytes: usize) -> usize {
    bytes.div_ceil(4)
}

/// RX_FIFO_INF bits 23:16, RXSUSED: RX status words waiting (§5.3.11).
pub fn rx_status_used(rx_fifo_inf: u32) -> u32 {
    (rx_fifo_inf >> 16) & 0xFF
}

/// TX_FIFO_INF bits 23:16, TXSUSED: TX status words waiting (§5.3.12).
pub fn tx_status_used(tx_fifo_inf: u32) -> u32 {
    (tx_fifo_inf >> 16) & 0xFF
}

/// TX_FIFO_INF bits 15:0, TDFREE: free bytes in the TX data FIFO (§5.3.12).
pub fn tx_data_free(tx_fifo_inf: u32) -> usize {
    (tx_fifo_inf & 0xFFFF) as usize
}

/// The MAC address as the MAC's ADDRL and ADDRH CSRs hold it (§5.4.3, §5.4.2): ADDRL has bytes
/// 0-3 (byte 0 in bits 7:0), ADDRH bytes 4-5.
pub fn mac_to_regs(mac: [u8; 6]) -> (u32, u32) {
    let [a, b, c, d, e, f] = mac;
    (
        u32::from_le_bytes([a, b, c, d]),
        u32::from_le_bytes([e, f, 0, 0]),
    )
}

/// The inverse of [`mac_to_regs`].
pub fn mac_from_regs(addrl: u32, addrh: u32) -> [u8; 6] {
    let [a, b, c, d] = addrl.to_le_bytes();
    let [e, f, _, _] = addrh.to_le_bytes();
    [a, b, c, d, e, f]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rx_status_length_and_words() {
        // A 60-byte frame (ARP, padded) with its FCS: 64 bytes, 16 words.
        let s = RxStatus(64 << 16);
        assert_eq!(s.packet_len(), 64);
        assert_eq!(s.frame_len(), 60);
        assert_eq!(s.fifo_words(), 16);
        assert!(s.is_good());
        // 61 bytes + FCS = 65: 17 words, the last one holding 1 byte.
        let s = RxStatus(65 << 16);
        assert_eq!(s.frame_len(), 61);
        assert_eq!(s.fifo_words(), 17);
    }

    #[test]
    fn rx_status_rejects_errors_and_sizes() {
        let len = 100 << 16;
        assert!(!RxStatus(len | RxStatus::ERROR | RxStatus::CRC_ERROR).is_good());
        assert!(!RxStatus(len | RxStatus::FILTER_FAIL).is_good());
        assert!(!RxStatus(len | RxStatus::RUNT).is_good());
        // Only the FCS: nothing to deliver.
        assert!(!RxStatus(4 << 16).is_good());
        assert!(!RxStatus(0).is_good());
        // The largest frame is accepted, one more byte is not.
        assert!(RxStatus(((MAX_FRAME + 4) as u32) << 16).is_good());
        assert!(!RxStatus(((MAX_FRAME + 5) as u32) << 16).is_good());
        // Broadcast and multicast flags are not errors.
        assert!(RxStatus(len | (1 << 13) | (1 << 10)).is_good());
    }

    #[test]
    fn rx_status_length_field_is_14_bits() {
        // Bit 30 (filter fail) and bit 31 do not leak into the length.
        assert_eq!(RxStatus(0xC000_0000 | (80 << 16)).packet_len(), 80);
        assert_eq!(RxStatus(0x3FFF_0000).packet_len(), 0x3FFF);
    }

    #[test]
    fn tx_status() {
        let s = TxStatus(0xBEEF_0000);
        assert_eq!(s.tag(), 0xBEEF);
        assert!(s.is_ok());
        assert!(!TxStatus(0x0001_8000).is_ok());
    }

    #[test]
    fn tx_commands() {
        assert_eq!(tx_command_a(60), 0x0000_303C);
        assert_eq!(tx_command_a(1514), 0x3000 | 1514);
        assert_eq!(tx_command_b(7, 1514), (7 << 16) | 1514);
        // Two command words and the data rounded up to words.
        assert_eq!(tx_fifo_bytes(60), 68);
        assert_eq!(tx_fifo_bytes(61), 72);
        assert_eq!(tx_fifo_bytes(MAX_FRAME), 4 * 379 + 8);
    }

    #[test]
    fn fifo_info_fields() {
        assert_eq!(rx_status_used(0x0003_0100), 3);
        assert_eq!(tx_status_used(0x00FF_1200), 0xFF);
        assert_eq!(tx_data_free(0x0001_1200), 0x1200);
    }

    #[test]
    fn mac_round_trip() {
        let mac = [0x52, 0x54, 0x00, 0x12, 0x34, 0x56];
        let (l, h) = mac_to_regs(mac);
        assert_eq!(l, 0x1200_5452);
        assert_eq!(h, 0x5634);
        assert_eq!(mac_from_regs(l, h), mac);
    }
}
