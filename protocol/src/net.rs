//! The network settings: the Ethernet board's address and the Modbus TCP server's policy (who
//! may connect, how many at once, for how long). Plain data, stored with the other settings on
//! every board; only boards with Ethernet (and the PC gateway) use them, through feature `tcp`.

use crate::time::Duration;

/// An IPv4 address.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Ipv4(pub [u8; 4]);

impl Ipv4 {
    /// 0.0.0.0: no address (an empty allow-list slot, no default router).
    pub const UNSPECIFIED: Ipv4 = Ipv4([0; 4]);

    /// The address as two registers, high byte first: `a.b`, `c.d`.
    pub const fn to_registers(self) -> [u16; 2] {
        let [a, b, c, d] = self.0;
        [(a as u16) << 8 | b as u16, (c as u16) << 8 | d as u16]
    }

    /// The address of two registers, high byte first.
    pub const fn from_registers(high: u16, low: u16) -> Ipv4 {
        let [a, b] = high.to_be_bytes();
        let [c, d] = low.to_be_bytes();
        Ipv4([a, b, c, d])
    }

    /// Whether a host may have this address: not 0.0.0.0, not multicast or reserved
    /// (224.0.0.0 and above), not loopback.
    pub const fn is_host(self) -> bool {
        let first = self.0[0];
        first != 0 && first != 127 && first < 224
    }
}

impl core::fmt::Display for Ipv4 {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let [a, b, c, d] = self.0;
        write!(f, "{a}.{b}.{c}.{d}")
    }
}

/// The most Modbus TCP connections served at once.
pub const MAX_CONNECTIONS: u8 = 4;

/// The longest idle time a connection may be given, s.
pub const MAX_IDLE_S: u16 = 3_600;

/// Who may connect, how many at once, and for how long without a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Policy {
    /// The clients allowed; [`Ipv4::UNSPECIFIED`] slots are empty, and all empty allows anyone.
    pub allow: [Ipv4; 4],
    /// Connections at once, 1 to [`MAX_CONNECTIONS`].
    pub max_connections: u8,
    /// A connection silent this many seconds is closed; 0 never closes one.
    pub idle_s: u16,
}

impl Policy {
    /// Anyone, [`MAX_CONNECTIONS`] at once, closed after 60 s without a request.
    pub const DEFAULT: Policy = Policy {
        allow: [Ipv4::UNSPECIFIED; 4],
        max_connections: MAX_CONNECTIONS,
        idle_s: 60,
    };

    /// Whether `peer` may connect.
    pub fn allows(&self, peer: Ipv4) -> bool {
        let listed = || self.allow.iter().filter(|&&a| a != Ipv4::UNSPECIFIED);
        listed().next().is_none() || listed().any(|&a| a == peer)
    }

    /// The idle time; zero: never.
    pub const fn idle(&self) -> Duration {
        Duration::from_secs(self.idle_s as u64)
    }
}

/// Whether `n` is a connection limit: 1 to [`MAX_CONNECTIONS`].
pub const fn max_connections_ok(n: u16) -> bool {
    n >= 1 && n <= MAX_CONNECTIONS as u16
}

/// Whether `s` is an idle time: 0 (never) to [`MAX_IDLE_S`].
pub const fn idle_ok(s: u16) -> bool {
    s <= MAX_IDLE_S
}

/// Whether `prefix` is a subnet prefix length: 1 to 32.
pub const fn prefix_ok(prefix: u16) -> bool {
    prefix >= 1 && prefix <= 32
}

/// The Ethernet board's address and the TCP server's policy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NetConfig {
    /// The board's address.
    pub ip: Ipv4,
    /// The subnet's prefix length (24: 255.255.255.0).
    pub prefix: u8,
    /// The default router; [`Ipv4::UNSPECIFIED`]: none (the PLC is on the same subnet).
    pub router: Ipv4,
    /// Who may connect.
    pub policy: Policy,
}

impl NetConfig {
    /// 192.168.1.100/24, no router, anyone, four connections, 60 s idle.
    pub const DEFAULT: NetConfig = NetConfig {
        ip: Ipv4([192, 168, 1, 100]),
        prefix: 24,
        router: Ipv4::UNSPECIFIED,
        policy: Policy::DEFAULT,
    };
}

/// The registers of [`NetConfig`] in the gateway unit's network block, by offset: IPADDR (2),
/// IPPREFIX, IPROUTER (2), TCPMAX, TCPIDLE, then (offset [`CONNECTIONS`](registers::CONNECTIONS), read-only, not a
/// setting) TCPCONN, then TCPALLOW (4 x 2). Addresses are two registers, high byte first.
pub mod registers {
    /// IPADDR, two registers.
    pub const IP: u16 = 0;
    /// IPPREFIX.
    pub const PREFIX: u16 = 2;
    /// IPROUTER, two registers.
    pub const ROUTER: u16 = 3;
    /// TCPMAX.
    pub const MAX_CONNECTIONS: u16 = 5;
    /// TCPIDLE, s.
    pub const IDLE: u16 = 6;
    /// TCPCONN: connections open now (read-only).
    pub const CONNECTIONS: u16 = 7;
    /// TCPALLOW: four addresses, two registers each.
    pub const ALLOW: u16 = 8;
    /// Registers of the block.
    pub const LEN: u16 = 16;
}

impl NetConfig {
    /// The address (its two registers) at `offset`, if an address register is there.
    fn address_mut(&mut self, offset: u16) -> Option<(&mut Ipv4, usize)> {
        use registers::*;
        let (address, at) = match offset {
            IP..=1 => (&mut self.ip, offset - IP),
            ROUTER..=4 => (&mut self.router, offset - ROUTER),
            ALLOW..=15 => {
                let n = usize::from((offset - ALLOW) / 2);
                (self.policy.allow.get_mut(n)?, (offset - ALLOW) % 2)
            }
            _ => return None,
        };
        Some((address, usize::from(at)))
    }

    /// The register at `offset` of the block (TCPCONN aside, which is not a setting).
    pub fn register(&self, offset: u16) -> Option<u16> {
        use registers::*;
        match offset {
            PREFIX => Some(u16::from(self.prefix)),
            MAX_CONNECTIONS => Some(u16::from(self.policy.max_connections)),
            IDLE => Some(self.policy.idle_s),
            _ => {
                let mut copy = *self;
                let (address, at) = copy.address_mut(offset)?;
                address.to_registers().get(at).copied()
            }
        }
    }

    /// Writes the register at `offset`: whether the value is one it takes (else nothing
    /// changes). Any address is taken here; the board falls back to the default address at
    /// its start if the stored one is not a host's ([`Ipv4::is_host`]).
    pub fn set_register(&mut self, offset: u16, value: u16) -> bool {
        NetSetting::parse(offset, value)
            .map(|setting| self.set(setting))
            .is_some()
    }

    /// Sets `setting`.
    pub fn set(&mut self, setting: NetSetting) {
        match setting {
            NetSetting::Prefix(prefix) => self.prefix = prefix,
            NetSetting::MaxConnections(n) => self.policy.max_connections = n,
            NetSetting::Idle(s) => self.policy.idle_s = s,
            NetSetting::AddressWord(offset, value) => {
                let Some((address, at)) = self.address_mut(offset) else {
                    return;
                };
                let mut words = address.to_registers();
                if let Some(word) = words.get_mut(at) {
                    *word = value;
                }
                let [high, low] = words;
                *address = Ipv4::from_registers(high, low);
            }
        }
    }
}

/// One register of the network block (IPADDR to TCPALLOW), checked: what a write of it sets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NetSetting {
    /// IPPREFIX: 1 to 32.
    Prefix(u8),
    /// TCPMAX: 1 to [`MAX_CONNECTIONS`].
    MaxConnections(u8),
    /// TCPIDLE, s: 0 (never) to [`MAX_IDLE_S`].
    Idle(u16),
    /// One word of an address (IPADDR, IPROUTER, a TCPALLOW slot), by the register's offset:
    /// any value (the board falls back to its default address at its start if the stored one
    /// is not a host's).
    AddressWord(u16, u16),
}

impl NetSetting {
    /// `value` at `offset` of the network block, if that register is a setting and takes it.
    pub fn parse(offset: u16, value: u16) -> Option<NetSetting> {
        use registers::*;
        match offset {
            PREFIX => prefix_ok(value).then_some(NetSetting::Prefix(value as u8)),
            MAX_CONNECTIONS => {
                max_connections_ok(value).then_some(NetSetting::MaxConnections(value as u8))
            }
            IDLE => idle_ok(value).then_some(NetSetting::Idle(value)),
            IP..=1 | ROUTER..=4 | ALLOW..=15 => Some(NetSetting::AddressWord(offset, value)),
            _ => None,
        }
    }
}
