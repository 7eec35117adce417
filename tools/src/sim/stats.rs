//! What the bus has counted (per-controller counts are in
//! [`ControllerStats`](super::controller::ControllerStats)).

/// Bus-wide counters. Every fault the simulator injects is counted here.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BusStats {
    /// Transmissions started by the host (frames or any other byte runs).
    pub host_transmissions: u64,
    /// Bytes the host sent.
    pub host_bytes_sent: u64,
    /// Breaks the host sent.
    pub breaks: u64,
    /// Bytes delivered to the host.
    pub bytes_to_host: u64,
    /// Bytes the host received at a baud rate other than its own (delivered as garbage).
    pub host_wrong_baud_bytes: u64,
    /// Replies controllers put on the line.
    pub replies_sent: u64,
    /// Replies dropped by fault injection.
    pub replies_dropped: u64,
    /// Replies delayed by fault injection.
    pub replies_delayed: u64,
    /// Replies suppressed because the axis is silent.
    pub replies_silenced: u64,
    /// Prepared replies lost to a break or a power loss.
    pub replies_cancelled: u64,
    /// Host bytes corrupted by fault injection.
    pub host_bytes_corrupted: u64,
    /// Host transmissions with at least one corrupted byte.
    pub host_frames_corrupted: u64,
    /// Reply bytes corrupted by fault injection.
    pub reply_bytes_corrupted: u64,
    /// Replies with at least one corrupted byte.
    pub replies_corrupted: u64,
    /// Pairs of overlapping transmissions (host, controllers, noise, break).
    pub collisions: u64,
    /// Bytes garbled by a collision.
    pub collided_bytes: u64,
    /// Noise bursts injected.
    pub noise_bursts: u64,
    /// Noise bytes injected.
    pub noise_bytes: u64,
    /// Power cycles (power losses) injected.
    pub power_cycles: u64,
}
