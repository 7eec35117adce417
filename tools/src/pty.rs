//! A pseudo-terminal pair in raw mode: the serial line a PLC or a bus master opens, for the
//! simulator's real-time mode and the PC gateway.

use nix::fcntl::OFlag;
use nix::pty::{grantpt, posix_openpt, ptsname_r, unlockpt, PtyMaster};
use nix::sys::termios::{self, BaudRate, SetArg};
use std::fs::File;
use std::io;
use std::os::unix::fs::OpenOptionsExt;
use std::path::PathBuf;

/// A new pair with the terminal in raw mode (at `rate`, if given): the master side, the slave
/// device held open (so that the terminal keeps its settings and never hangs up when the
/// client closes it), and the slave's path for the client.
pub fn open_raw(rate: Option<BaudRate>) -> io::Result<(PtyMaster, File, PathBuf)> {
    let master = posix_openpt(OFlag::O_RDWR | OFlag::O_NOCTTY)?;
    grantpt(&master)?;
    unlockpt(&master)?;
    let path = PathBuf::from(ptsname_r(&master)?);
    let slave = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(nix::libc::O_NOCTTY)
        .open(&path)?;
    let mut attrs = termios::tcgetattr(&slave)?;
    termios::cfmakeraw(&mut attrs);
    if let Some(rate) = rate {
        termios::cfsetspeed(&mut attrs, rate)?;
    }
    termios::tcsetattr(&slave, SetArg::TCSANOW, &attrs)?;
    Ok((master, slave, path))
}
