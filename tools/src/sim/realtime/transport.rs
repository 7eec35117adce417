//! The transports: a pseudo-terminal pair or a loopback TCP socket, and the termios rates.

use std::fs::File;
use std::io::{self, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::os::fd::{AsFd, BorrowedFd};
use std::path::{Path, PathBuf};
use std::time::Duration;

use nix::errno::Errno;
use nix::fcntl::{fcntl, FcntlArg, OFlag};
use nix::libc::tcflag_t;
use nix::poll::{ppoll, PollFd, PollFlags};
use nix::pty::PtyMaster;
use nix::sys::termios::{self, BaudRate, ControlFlags, Termios};
use nix::sys::time::TimeSpec;
use protocol::line::Baud;

/// Where the master is.
#[derive(Debug)]
pub enum Transport {
    /// A pseudo-terminal.
    Pty(Pty),
    /// A loopback TCP socket.
    Tcp(TcpServer),
}

pub(super) enum Input {
    Bytes(usize),
    Connected(SocketAddr),
    Closed,
    Nothing,
}

impl Transport {
    pub(super) fn speed_change(&mut self) -> io::Result<Option<Baud>> {
        match self {
            Transport::Pty(pty) => pty.speed_change(),
            Transport::Tcp(_) => Ok(None),
        }
    }

    pub(super) fn read(&mut self, buf: &mut [u8]) -> io::Result<Input> {
        match self {
            Transport::Pty(pty) => pty.read(buf),
            Transport::Tcp(tcp) => tcp.read(buf),
        }
    }

    /// Bytes written; 0 when the master cannot take more now (or is not there).
    pub(super) fn write(&mut self, bytes: &[u8]) -> io::Result<usize> {
        let result = match self {
            Transport::Pty(pty) => pty.master.write(bytes),
            Transport::Tcp(tcp) => match tcp.client.as_mut() {
                Some(client) => client.write(bytes),
                None => return Ok(0),
            },
        };
        match result {
            Ok(n) => Ok(n),
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => Ok(0),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => Ok(0),
            // The client went away mid-write; the next read reports it.
            Err(e) if matches!(self, Transport::Tcp(_)) && disconnection(&e) => Ok(0),
            Err(e) => Err(e),
        }
    }

    /// Sleep up to `timeout`, or until the master has written (or connected), or can take
    /// more bytes if `output` is pending.
    pub(super) fn wait(&self, timeout: Duration, output: bool) -> io::Result<()> {
        let (fd, connected) = match self {
            Transport::Pty(pty) => (pty.master.as_fd(), true),
            Transport::Tcp(tcp) => match tcp.client.as_ref() {
                Some(client) => (client.as_fd(), true),
                None => (tcp.listener.as_fd(), false),
            },
        };
        wait_fd(fd, timeout, output && connected)
    }
}

fn wait_fd(fd: BorrowedFd<'_>, timeout: Duration, output: bool) -> io::Result<()> {
    let mut events = PollFlags::POLLIN;
    if output {
        events |= PollFlags::POLLOUT;
    }
    let mut fds = [PollFd::new(fd, events)];
    match ppoll(&mut fds, Some(TimeSpec::from_duration(timeout)), None) {
        Ok(_) | Err(Errno::EINTR) => Ok(()),
        Err(e) => Err(e.into()),
    }
}

fn disconnection(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::ConnectionReset
            | io::ErrorKind::ConnectionAborted
            | io::ErrorKind::BrokenPipe
            | io::ErrorKind::NotConnected
            | io::ErrorKind::UnexpectedEof
    )
}

/// A pseudo-terminal pair; the master opens [`path`](Self::path) as its serial port.
#[derive(Debug)]
pub struct Pty {
    master: PtyMaster,
    /// Held open so that the terminal keeps its settings and never hangs up.
    slave: File,
    path: PathBuf,
    /// The last speed seen, bit/s (`None`: not a rate).
    speed: Option<u32>,
}

impl Pty {
    /// A new pair, the terminal in raw mode at `baud` (if termios has a constant for it; else
    /// its default speed, which is then not taken as the master's rate).
    pub fn open(baud: Baud) -> io::Result<Pty> {
        let (master, slave, path) = crate::pty::open_raw(termios_rate(baud))?;
        let flags = OFlag::from_bits_retain(fcntl(&master, FcntlArg::F_GETFL)?);
        fcntl(&master, FcntlArg::F_SETFL(flags | OFlag::O_NONBLOCK))?;
        let speed = speed_bps(&slave)?;
        Ok(Pty {
            master,
            slave,
            path,
            speed,
        })
    }

    /// The slave device, `/dev/pts/N`.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The rate the master set, when it changed since the last call and is one of the rates.
    fn speed_change(&mut self) -> io::Result<Option<Baud>> {
        let speed = speed_bps(&self.slave)?;
        if speed == self.speed {
            return Ok(None);
        }
        self.speed = speed;
        Ok(speed.and_then(Baud::from_bits_per_second))
    }

    fn read(&mut self, buf: &mut [u8]) -> io::Result<Input> {
        match self.master.read(buf) {
            Ok(0) => Ok(Input::Nothing),
            Ok(n) => Ok(Input::Bytes(n)),
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => Ok(Input::Nothing),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => Ok(Input::Nothing),
            // EIO: no slave open. Cannot happen while `slave` is held; nothing to read anyway.
            Err(e) if e.raw_os_error() == Some(Errno::EIO as i32) => Ok(Input::Nothing),
            Err(e) => Err(e),
        }
    }
}

/// The speed bits of the control flags (`cfgetospeed` without its panic on unknown values).
fn raw_speed(attrs: &Termios) -> tcflag_t {
    (attrs.control_flags & ControlFlags::CBAUD).bits()
}

fn termios_rate(baud: Baud) -> Option<BaudRate> {
    match baud {
        Baud::B9600 => Some(BaudRate::B9600),
        Baud::B19200 => Some(BaudRate::B19200),
        Baud::B38400 => Some(BaudRate::B38400),
        Baud::B57600 => Some(BaudRate::B57600),
        Baud::B115200 => Some(BaudRate::B115200),
        Baud::B14400 | Baud::B28800 | Baud::B76800 => None,
    }
}

/// The terminal's speed in bit/s: from its `CBAUD` code, or, where a program set an arbitrary
/// rate (`BOTHER`, as the `serialport` crate does on Linux through `termios2`), the number itself.
fn speed_bps(terminal: &File) -> io::Result<Option<u32>> {
    let code = raw_speed(&termios::tcgetattr(terminal)?);
    if code == nix::libc::BOTHER {
        // SAFETY: termios2 is a plain C struct, valid all-zero; TCGETS2 fills it from the
        // terminal open as `terminal`, whose descriptor outlives the call.
        let mut attrs: nix::libc::termios2 = unsafe { std::mem::zeroed() };
        let done = unsafe {
            nix::libc::ioctl(
                std::os::fd::AsRawFd::as_raw_fd(terminal),
                nix::libc::TCGETS2,
                &mut attrs,
            )
        };
        if done != 0 {
            return Err(io::Error::last_os_error());
        }
        return Ok(Some(attrs.c_ospeed));
    }
    Ok(Baud::ALL
        .into_iter()
        .find(|&baud| termios_rate(baud).is_some_and(|rate| rate as tcflag_t == code))
        .map(Baud::bits_per_second))
}

/// A listening socket on a loopback address, one client at a time.
#[derive(Debug)]
pub struct TcpServer {
    listener: TcpListener,
    client: Option<TcpStream>,
}

impl TcpServer {
    /// Listen on `addr`, which must be a loopback address (127.0.0.0/8 or ::1); port 0 picks a
    /// free port ([`local_addr`](Self::local_addr)).
    pub fn bind(addr: SocketAddr) -> io::Result<TcpServer> {
        if !addr.ip().is_loopback() {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("{addr} is not a loopback address; the simulator listens on loopback only"),
            ));
        }
        let listener = TcpListener::bind(addr)?;
        listener.set_nonblocking(true)?;
        Ok(TcpServer {
            listener,
            client: None,
        })
    }

    /// The address listened on.
    pub fn local_addr(&self) -> io::Result<SocketAddr> {
        self.listener.local_addr()
    }

    fn read(&mut self, buf: &mut [u8]) -> io::Result<Input> {
        let Some(client) = self.client.as_mut() else {
            return match self.listener.accept() {
                Ok((stream, peer)) => {
                    stream.set_nonblocking(true)?;
                    stream.set_nodelay(true)?;
                    self.client = Some(stream);
                    Ok(Input::Connected(peer))
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => Ok(Input::Nothing),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => Ok(Input::Nothing),
                // A client that gave up while in the backlog.
                Err(e) if disconnection(&e) => Ok(Input::Nothing),
                Err(e) => Err(e),
            };
        };
        match client.read(buf) {
            Ok(0) => {
                self.client = None;
                Ok(Input::Closed)
            }
            Ok(n) => Ok(Input::Bytes(n)),
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => Ok(Input::Nothing),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => Ok(Input::Nothing),
            Err(e) if disconnection(&e) => {
                self.client = None;
                Ok(Input::Closed)
            }
            Err(e) => Err(e),
        }
    }
}
