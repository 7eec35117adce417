//! The gateway's network task: Modbus TCP on port 502 around the protocol [`Node`], with
//! embassy-net. Shared by every build with Ethernet (the Ethernet board and the emulator's
//! `mps2-an386` build), so that what the emulator proves is the board's own code.
//!
//! # Shape
//! The node has one owner, the gateway task, as on every board: nothing here locks it. Each of
//! [`SOCKETS`] sockets has a task of its own ([`serve`]) that accepts a client on port 502 and
//! moves bytes; the two sides meet in a [`Port`] (in a `static`):
//!
//! | Socket task → gateway | Gateway → socket task |
//! |---|---|
//! | [`Event::Opened`] with the client's address | `close`: close the connection (refused, replaced, idle, framing lost, not reading) |
//! | bytes in the socket's receive pipe, and [`Event::Data`] | the replies, in the socket's send pipe |
//! | [`Event::Sent`]: the send pipe has emptied | |
//! | [`Event::Eof`]: the client has closed its side | `answered`: every request of it answered, end the connection after the replies |
//! | [`Event::Closed`]: the connection has ended, and the task no longer touches the pipes | `released`: the pipes are empty, hand over the next client |
//!
//! A gateway loop makes two calls, the same on every build: [`Port::pump`] before the node's
//! actions and again after them (it hands the node every queued event and the bytes it has room
//! for, and says whether the node has more to do), and [`Port::act`] for each [`Action::Tcp`]
//! the node asks for; it waits for [`Port::ready`] beside its other inputs. It never waits on a socket.
//! Back-pressure instead: once a socket's send pipe has no room for another whole reply, the
//! node answers none of that client's requests ([`Node::tcp_writable`]) until its replies have
//! left ([`Event::Sent`]); a client that pipelines many requests, or reads its replies slowly,
//! waits in its pipe and in TCP's window, not in the gateway's time, and one that never reads is
//! closed by the idle time. Every end of a connection goes through [`Event::Closed`] and
//! `released`, so no byte of one client ever reaches the next one on the same socket; and the
//! socket task looks at the close before anything else and around every wait of its own (a full
//! pipe, a client that does not read), so a close always ends the connection.
//!
//! What a connection is (open, its client, its stream, writable, past its FIN, idle since) is
//! the node's alone ([`protocol::modbus::tcp::Server`]); a [`Port`] holds only what crosses
//! between the tasks: the bytes in flight, the signals, and whether an event is queued.
//!
//! [`Action::Tcp`]: protocol::node::Action::Tcp

#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

use core::sync::atomic::{AtomicBool, Ordering};
use embassy_futures::join::join;
use embassy_futures::select::{select, select3, Either, Either3};
use embassy_net::tcp::TcpSocket;
use embassy_net::{IpAddress, Stack};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_sync::pipe::Pipe;
use embassy_sync::signal::Signal;
use protocol::modbus::tcp::MAX_TCP_ADU_LEN;
use protocol::net::Ipv4;
use protocol::node::{Node, TcpAction};
use protocol::time::Instant;

pub use protocol::modbus::tcp::{SocketHandle, MODBUS_TCP_PORT, SOCKETS};

type Cs = CriticalSectionRawMutex;

/// Bytes from a client waiting for the node: more than one request (260 bytes at most), so a
/// pipelining client's next request is already here when the node is ready for it.
pub const RECEIVE_PIPE: usize = 512;

/// Replies waiting for the socket: a few whole replies (260 bytes at most each). A client that
/// lets this fill up is not reading its replies.
pub const SEND_PIPE: usize = 1024;

/// Events queued for the gateway task, at most (a socket task waits when it is full): per
/// socket at most one Data and one Sent (`Socket::data_queued`), and the connection's Opened,
/// Eof and Closed, one after the other.
const EVENTS: usize = 4 * SOCKETS;

/// What a socket task tells the gateway task.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Event {
    /// A client at this address connected on the socket.
    Opened {
        /// The socket.
        socket: SocketHandle,
        /// The client's IPv4 address.
        peer: Ipv4,
    },
    /// Bytes from the client wait in the socket's receive pipe.
    Data(SocketHandle),
    /// The socket's connection has ended (the client closed it, it broke, or the gateway
    /// closed it): its task listens again, and waits to be released before it reports the next
    /// client.
    Closed(SocketHandle),
    /// The socket's send pipe has emptied: it has room for replies again.
    Sent(SocketHandle),
    /// The client has closed its side (TCP FIN): once what it sent before is answered, the
    /// connection ends.
    Eof(SocketHandle),
}

/// How long a connection's end may wait for TCP to send its reset: a client that vanished (no
/// ARP answer any more) would otherwise hold the socket for good.
const CLOSE_WAIT: embassy_time::Duration = embassy_time::Duration::from_secs(1);

/// One socket's side of the [`Port`].
struct Socket {
    receive: Pipe<Cs, RECEIVE_PIPE>,
    send: Pipe<Cs, SEND_PIPE>,
    close: Signal<Cs, ()>,
    released: Signal<Cs, ()>,
    /// After the client's FIN ([`Event::Eof`]): everything it sent has been answered
    /// ([`Node::tcp_finish`]), the task ends the connection gracefully.
    answered: Signal<Cs, ()>,
    /// An [`Event::Data`] / [`Event::Sent`] is queued and not handled yet: at most one of each
    /// per socket waits in the channel, so that it never fills (a trickling client would
    /// otherwise queue one per read).
    data_queued: AtomicBool,
    sent_queued: AtomicBool,
}

impl Socket {
    const fn new() -> Socket {
        Socket {
            receive: Pipe::new(),
            send: Pipe::new(),
            close: Signal::new(),
            released: Signal::new(),
            answered: Signal::new(),
            data_queued: AtomicBool::new(false),
            sent_queued: AtomicBool::new(false),
        }
    }
}

/// Where the socket tasks and the gateway task meet; see the [crate documentation](crate).
pub struct Port {
    events: Channel<Cs, Event, EVENTS>,
    sockets: [Socket; SOCKETS],
    /// Shown every event as it is handed to the node (a log), if set.
    trace: Option<fn(&Event)>,
}

impl Default for Port {
    fn default() -> Self {
        Port::new()
    }
}

impl Port {
    /// Empty pipes, no events.
    pub const fn new() -> Port {
        Port::traced(None)
    }

    /// The same, with `trace` shown every event as it is handed to the node.
    pub const fn with_trace(trace: fn(&Event)) -> Port {
        Port::traced(Some(trace))
    }

    const fn traced(trace: Option<fn(&Event)>) -> Port {
        Port {
            events: Channel::new(),
            sockets: [const { Socket::new() }; SOCKETS],
            trace,
        }
    }

    /// Socket `socket`'s side (never `None`: a handle is always in range).
    fn socket(&self, socket: SocketHandle) -> Option<&Socket> {
        self.sockets.get(socket.index())
    }

    /// Waits until an event is queued (the gateway task waits for it beside its lines and
    /// deadlines), then leaves it for [`pump`](Port::pump).
    pub async fn ready(&self) {
        self.events.ready_to_receive().await
    }

    /// The one call a gateway loop makes before and after the node's actions: hands the node
    /// at `now` every queued event and the received bytes it has room for (a frame that got no
    /// reply, another protocol's or a malformed one, leaves room that no reply refills), and
    /// ends the connections it has done with. Whether it gave the node anything: poll it again
    /// then, and pump again after.
    pub fn pump(&self, node: &mut Node, now: Instant) -> bool {
        let mut gave = false;
        while let Ok(event) = self.events.try_receive() {
            if let Some(trace) = self.trace {
                trace(&event);
            }
            self.handle(event, node, now);
            gave = true;
        }
        for socket in SocketHandle::all() {
            gave |= self.feed(socket, node, now);
        }
        if !gave {
            // The node is idle: a client past its FIN whose every whole request has been
            // answered (nothing in its pipe, no whole frame in the node: a fragment never
            // completes now) is done, and no longer counted as connected (TCPCONN).
            for socket in SocketHandle::all() {
                if let Some(s) = self.socket(socket) {
                    if s.receive.is_empty() && node.tcp_finish(socket) {
                        s.answered.signal(());
                    }
                }
            }
        }
        gave
    }

    /// Carries out what the node asked for on a socket at `now`.
    pub fn act(&self, action: TcpAction, node: &mut Node, now: Instant) {
        match action {
            TcpAction::Reply(socket) => self.reply(socket, node, now),
            TcpAction::Close(socket) => self.close(socket, node),
        }
    }

    /// Hands an event to the node at `now`.
    fn handle(&self, event: Event, node: &mut Node, now: Instant) {
        match event {
            Event::Opened { socket, peer } => {
                if !node.tcp_opened(now, socket, peer) {
                    self.close_socket(socket);
                }
            }
            Event::Data(socket) => {
                if let Some(s) = self.socket(socket) {
                    s.data_queued.store(false, Ordering::Relaxed);
                }
                self.feed(socket, node, now);
            }
            Event::Sent(socket) => {
                if let Some(s) = self.socket(socket) {
                    s.sent_queued.store(false, Ordering::Relaxed);
                    if s.send.free_capacity() >= MAX_TCP_ADU_LEN {
                        node.tcp_writable(socket, true);
                    }
                }
                self.feed(socket, node, now);
            }
            Event::Eof(socket) => {
                node.tcp_eof(socket);
                self.feed(socket, node, now);
            }
            Event::Closed(socket) => {
                node.tcp_closed(socket);
                if let Some(s) = self.socket(socket) {
                    s.receive.clear();
                    s.send.clear();
                    s.close.reset();
                    s.answered.reset();
                    s.data_queued.store(false, Ordering::Relaxed);
                    s.sent_queued.store(false, Ordering::Relaxed);
                    s.released.signal(());
                }
            }
        }
    }

    /// Gives the node the received bytes it has room for; whether it gave any. Bytes of a
    /// socket the node holds no connection on stay: they are a new client's whose Opened is
    /// still queued (the gateway task may have awaited its bus meanwhile), or a closed one's,
    /// which its close empties (`close_socket`, [`Event::Closed`]).
    fn feed(&self, socket: SocketHandle, node: &mut Node, now: Instant) -> bool {
        let Some(s) = self.socket(socket) else {
            return false;
        };
        if !node.tcp_connected(socket) {
            return false;
        }
        let mut fed = false;
        let mut buf = [0u8; 64];
        loop {
            let room = node.tcp_room(socket).min(buf.len());
            let Some(chunk) = buf.get_mut(..room).filter(|c| !c.is_empty()) else {
                return fed;
            };
            let Ok(n) = s.receive.try_read(chunk) else {
                return fed;
            };
            node.tcp_received(now, socket, chunk.get(..n).unwrap_or(&[]));
            fed = true;
        }
    }

    /// Queues the node's reply ([`Node::tcp_reply`], read where it is) on `socket`, whole, or
    /// closes the connection (it cannot happen while the node is told, as here, when the pipe
    /// has no room for another reply); then gives the node what came meanwhile.
    fn reply(&self, socket: SocketHandle, node: &mut Node, now: Instant) {
        let Some(s) = self.socket(socket) else {
            return;
        };
        let mut rest = node.tcp_reply();
        if s.send.free_capacity() < rest.len() {
            self.close(socket, node);
            return;
        }
        // A pipe writes up to its end at a time: a reply across the wrap takes two writes.
        while !rest.is_empty() {
            match s.send.try_write(rest) {
                Ok(n) if n > 0 => rest = rest.get(n..).unwrap_or(&[]),
                _ => {
                    self.close(socket, node);
                    return;
                }
            }
        }
        // Back-pressure: no more of this client's requests until its replies have left
        // ([`Event::Sent`]); the other clients' are answered meanwhile.
        if s.send.free_capacity() < MAX_TCP_ADU_LEN {
            node.tcp_writable(socket, false);
        }
        self.feed(socket, node, now);
    }

    /// Closes the connection on `socket`, as the node asked ([`TcpAction::Close`]).
    fn close(&self, socket: SocketHandle, node: &mut Node) {
        node.tcp_closed(socket);
        self.close_socket(socket);
    }

    /// Tells the socket task to close, and empties its receive pipe (the task may be waiting
    /// for room in it; the bytes are the closed client's).
    fn close_socket(&self, socket: SocketHandle) {
        if let Some(s) = self.socket(socket) {
            s.close.signal(());
            s.receive.clear();
        }
    }
}

/// The client's IPv4 address (0.0.0.0, which no allow-list matches, if it has none).
fn peer_of(socket: &TcpSocket<'_>) -> Ipv4 {
    match socket.remote_endpoint().map(|e| e.addr) {
        Some(IpAddress::Ipv4(address)) => Ipv4(address.octets()),
        #[allow(unreachable_patterns)]
        _ => Ipv4::UNSPECIFIED,
    }
}

/// Socket `index`: accepts a client on [`MODBUS_TCP_PORT`], moves its bytes to and from the
/// gateway task through `port` until the connection ends, reports the end, and listens again at
/// once; it reports the next client once the gateway has released the socket, for good. `rx`
/// and `tx` are the socket's own TCP buffers.
///
/// TCP's own time-outs are off: the node closes an idle connection (its TCPIDLE setting), and
/// keep-alives would only hide a half-open one from it.
pub async fn serve(
    stack: Stack<'static>,
    port: &'static Port,
    index: SocketHandle,
    rx: &'static mut [u8],
    tx: &'static mut [u8],
) -> ! {
    let Some(s) = port.socket(index) else {
        loop {
            core::future::pending::<()>().await;
        }
    };
    let mut buf = [0u8; 256];
    let mut out = [0u8; 256];
    // A connection's end has been reported (every time but the first): the gateway releases
    // the pipes before the next client is reported.
    let mut releasing = false;
    loop {
        let mut socket = TcpSocket::new(stack, rx, tx);
        socket.set_nagle_enabled(false);
        // The socket listens again at once, while the gateway releases the last connection:
        // a client that connects meanwhile waits in TCP's handshake and buffers, not for a
        // reset (smoltcp answers a SYN that no socket listens for with one). Its Opened, and
        // the first read of its bytes, come only after the release.
        let release = async {
            if releasing {
                s.released.wait().await;
            }
        };
        let (accepted, ()) = join(socket.accept(MODBUS_TCP_PORT), release).await;
        if accepted.is_ok() {
            s.close.reset();
            s.answered.reset();
            port.events
                .send(Event::Opened {
                    socket: index,
                    peer: peer_of(&socket),
                })
                .await;
            match connected(&mut socket, port, s, index, &mut buf, &mut out).await {
                // The replies in TCP's buffer go out, then our FIN.
                End::Graceful => socket.close(),
                End::Abort => socket.abort(),
            }
            // The last bytes, our FIN or the reset, if the client is still there to take them;
            // never longer than CLOSE_WAIT.
            let _ = embassy_time::with_timeout(CLOSE_WAIT, socket.flush()).await;
        }
        drop(socket);
        s.released.reset();
        port.events.send(Event::Closed(index)).await;
        releasing = true;
    }
}

/// How a connection ends.
enum End {
    /// The client closed its side and every request of it has been answered: a FIN, after the
    /// replies.
    Graceful,
    /// The gateway closed it, or it broke: a reset.
    Abort,
}

/// Moves bytes until the client closes, the connection breaks or the gateway closes it. The
/// close is looked at first. Bytes read from the client wait in `buf` while the receive pipe is
/// full (the node holds requests it has not answered), and meanwhile the replies keep going out:
/// the node answers only once they have ([`Event::Sent`]), so reading and sending must never
/// wait on each other.
async fn connected(
    socket: &mut TcpSocket<'_>,
    port: &Port,
    s: &Socket,
    index: SocketHandle,
    buf: &mut [u8],
    out: &mut [u8],
) -> End {
    // `buf[start..end]`: read from the client, not in the receive pipe yet.
    let (mut start, mut end) = (0, 0);
    loop {
        let (mut reader, mut writer) = socket.split();
        let inbound = async {
            match buf.get(start..end).filter(|b| !b.is_empty()) {
                Some(bytes) => Inbound::Piped(s.receive.write(bytes).await),
                None => Inbound::Read(reader.read(buf).await),
            }
        };
        match select3(s.close.wait(), inbound, s.send.read(out)).await {
            Either3::First(()) => return End::Abort,
            Either3::Second(Inbound::Piped(n)) => {
                start += n;
                data(port, s, index).await;
            }
            Either3::Second(Inbound::Read(Ok(n))) if n > 0 => (start, end) = (0, n),
            // The client closed its side (0 bytes): its last requests are still answered.
            Either3::Second(Inbound::Read(Ok(_))) => {
                return finish(&mut writer, port, s, index, out).await
            }
            // The connection broke.
            Either3::Second(Inbound::Read(Err(_))) => return End::Abort,
            Either3::Third(n) => {
                if !send(&mut writer, port, s, index, out.get(..n).unwrap_or(&[])).await {
                    return End::Abort;
                }
            }
        }
    }

    /// What the inbound side did: bytes put in the receive pipe, or a read from the client.
    enum Inbound {
        Piped(usize),
        Read(Result<usize, embassy_net::tcp::Error>),
    }

    /// Tells the gateway bytes wait in the receive pipe, unless it has been told already.
    async fn data(port: &Port, s: &Socket, index: SocketHandle) {
        if !s.data_queued.swap(true, Ordering::Relaxed) {
            port.events.send(Event::Data(index)).await;
        }
    }

    /// Writes `bytes` to the client unless the gateway closes first; `false` if it did, or the
    /// connection broke. An emptied send pipe is reported ([`Event::Sent`]).
    async fn send(
        writer: &mut embassy_net::tcp::TcpWriter<'_>,
        port: &Port,
        s: &Socket,
        index: SocketHandle,
        bytes: &[u8],
    ) -> bool {
        use embedded_io_async::Write;
        match select(s.close.wait(), writer.write_all(bytes)).await {
            Either::Second(Ok(())) => {
                if s.send.is_empty() && !s.sent_queued.swap(true, Ordering::Relaxed) {
                    port.events.send(Event::Sent(index)).await;
                }
                true
            }
            _ => false,
        }
    }

    /// After the client's FIN: the replies to what it sent before, until the gateway says every
    /// request of it has been answered (or it closes), then what is left in the send pipe.
    async fn finish(
        writer: &mut embassy_net::tcp::TcpWriter<'_>,
        port: &Port,
        s: &Socket,
        index: SocketHandle,
        out: &mut [u8],
    ) -> End {
        port.events.send(Event::Eof(index)).await;
        loop {
            match select3(s.close.wait(), s.answered.wait(), s.send.read(out)).await {
                Either3::First(()) => return End::Abort,
                Either3::Second(()) => {
                    while let Ok(n) = s.send.try_read(out) {
                        if !send(writer, port, s, index, out.get(..n).unwrap_or(&[])).await {
                            return End::Abort;
                        }
                    }
                    return End::Graceful;
                }
                Either3::Third(n) => {
                    if !send(writer, port, s, index, out.get(..n).unwrap_or(&[])).await {
                        return End::Abort;
                    }
                }
            }
        }
    }
}
