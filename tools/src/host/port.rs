//! The two serial lines of the host gateway: a pseudo-terminal or a real serial device, raw,
//! non-blocking, with an output queue so that a slow reader never stalls the loop.

use std::collections::VecDeque;
use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::{AsFd, BorrowedFd, OwnedFd};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

use nix::errno::Errno;
use nix::fcntl::{fcntl, FcntlArg, OFlag};
use nix::sys::termios::{self, BaudRate, ControlFlags, InputFlags, SetArg};

/// Parity of a serial line (8 data bits, 1 stop bit): the PLC line's setting.
pub use protocol::plc::Parity;

/// A serial line: the master side of a pseudo-terminal, or a serial device.
#[derive(Debug)]
pub struct Port {
    file: File,
    /// A pseudo-terminal's slave, held open so that the terminal keeps its settings and the
    /// master never sees a hang-up while the client closes and reopens it.
    slave: Option<File>,
    path: PathBuf,
    out: VecDeque<u8>,
}

/// What a read gave.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Input {
    /// This many bytes.
    Bytes(usize),
    /// Nothing now.
    Nothing,
}

/// The termios constant of a rate, if Linux has one.
pub fn termios_rate(bps: u32) -> Option<BaudRate> {
    Some(match bps {
        1200 => BaudRate::B1200,
        2400 => BaudRate::B2400,
        4800 => BaudRate::B4800,
        9600 => BaudRate::B9600,
        19_200 => BaudRate::B19200,
        38_400 => BaudRate::B38400,
        57_600 => BaudRate::B57600,
        115_200 => BaudRate::B115200,
        230_400 => BaudRate::B230400,
        460_800 => BaudRate::B460800,
        921_600 => BaudRate::B921600,
        _ => return None,
    })
}

fn unsupported_rate(bps: u32) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidInput,
        format!("{bps} bit/s: termios has no constant for this rate"),
    )
}

impl Port {
    /// A new pseudo-terminal pair in raw mode at `bps` (the rate is only recorded: a
    /// pseudo-terminal has no line rate). The client opens [`path`](Self::path).
    pub fn pty(bps: u32) -> io::Result<Port> {
        let (master, slave, path) = crate::pty::open_raw(termios_rate(bps))?;
        let file = File::from(OwnedFd::from(master));
        set_nonblocking(&file)?;
        Ok(Port {
            file,
            slave: Some(slave),
            path,
            out: VecDeque::new(),
        })
    }

    /// A serial device in raw mode, 8 data bits, 1 stop bit, no flow control, at `bps`.
    pub fn serial(path: &Path, bps: u32, parity: Parity) -> io::Result<Port> {
        let rate = termios_rate(bps).ok_or_else(|| unsupported_rate(bps))?;
        // Every failure names the device: "Inappropriate ioctl for device" alone does not say
        // which of the two lines is not a serial port.
        let named = |e: io::Error| {
            let what = if e.raw_os_error() == Some(Errno::ENOTTY as i32) {
                format!("not a serial port ({e})")
            } else {
                e.to_string()
            };
            io::Error::new(e.kind(), format!("{}: {what}", path.display()))
        };
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(nix::libc::O_NOCTTY | nix::libc::O_NONBLOCK)
            .open(path)
            .map_err(named)?;
        let set_up = || -> io::Result<()> {
            let mut attrs = termios::tcgetattr(&file)?;
            termios::cfmakeraw(&mut attrs);
            attrs.control_flags &= !(ControlFlags::CSTOPB
                | ControlFlags::CRTSCTS
                | ControlFlags::PARENB
                | ControlFlags::PARODD);
            attrs.control_flags |= ControlFlags::CLOCAL | ControlFlags::CREAD | ControlFlags::CS8;
            attrs.input_flags &= !(InputFlags::IXON | InputFlags::IXOFF | InputFlags::INPCK);
            match parity {
                Parity::None => {}
                Parity::Even => attrs.control_flags |= ControlFlags::PARENB,
                Parity::Odd => attrs.control_flags |= ControlFlags::PARENB | ControlFlags::PARODD,
            }
            termios::cfsetspeed(&mut attrs, rate)?;
            termios::tcsetattr(&file, SetArg::TCSANOW, &attrs)?;
            termios::tcflush(&file, termios::FlushArg::TCIOFLUSH)?;
            Ok(())
        };
        set_up().map_err(named)?;
        Ok(Port {
            file,
            slave: None,
            path: path.to_path_buf(),
            out: VecDeque::new(),
        })
    }

    /// The device the client opens (`/dev/pts/N`) or the device opened.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The descriptor to wait on.
    pub fn fd(&self) -> BorrowedFd<'_> {
        self.file.as_fd()
    }

    /// Whether bytes wait to be written.
    pub fn output_pending(&self) -> bool {
        !self.out.is_empty()
    }

    /// Read what is there, without blocking.
    pub fn read(&mut self, buf: &mut [u8]) -> io::Result<Input> {
        match self.file.read(buf) {
            Ok(0) => Ok(Input::Nothing),
            Ok(n) => Ok(Input::Bytes(n)),
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => Ok(Input::Nothing),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => Ok(Input::Nothing),
            // A pseudo-terminal without any slave open: cannot happen while `slave` is held.
            Err(e) if self.slave.is_some() && e.raw_os_error() == Some(Errno::EIO as i32) => {
                Ok(Input::Nothing)
            }
            Err(e) => Err(e),
        }
    }

    /// Queue `bytes` and write as much as the line takes now.
    pub fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.out.extend(bytes);
        self.flush()
    }

    /// Write queued bytes, as far as the line takes them without blocking.
    pub fn flush(&mut self) -> io::Result<()> {
        while !self.out.is_empty() {
            let (front, _) = self.out.as_slices();
            match self.file.write(front) {
                Ok(0) => break,
                Ok(n) => {
                    self.out.drain(..n.min(self.out.len()));
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }

    /// Write everything queued and wait until the UART has sent it (before a rate change or
    /// a break). Blocks for at most the queued bytes' wire time.
    pub fn drain(&mut self) -> io::Result<()> {
        while !self.out.is_empty() {
            self.flush()?;
            if !self.out.is_empty() {
                wait(&[(self.fd(), true)], std::time::Duration::from_millis(5))?;
            }
        }
        match termios::tcdrain(&self.file) {
            Ok(()) | Err(Errno::ENOTTY) => Ok(()),
            Err(e) => Err(e.into()),
        }
    }

    /// Switch the line to `bps` (after the queued bytes have gone out).
    pub fn set_rate(&mut self, bps: u32) -> io::Result<()> {
        let rate = termios_rate(bps).ok_or_else(|| unsupported_rate(bps))?;
        self.drain()?;
        let mut attrs = termios::tcgetattr(&self.file)?;
        termios::cfsetspeed(&mut attrs, rate)?;
        termios::tcsetattr(&self.file, SetArg::TCSANOW, &attrs)?;
        Ok(())
    }

    /// Start (`true`) or end a break: the line held at 0 (TIOCSBRK / TIOCCBRK).
    pub fn set_break(&mut self, on: bool) -> io::Result<()> {
        if on {
            self.drain()?;
        }
        let request = if on {
            nix::libc::TIOCSBRK
        } else {
            nix::libc::TIOCCBRK
        };
        use std::os::fd::AsRawFd;
        // SAFETY: TIOCSBRK and TIOCCBRK take no argument; the descriptor is open for the
        // lifetime of `self.file`.
        let result = unsafe { nix::libc::ioctl(self.file.as_raw_fd(), request) };
        Errno::result(result).map(drop).map_err(io::Error::from)
    }
}

fn set_nonblocking(file: &File) -> io::Result<()> {
    let flags = OFlag::from_bits_retain(fcntl(file, FcntlArg::F_GETFL)?);
    fcntl(file, FcntlArg::F_SETFL(flags | OFlag::O_NONBLOCK))?;
    Ok(())
}

/// Sleep up to `timeout` or until one of `fds` is readable (or writable, where its flag is
/// set). A signal ends the wait early.
pub fn wait(fds: &[(BorrowedFd<'_>, bool)], timeout: std::time::Duration) -> io::Result<()> {
    use nix::poll::{ppoll, PollFd, PollFlags};
    use nix::sys::time::TimeSpec;
    let mut polls: Vec<PollFd<'_>> = fds
        .iter()
        .map(|&(fd, output)| {
            let mut events = PollFlags::POLLIN;
            if output {
                events |= PollFlags::POLLOUT;
            }
            PollFd::new(fd, events)
        })
        .collect();
    match ppoll(&mut polls, Some(TimeSpec::from_duration(timeout)), None) {
        Ok(_) | Err(Errno::EINTR) => Ok(()),
        Err(e) => Err(e.into()),
    }
}

/// Whether `fd` has something to read (or is at its end) right now.
pub fn readable(fd: BorrowedFd<'_>) -> io::Result<bool> {
    use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
    let mut polls = [PollFd::new(fd, PollFlags::POLLIN)];
    match poll(&mut polls, PollTimeout::ZERO) {
        Ok(n) => Ok(n > 0
            && polls[0].revents().is_some_and(|r| {
                r.intersects(PollFlags::POLLIN | PollFlags::POLLHUP | PollFlags::POLLERR)
            })),
        Err(Errno::EINTR) => Ok(false),
        Err(e) => Err(e.into()),
    }
}
