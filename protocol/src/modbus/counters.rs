//! What the slave counts: [`SlaveCounters`], shared by the [`Slave`](super::Slave) that counts
//! and by FC08 Diagnostics ([`diag`](super::diag)), which reports the counts since its last
//! clear. A leaf: it depends on no other module here but the [`Exception`] it counts by.

use super::Exception;

/// What the slave has counted (wrapping counters).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SlaveCounters {
    /// Frames with a good CRC handed to [`Slave::handle`](super::Slave::handle), for any unit.
    pub frames: u32,
    /// Bursts with a bad CRC seen by [`Slave::poll`](super::Slave::poll).
    pub crc_errors: u32,
    /// Bursts of fewer than 4 bytes seen by [`Slave::poll`](super::Slave::poll).
    pub too_short: u32,
    /// Bursts longer than 256 bytes seen by [`Slave::poll`](super::Slave::poll).
    pub too_long: u32,
    /// Bursts broken by a t1.5 gap seen by [`Slave::poll`](super::Slave::poll).
    pub bad_gaps: u32,
    /// Frames for other units, and broadcasts that are not writes. Every frame is ignored,
    /// answered ([`replies`](Self::replies)) or [`unanswered`](Self::unanswered).
    pub ignored: u32,
    /// Broadcast writes (applied or refused).
    pub broadcasts: u32,
    /// Broadcast writes refused (invalid, or the model returned an exception).
    pub broadcast_errors: u32,
    /// Exception 01 replies.
    pub illegal_function: u32,
    /// Exception 02 replies.
    pub illegal_data_address: u32,
    /// Exception 03 replies.
    pub illegal_data_value: u32,
    /// Exception 04 replies.
    pub server_device_failure: u32,
    /// Exception 0A replies (TCP: a unit nobody serves).
    pub gateway_path_unavailable: u32,
    /// Replies produced, normal and exception.
    pub replies: u32,
    /// PDUs that are not requests (to a served unit or broadcast).
    pub malformed: u32,
    /// Frames to a unit served, or broadcast (FC08's server message count).
    pub served: u32,
    /// Of those, frames not answered: broadcasts, malformed, Listen Only (FC08's server no
    /// response count).
    pub unanswered: u32,
}

impl SlaveCounters {
    pub(super) const ZERO: SlaveCounters = SlaveCounters {
        frames: 0,
        crc_errors: 0,
        too_short: 0,
        too_long: 0,
        bad_gaps: 0,
        ignored: 0,
        broadcasts: 0,
        broadcast_errors: 0,
        illegal_function: 0,
        illegal_data_address: 0,
        illegal_data_value: 0,
        server_device_failure: 0,
        gateway_path_unavailable: 0,
        replies: 0,
        malformed: 0,
        served: 0,
        unanswered: 0,
    };

    /// Both sets of counts added up (the PLC link's counters over RTU and TCP together).
    #[must_use]
    pub fn plus(&self, other: &SlaveCounters) -> SlaveCounters {
        let add = |a: u32, b: u32| a.wrapping_add(b);
        SlaveCounters {
            frames: add(self.frames, other.frames),
            crc_errors: add(self.crc_errors, other.crc_errors),
            too_short: add(self.too_short, other.too_short),
            too_long: add(self.too_long, other.too_long),
            bad_gaps: add(self.bad_gaps, other.bad_gaps),
            ignored: add(self.ignored, other.ignored),
            broadcasts: add(self.broadcasts, other.broadcasts),
            broadcast_errors: add(self.broadcast_errors, other.broadcast_errors),
            illegal_function: add(self.illegal_function, other.illegal_function),
            illegal_data_address: add(self.illegal_data_address, other.illegal_data_address),
            illegal_data_value: add(self.illegal_data_value, other.illegal_data_value),
            server_device_failure: add(self.server_device_failure, other.server_device_failure),
            gateway_path_unavailable: add(
                self.gateway_path_unavailable,
                other.gateway_path_unavailable,
            ),
            replies: add(self.replies, other.replies),
            malformed: add(self.malformed, other.malformed),
            served: add(self.served, other.served),
            unanswered: add(self.unanswered, other.unanswered),
        }
    }

    /// The number of replies with `exception`.
    pub fn exceptions(&self, exception: Exception) -> u32 {
        match exception {
            Exception::IllegalFunction => self.illegal_function,
            Exception::IllegalDataAddress => self.illegal_data_address,
            Exception::IllegalDataValue => self.illegal_data_value,
            Exception::ServerDeviceFailure => self.server_device_failure,
            Exception::GatewayPathUnavailable => self.gateway_path_unavailable,
        }
    }

    /// The counter of replies with `exception`, to count one more.
    pub(super) fn exception_counter(&mut self, exception: Exception) -> &mut u32 {
        match exception {
            Exception::IllegalFunction => &mut self.illegal_function,
            Exception::IllegalDataAddress => &mut self.illegal_data_address,
            Exception::IllegalDataValue => &mut self.illegal_data_value,
            Exception::ServerDeviceFailure => &mut self.server_device_failure,
            Exception::GatewayPathUnavailable => &mut self.gateway_path_unavailable,
        }
    }
}
