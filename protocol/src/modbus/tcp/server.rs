//! The Modbus TCP server's connections: who may connect, how many at once, for how long, and
//! in which order their requests are served.
//!
//! The caller owns the sockets ([`SOCKETS`] of them, each named by a [`SocketHandle`]) and tells
//! the server what happens on them; the server says which to close. Everything known about a
//! connection is here, in one place: its client, when it last sent, its stream, whether its
//! socket can take a reply, whether the client has sent its FIN; the caller keeps only its bytes
//! in flight. One socket more than the most connections
//! allowed lets a new client in when every slot is taken: the connection idle the longest is
//! closed for it (TCP Guide §4.2.1.2, "connection management": a server keeps a pool and
//! reuses its oldest connection rather than refusing a new one).
//!
//! - A client not on a non-empty allow-list is refused: the socket is closed at once and
//!   counted; its bytes never reach the register map.
//! - A connection that sends nothing for the idle time is closed (a half-open connection, whose
//!   client vanished without a FIN, would otherwise hold its slot for good).
//! - Requests are served one at a time, round robin over the connections: a client that
//!   pipelines many requests gets one answered per turn, and a slow client's partial frame waits
//!   in its own [`Stream`] without holding anyone else up.

use super::mbap::{MbapError, Stream, TcpAdu};
use crate::net::{Ipv4, Policy};
use crate::time::{Duration, Instant};

/// The most connections served at once.
pub const MAX_CONNECTIONS: usize = crate::net::MAX_CONNECTIONS as usize;

/// Sockets the caller provides: one more than [`MAX_CONNECTIONS`], so that a new client can
/// still connect (and replace the connection idle the longest) when every slot is taken.
pub const SOCKETS: usize = MAX_CONNECTIONS + 1;

/// One of the caller's [`SOCKETS`] sockets. Only [`SocketHandle::new`] and
/// [`SocketHandle::all`] make one, so its index is always in range.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SocketHandle(u8);

impl SocketHandle {
    /// Socket `index`, if it is one of the [`SOCKETS`].
    pub const fn new(index: usize) -> Option<SocketHandle> {
        if index < SOCKETS {
            Some(SocketHandle(index as u8))
        } else {
            None
        }
    }

    /// Every socket, the first one first.
    pub fn all() -> impl Iterator<Item = SocketHandle> {
        (0..SOCKETS as u8).map(SocketHandle)
    }

    /// Its index, 0 to [`SOCKETS`] - 1 (for the caller's own tables).
    pub const fn index(self) -> usize {
        self.0 as usize
    }

    /// Its bit in a set of sockets.
    const fn bit(self) -> u8 {
        1 << self.0
    }
}

impl core::fmt::Display for SocketHandle {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// What the server has counted (wrapping counters).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TcpCounters {
    /// Connections admitted.
    pub accepted: u32,
    /// Connections refused: the client is not on the allow-list.
    pub refused: u32,
    /// Connections closed to make room for a new one (every slot taken), or because the limit
    /// was lowered.
    pub replaced: u32,
    /// Connections closed after the idle time without a request.
    pub idle_closed: u32,
    /// Frames with a protocol id other than 0 (skipped) or a length out of range (the
    /// connection closed).
    pub mbap_errors: u32,
    /// Whole frames taken to be answered.
    pub frames: u32,
}

/// One connection.
#[derive(Clone, Debug)]
struct Connection {
    peer: Ipv4,
    /// When it was opened or last sent a byte.
    last: Instant,
    /// Its place in the order of opening ([`Server::opened`] when it opened): of connections
    /// idle as long (a burst of connects at one instant), the one opened first goes first.
    order: u32,
    stream: Stream,
    /// Whether the socket can take a whole reply now ([`Server::set_writable`]).
    writable: bool,
    /// The client has closed its side (TCP FIN): what it sent before is still answered, then
    /// the connection ends ([`Server::finish`]).
    eof: bool,
}

/// The connection table; see the [module documentation](self).
#[derive(Clone, Debug)]
pub struct Server {
    connections: [Option<Connection>; SOCKETS],
    /// Sockets to close (bit n = socket n), not handed out yet: their connections are
    /// forgotten already.
    close: u8,
    /// Where the next round of [`next_frame`](Server::next_frame) starts.
    turn: usize,
    /// Connections opened so far (wrapping): the next one's [`Connection::order`].
    opened: u32,
    counters: TcpCounters,
}

impl Default for Server {
    fn default() -> Self {
        Server::new()
    }
}

/// Adds one to a wrapping counter.
fn bump(counter: &mut u32) {
    *counter = counter.wrapping_add(1);
}

impl Server {
    /// No connections.
    pub const fn new() -> Server {
        const NONE: Option<Connection> = None;
        Server {
            connections: [NONE; SOCKETS],
            close: 0,
            turn: 0,
            opened: 0,
            counters: TcpCounters {
                accepted: 0,
                refused: 0,
                replaced: 0,
                idle_closed: 0,
                mbap_errors: 0,
                frames: 0,
            },
        }
    }

    /// A client at `peer` connected on `socket` at `now`: whether it is admitted. A refused
    /// one is counted, and the caller closes the socket at once. When every slot is taken, the
    /// connection idle the longest is to be closed ([`take_close`](Server::take_close)).
    pub fn open(
        &mut self,
        now: Instant,
        socket: SocketHandle,
        peer: Ipv4,
        policy: &Policy,
    ) -> bool {
        self.closed(socket);
        if !policy.allows(peer) {
            bump(&mut self.counters.refused);
            return false;
        }
        if let Some(slot) = self.connections.get_mut(socket.index()) {
            *slot = Some(Connection {
                peer,
                last: now,
                order: self.opened,
                stream: Stream::new(),
                writable: true,
                eof: false,
            });
        }
        self.opened = self.opened.wrapping_add(1);
        bump(&mut self.counters.accepted);
        self.trim(policy);
        true
    }

    /// Marks connections beyond the limit for closing, the ones idle the longest first and, of
    /// those idle as long, the one opened first. The newest connection is never the one chosen:
    /// it has just been admitted, and is idle no longer than any other (a burst of connects at
    /// one instant once closed each newcomer instead, the lowest socket winning the tie).
    fn trim(&mut self, policy: &Policy) {
        let limit = usize::from(policy.max_connections.clamp(1, MAX_CONNECTIONS as u8));
        while self.open_count() > limit {
            let next = self.opened;
            // How many connections opened after it (wrapping): the larger, the older.
            let age = |c: &Connection| next.wrapping_sub(c.order);
            let oldest = self
                .open_sockets()
                .min_by_key(|&(_, c)| (c.last, core::cmp::Reverse(age(c))))
                .map(|(socket, _)| socket);
            let Some(socket) = oldest else { return };
            self.drop_connection(socket);
            self.close |= socket.bit();
            bump(&mut self.counters.replaced);
        }
    }

    /// The open connections and their sockets.
    fn open_sockets(&self) -> impl Iterator<Item = (SocketHandle, &Connection)> {
        SocketHandle::all()
            .zip(self.connections.iter())
            .filter_map(|(socket, c)| c.as_ref().map(|c| (socket, c)))
    }

    /// The connection on `socket`, if one is open.
    fn connection(&self, socket: SocketHandle) -> Option<&Connection> {
        self.connections
            .get(socket.index())
            .and_then(Option::as_ref)
    }

    /// The connection on `socket`, if one is open, to change.
    fn connection_mut(&mut self, socket: SocketHandle) -> Option<&mut Connection> {
        self.connections
            .get_mut(socket.index())
            .and_then(Option::as_mut)
    }

    /// How many connections are open.
    fn open_count(&self) -> usize {
        self.open_sockets().count()
    }

    /// Forgets the connection on `socket`.
    fn drop_connection(&mut self, socket: SocketHandle) {
        if let Some(slot) = self.connections.get_mut(socket.index()) {
            *slot = None;
        }
    }

    /// Bytes from the client on `socket` at `now`: how many were taken (at most what one frame
    /// needs; the caller keeps the rest and offers it again after the next request has been
    /// answered). Bytes for a socket with no connection are taken and dropped.
    pub fn received(&mut self, now: Instant, socket: SocketHandle, bytes: &[u8]) -> usize {
        let Some(connection) = self.connection_mut(socket) else {
            return bytes.len();
        };
        let taken = connection.stream.push(bytes);
        if taken > 0 {
            connection.last = now;
        }
        taken
    }

    /// The connection on `socket` has ended (the client closed it, it broke, or the caller
    /// closed it as asked).
    pub fn closed(&mut self, socket: SocketHandle) {
        self.drop_connection(socket);
        self.close &= !socket.bit();
    }

    /// The client on `socket` has closed its side (TCP FIN): its requests still waiting are
    /// answered, then [`finish`](Server::finish) ends the connection.
    pub fn eof(&mut self, socket: SocketHandle) {
        if let Some(connection) = self.connection_mut(socket) {
            connection.eof = true;
        }
    }

    /// Whether the connection on `socket` is done: its client has sent its FIN and no whole
    /// request of it waits (a fragment never completes now). A done connection is forgotten
    /// (no longer counted), and the caller ends it once its replies have left. The caller asks
    /// only when it holds none of the client's bytes either.
    pub fn finish(&mut self, socket: SocketHandle) -> bool {
        let done = self
            .connection(socket)
            .is_some_and(|c| c.eof && !c.stream.is_ready());
        if done {
            self.drop_connection(socket);
        }
        done
    }

    /// Whether `socket`'s send side has room for a whole reply: while it has not, its requests
    /// wait (a client slow to read its replies gets no more of them until it does; the others'
    /// are answered meanwhile). Every socket is writable when its connection opens.
    pub fn set_writable(&mut self, socket: SocketHandle, writable: bool) {
        if let Some(connection) = self.connection_mut(socket) {
            connection.writable = writable;
        }
    }

    /// Whether a connection is open on `socket`.
    pub fn is_open(&self, socket: SocketHandle) -> bool {
        self.connection(socket).is_some()
    }

    /// The next whole request and its socket, taking turns between the connections; frames that
    /// are not requests are counted and dropped on the way (a length out of range also closes
    /// its connection).
    pub fn next_frame(&mut self) -> Option<(SocketHandle, TcpAdu<'_>)> {
        let socket = self.ready_socket()?;
        self.turn = (socket.index() + 1) % SOCKETS;
        bump(&mut self.counters.frames);
        let connection = self.connection_mut(socket)?;
        match connection.stream.take()? {
            Ok(adu) => Some((socket, adu)),
            Err(_) => None,
        }
    }

    /// The first socket from this turn's start with a valid frame in front.
    fn ready_socket(&mut self) -> Option<SocketHandle> {
        for k in 0..SOCKETS {
            let Some(socket) = SocketHandle::new((self.turn + k) % SOCKETS) else {
                continue;
            };
            while let Some(connection) = self.connection_mut(socket).filter(|c| c.writable) {
                match connection.stream.peek() {
                    None => break,
                    Some(Ok(_)) => return Some(socket),
                    Some(Err(error)) => {
                        let _ = connection.stream.take();
                        bump(&mut self.counters.mbap_errors);
                        if error == MbapError::Length {
                            self.drop_connection(socket);
                            self.close |= socket.bit();
                        }
                    }
                }
            }
        }
        None
    }

    /// A socket to close now, if any: one asked for (a replaced connection, a bad length), one
    /// beyond a lowered limit, one idle for the policy's idle time at `now`. Call until `None`.
    /// (An allow-list change admits or refuses new clients only: a PLC that rewrites the list
    /// over TCP, an address in two registers, is not cut off halfway.)
    pub fn take_close(&mut self, now: Instant, policy: &Policy) -> Option<SocketHandle> {
        self.trim(policy);
        if let Some(socket) = SocketHandle::new(self.close.trailing_zeros() as usize) {
            self.close &= !socket.bit();
            return Some(socket);
        }
        let idle = self
            .open_sockets()
            .find(|(_, c)| policy.idle() != Duration::ZERO && now.since(c.last) >= policy.idle())
            .map(|(socket, _)| socket);
        let socket = idle?;
        self.drop_connection(socket);
        bump(&mut self.counters.idle_closed);
        Some(socket)
    }

    /// When something is due: [`Instant::ZERO`] (now) while a frame waits or a socket is to be
    /// closed, else the earliest idle time-out; `None`: nothing until bytes arrive.
    pub fn poll_at(&self, policy: &Policy) -> Option<Instant> {
        let ready = |(_, c): (SocketHandle, &Connection)| c.writable && c.stream.is_ready();
        if self.close != 0 || self.open_sockets().any(ready) {
            return Some(Instant::ZERO);
        }
        if policy.idle() == Duration::ZERO {
            return None;
        }
        self.open_sockets()
            .map(|(_, c)| c.last + policy.idle())
            .min()
    }

    /// Whether `socket` has room for more bytes ([`received`](Server::received) would take
    /// some): the caller reads the socket only then.
    pub fn room(&self, socket: SocketHandle) -> usize {
        self.connection(socket).map_or(0, |c| c.stream.room())
    }

    /// The connections open now.
    pub fn connections(&self) -> u8 {
        u8::try_from(self.open_count()).unwrap_or(u8::MAX)
    }

    /// The client on `socket`, if a connection is open there.
    pub fn peer(&self, socket: SocketHandle) -> Option<Ipv4> {
        self.connection(socket).map(|c| c.peer)
    }

    /// What has been counted.
    pub fn counters(&self) -> TcpCounters {
        self.counters
    }
}
