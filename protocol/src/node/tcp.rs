//! The node's Modbus TCP side (feature `tcp`): the sockets the caller owns, the connections'
//! state (its [`Server`](crate::modbus::tcp::Server)'s alone) and the reply being sent.

use super::*;

/// What the caller does on a Modbus TCP socket (feature `tcp`). It holds no borrow of the node,
/// so the caller can hand the node on while it carries it out.
#[cfg(feature = "tcp")]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TcpAction {
    /// Send the reply [`Node::tcp_reply`] holds (MBAP header included) on this socket, the one
    /// the request came on. Never wait for the client to take it: if the socket's send buffer
    /// has no room for it, the client is not reading, so close the socket (and report it with
    /// [`Node::tcp_closed`]).
    Reply(SocketHandle),
    /// Close this socket: a refused, replaced or idle client, or a stream that lost its
    /// framing. Report it with [`Node::tcp_closed`] once done.
    Close(SocketHandle),
}

/// The Modbus TCP side of the node: the connections, a slave of its own (its counters and
/// state are not the serial line's), and the reply being sent.
#[cfg(feature = "tcp")]
#[derive(Debug)]
pub(super) struct TcpPort {
    pub(super) server: crate::modbus::tcp::Server,
    pub(super) slave: Slave,
    pub(super) reply: ReplyBuffer,
}

/// The Modbus TCP side (feature `tcp`): the caller owns [`SOCKETS`](crate::modbus::tcp::SOCKETS)
/// sockets listening on one port (502), each named by a [`SocketHandle`], and reports what
/// happens on them; the node answers through [`TcpAction::Reply`] and closes through
/// [`TcpAction::Close`]. Each connection's state is the node's alone (its TCP server's). The
/// same register map, units and exceptions as the serial line
/// ([`crate::modbus::tcp`] says what differs); any request to a unit served, from any
/// connection, is PLC activity for the watchdog.
#[cfg(feature = "tcp")]
impl Node {
    /// A client at `peer` connected on `socket` at `now`: whether it is admitted (not on a
    /// non-empty allow-list: close the socket at once, without reporting it closed). When
    /// every slot is taken, the connection idle the longest is closed for it
    /// ([`TcpAction::Close`]).
    pub fn tcp_opened(
        &mut self,
        now: Instant,
        socket: SocketHandle,
        peer: crate::net::Ipv4,
    ) -> bool {
        let policy = self.gateway.config().settings.net.policy;
        self.dirty = true;
        self.tcp.server.open(now, socket, peer, &policy)
    }

    /// Bytes from the client on `socket` at `now`: how many were taken. Offer the rest again
    /// once [`tcp_room`](Node::tcp_room) says there is room (after the request in front has
    /// been answered), and read the socket only then: TCP's window holds the client back
    /// meanwhile, as it should.
    pub fn tcp_received(&mut self, now: Instant, socket: SocketHandle, bytes: &[u8]) -> usize {
        let taken = self.tcp.server.received(now, socket, bytes);
        if taken > 0 {
            self.dirty = true;
        }
        taken
    }

    /// How many bytes [`tcp_received`](Node::tcp_received) would take on `socket` now (0: no
    /// connection there, or a whole request waits to be answered).
    pub fn tcp_room(&self, socket: SocketHandle) -> usize {
        self.tcp.server.room(socket)
    }

    /// The connection on `socket` has ended: the client closed it, it broke, or the caller
    /// closed it (asked by [`TcpAction::Close`], or a reply that did not fit).
    pub fn tcp_closed(&mut self, socket: SocketHandle) {
        self.tcp.server.closed(socket);
    }

    /// The client on `socket` has closed its side (TCP FIN): what it sent before is still
    /// answered; [`tcp_finish`](Node::tcp_finish) says when the connection is done.
    pub fn tcp_eof(&mut self, socket: SocketHandle) {
        self.tcp.server.eof(socket);
    }

    /// Whether the connection on `socket` is done: past its client's FIN, with no whole request
    /// left to answer. A done connection is no longer counted (TCPCONN); end it gracefully once
    /// its replies have left. Ask only while none of the client's bytes wait with the caller.
    pub fn tcp_finish(&mut self, socket: SocketHandle) -> bool {
        self.tcp.server.finish(socket)
    }

    /// Whether `socket` can take a whole reply now (the caller's send buffer for it has room
    /// for [`MAX_TCP_ADU_LEN`](crate::modbus::tcp::MAX_TCP_ADU_LEN) bytes): while it cannot, the
    /// node answers none of its requests (the others' are answered meanwhile), so a client slow
    /// to read its replies is held back, not cut off; the idle time still closes one that
    /// never reads. Every socket is writable when its connection opens.
    pub fn tcp_writable(&mut self, socket: SocketHandle, writable: bool) {
        self.tcp.server.set_writable(socket, writable);
        if writable {
            self.dirty = true;
        }
    }

    /// Whether a connection is open on `socket` (the caller drops bytes for one that is not).
    pub fn tcp_connected(&self, socket: SocketHandle) -> bool {
        self.tcp.server.is_open(socket)
    }

    /// The reply of the last [`TcpAction::Reply`], MBAP header included: read it where it is,
    /// before the next [`poll`](Node::poll).
    pub fn tcp_reply(&self) -> &[u8] {
        self.tcp.reply.as_bytes()
    }

    /// What the TCP server has counted.
    pub fn tcp_counters(&self) -> crate::modbus::tcp::TcpCounters {
        self.tcp.server.counters()
    }

    /// What the Modbus slave of the TCP side has counted.
    pub fn tcp_slave_counters(&self) -> SlaveCounters {
        self.tcp.slave.counters()
    }

    /// The connections open now.
    pub fn tcp_connections(&self) -> u8 {
        self.tcp.server.connections()
    }

    /// A socket to close, or the next request answered (taking turns between connections).
    pub(super) fn poll_tcp(&mut self, now: Instant) -> Option<TcpAction> {
        let policy = self.gateway.config().settings.net.policy;
        if let Some(socket) = self.tcp.server.take_close(now, &policy) {
            return Some(TcpAction::Close(socket));
        }
        let link = self.link_counters();
        let view = crate::plc::TcpView {
            counters: self.tcp.server.counters(),
            connections: self.tcp.server.connections(),
        };
        let direct_unit = self.gateway.config().settings.unit.get();
        loop {
            let (socket, adu) = self.tcp.server.next_frame()?;
            let mut model = self.gateway.registers(now, link).with_tcp(view);
            let handled =
                self.tcp
                    .slave
                    .handle_tcp(&adu, direct_unit, &mut model, &mut self.tcp.reply);
            match handled {
                Handled::Reply(_) => {
                    self.gateway.plc_activity(now, now);
                    return Some(TcpAction::Reply(socket));
                }
                Handled::Unserved(_) => return Some(TcpAction::Reply(socket)),
                // Not a request: nothing to answer; the next one, if any.
                _ => {}
            }
        }
    }
}
