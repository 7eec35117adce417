//! The host gateway's Modbus TCP side: a listening socket and the node's
//! [`SOCKETS`] connection slots, non-blocking, in the same loop as the serial lines.
//!
//! What the firmware's network task does with embassy-net, done with std: accept, tell the
//! node ([`Node::tcp_opened`]), hand it the bytes it has room for, send its replies without
//! ever waiting on a client, close what it says to close.

use std::collections::VecDeque;
use std::io::{self, Read, Write};
use std::net::{IpAddr, Shutdown, SocketAddr, TcpListener, TcpStream};
use std::os::fd::{AsFd, BorrowedFd};

use protocol::modbus::tcp::{SocketHandle, SOCKETS};
use protocol::net::Ipv4;
use protocol::node::Node;
use protocol::time::Instant;

/// Reply bytes a client may leave unread before its connection is closed (a client that sends
/// requests and never reads the replies; the firmware's socket buffer is smaller still).
const MAX_UNREAD: usize = 16 * 1024;

/// One connection.
struct Connection {
    stream: TcpStream,
    /// Bytes read from the client that the node has not taken yet.
    unread: Vec<u8>,
    /// Reply bytes not written yet.
    out: VecDeque<u8>,
    /// The client has closed its side (FIN): its socket is no longer waited on (the node is
    /// told, and says when the connection is done: [`Node::tcp_finish`]).
    eof: bool,
}

/// The listening socket and the connections.
pub struct TcpSide {
    listener: TcpListener,
    connections: Vec<Option<Connection>>,
    /// Clients that connected while every socket was in use (closed at once).
    pub overflows: u64,
}

/// The node's address form of a client's address (IPv4, or an IPv4-mapped IPv6 one; any other
/// is 0.0.0.0, which no allow-list entry matches).
fn ipv4_of(addr: &SocketAddr) -> Ipv4 {
    match addr.ip() {
        IpAddr::V4(v4) => Ipv4(v4.octets()),
        IpAddr::V6(v6) => v6
            .to_ipv4_mapped()
            .map_or(Ipv4::UNSPECIFIED, |v4| Ipv4(v4.octets())),
    }
}

impl TcpSide {
    /// Listens on `addr` (port 0: any free port).
    pub fn bind(addr: SocketAddr) -> io::Result<TcpSide> {
        let listener = TcpListener::bind(addr)
            .map_err(|e| io::Error::new(e.kind(), format!("--modbus-tcp {addr}: {e}")))?;
        listener.set_nonblocking(true)?;
        Ok(TcpSide {
            listener,
            connections: (0..SOCKETS).map(|_| None).collect(),
            overflows: 0,
        })
    }

    /// Every connection dropped, as a reset of the gateway drops them: what is still to be
    /// written is tried once, then the connection is shut down. The node is not told (it is
    /// replaced).
    pub fn drop_all(&mut self) {
        for slot in &mut self.connections {
            if let Some(mut connection) = slot.take() {
                let (a, b) = connection.out.as_slices();
                let _ = connection.stream.write_all(a);
                let _ = connection.stream.write_all(b);
                let _ = connection.stream.shutdown(Shutdown::Both);
            }
        }
    }

    /// The address listened on.
    pub fn local_addr(&self) -> io::Result<SocketAddr> {
        self.listener.local_addr()
    }

    /// Accepts new clients, reads what the node has room for, writes pending replies.
    pub fn pump(&mut self, now: u64, node: &mut Node) -> io::Result<()> {
        loop {
            let (stream, peer) = match self.listener.accept() {
                Ok(accepted) => accepted,
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                // A client that reset before it was accepted, and the like: not ours to fail on.
                Err(_) => break,
            };
            let free = self.connections.iter().position(Option::is_none);
            let Some(socket) = free.and_then(SocketHandle::new) else {
                self.overflows += 1;
                let _ = stream.shutdown(Shutdown::Both);
                continue;
            };
            if !node.tcp_opened(Instant(now), socket, ipv4_of(&peer)) {
                let _ = stream.shutdown(Shutdown::Both);
                continue;
            }
            stream.set_nonblocking(true)?;
            stream.set_nodelay(true)?;
            if let Some(slot) = self.connections.get_mut(socket.index()) {
                *slot = Some(Connection {
                    stream,
                    unread: Vec::new(),
                    out: VecDeque::new(),
                    eof: false,
                });
            }
        }
        for socket in SocketHandle::all() {
            self.read(now, socket, node);
            self.flush(socket, node);
            self.finish(socket, node);
        }
        Ok(())
    }

    /// Closes a connection whose client has closed its side once everything it sent has been
    /// answered and written.
    fn finish(&mut self, socket: SocketHandle, node: &mut Node) {
        let Some(Some(connection)) = self.connections.get(socket.index()) else {
            return;
        };
        // Nothing of the client's left here; the node says whether it answered everything (a
        // fragment left in it never completes after the FIN: only whole requests count).
        let done = connection.eof
            && connection.unread.is_empty()
            && connection.out.is_empty()
            && node.tcp_finish(socket);
        if done {
            self.close(socket, node);
        }
    }

    /// Offers the node what was read before, then reads more while it has room.
    fn read(&mut self, now: u64, socket: SocketHandle, node: &mut Node) {
        let Some(Some(connection)) = self.connections.get_mut(socket.index()) else {
            return;
        };
        let mut ended = false;
        loop {
            if !connection.unread.is_empty() {
                let taken = node.tcp_received(Instant(now), socket, &connection.unread);
                connection.unread.drain(..taken);
            }
            let room = node.tcp_room(socket);
            // Past the client's FIN only what was read before is left to hand over.
            if !connection.unread.is_empty() || room == 0 || connection.eof {
                break;
            }
            let mut buf = [0u8; 512];
            let want = room.min(buf.len());
            match connection
                .stream
                .read(buf.get_mut(..want).unwrap_or(&mut []))
            {
                Ok(0) => {
                    connection.eof = true;
                    node.tcp_eof(socket);
                    break;
                }
                Ok(n) => connection
                    .unread
                    .extend_from_slice(buf.get(..n).unwrap_or(&[])),
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(_) => {
                    ended = true;
                    break;
                }
            }
        }
        if ended {
            self.close(socket, node);
        }
    }

    /// Writes what the client takes now; a client that takes nothing while too much waits is
    /// closed.
    fn flush(&mut self, socket: SocketHandle, node: &mut Node) {
        let Some(Some(connection)) = self.connections.get_mut(socket.index()) else {
            return;
        };
        let mut broken = false;
        while !connection.out.is_empty() {
            let (front, _) = connection.out.as_slices();
            match connection.stream.write(front) {
                Ok(0) => break,
                Ok(n) => {
                    connection.out.drain(..n.min(connection.out.len()));
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(_) => {
                    broken = true;
                    break;
                }
            }
        }
        if broken || connection.out.len() > MAX_UNREAD {
            self.close(socket, node);
        }
    }

    /// The node's reply for `socket`: sent now as far as the client takes it.
    pub fn reply(&mut self, now: u64, socket: SocketHandle, bytes: &[u8], node: &mut Node) {
        if let Some(Some(connection)) = self.connections.get_mut(socket.index()) {
            connection.out.extend(bytes);
        }
        self.flush(socket, node);
        // A pipelining client's next request may already be here.
        self.read(now, socket, node);
    }

    /// Closes `socket` (the node asked, or the client left), and tells the node.
    pub fn close(&mut self, socket: SocketHandle, node: &mut Node) {
        if let Some(slot) = self.connections.get_mut(socket.index()) {
            if let Some(connection) = slot.take() {
                let _ = connection.stream.shutdown(Shutdown::Both);
            }
        }
        node.tcp_closed(socket);
    }

    /// The descriptors to wait on, with whether output is pending.
    pub fn fds(&self) -> Vec<(BorrowedFd<'_>, bool)> {
        let mut fds = vec![(self.listener.as_fd(), false)];
        // A client past its FIN is always readable (at its end): not waited on.
        for connection in self.connections.iter().flatten().filter(|c| !c.eof) {
            fds.push((connection.stream.as_fd(), !connection.out.is_empty()));
        }
        fds
    }

    /// The connections open now.
    pub fn open(&self) -> usize {
        self.connections.iter().flatten().count()
    }
}
