//! The simulator in real time (`sim::realtime`): a master on the other side of a pseudo-terminal
//! or a loopback TCP socket, written here with the `protocol` crate.
//!
//! These tests run on the wall clock, so they check behaviour, never exact timing: every wait
//! is bounded (a few seconds at most) and every time check is a lower bound (jitter only makes
//! things later). Only loopback addresses are used.

use std::collections::VecDeque;
use std::fs::File;
use std::io::{self, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::os::fd::AsFd;
use std::os::unix::fs::OpenOptionsExt;
use std::time::{Duration, Instant};

use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use nix::sys::termios::{self, BaudRate, SetArg};
use protocol::alarm::AlarmCode;
use protocol::frame::Packet;
use protocol::line::Baud;
use protocol::{Axis, Command, Deframer, Reply, Request, Rtim};
use rc_tools::sim::realtime::{
    bus_at_line, Control, Ended, Handle, Options, Outcome, Pty, RealTime, TcpServer, Transport,
};
use rc_tools::sim::BusConfig;

/// Long enough for any answer on a loaded machine (RTIM 255 ms at 9.6 kbit/s included).
const ANSWER_TIMEOUT: Duration = Duration::from_secs(3);
/// How long a master waits before it calls an axis silent (the task's 300 ms).
const SILENCE: Duration = Duration::from_millis(300);

fn axis(n: u8) -> Axis {
    Axis::new(n).unwrap()
}

fn request(n: u8, command: Command) -> Request {
    Request::new(axis(n), command)
}

/// Two axes (0 and 1) at 115.2 kbit/s and RTIM 3 ms, host at the same rate.
fn realtime(options: Options) -> RealTime {
    let bus = bus_at_line(
        BusConfig::default(),
        &[axis(0), axis(1)],
        Baud::B115200,
        Rtim::new(3).unwrap(),
    );
    RealTime::new(bus, options)
}

/// The master side of a transport: a file descriptor it reads and writes, and a deframer.
struct Master<T> {
    port: T,
    deframer: Deframer,
    /// Bytes read but not yet deframed (a read may bring more than one packet).
    unread: VecDeque<u8>,
}

impl<T: Read + Write + AsFd> Master<T> {
    fn new(port: T) -> Self {
        Master {
            port,
            deframer: Deframer::new(),
            unread: VecDeque::new(),
        }
    }

    fn send(&mut self, request: &Request) {
        self.port.write_all(&request.emit().to_bytes()).unwrap();
        self.port.flush().unwrap();
    }

    /// The bytes that arrive within `timeout` (returns early once `enough` have come).
    fn read_for(&mut self, timeout: Duration, enough: usize) -> Vec<u8> {
        let deadline = Instant::now() + timeout;
        let mut bytes = Vec::new();
        let mut buf = [0u8; 256];
        while bytes.len() < enough {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            let ms = u16::try_from(left.as_millis().max(1)).unwrap_or(u16::MAX);
            let mut fds = [PollFd::new(self.port.as_fd(), PollFlags::POLLIN)];
            if poll(&mut fds, PollTimeout::from(ms)).unwrap() == 0 {
                continue;
            }
            match self.port.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => bytes.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {}
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => panic!("read: {e}"),
            }
        }
        bytes
    }

    /// The next packet within `timeout`.
    fn packet(&mut self, timeout: Duration) -> Option<Packet> {
        let deadline = Instant::now() + timeout;
        loop {
            while let Some(byte) = self.unread.pop_front() {
                if let Ok(packet) = self.deframer.push(byte) {
                    return Some(packet);
                }
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return None;
            }
            let bytes = self.read_for(left, 1);
            self.unread.extend(bytes);
        }
    }

    /// Send `request` and return its answer (any other packet fails the test).
    fn transact(&mut self, request: &Request) -> Reply {
        self.send(request);
        match self.packet(ANSWER_TIMEOUT) {
            Some(Packet::Frame(frame)) => {
                let reply = Reply::parse(&frame).unwrap();
                reply
                    .answers(request)
                    .unwrap_or_else(|e| panic!("{reply:?} does not answer {request:?}: {e:?}"));
                reply
            }
            other => panic!("no answer to {request:?}: {other:?}"),
        }
    }

    /// Send `request` and expect no byte at all for [`SILENCE`].
    fn expect_silence(&mut self, request: &Request) {
        self.send(request);
        assert!(self.unread.is_empty(), "unread {:02X?}", self.unread);
        let bytes = self.read_for(SILENCE, 1);
        assert!(bytes.is_empty(), "{request:?} got {bytes:02X?}");
    }
}

/// Open the simulator's pseudo-terminal as a master would open its serial port.
fn open_port(pty: &Pty) -> File {
    std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(nix::libc::O_NOCTTY | nix::libc::O_NONBLOCK)
        .open(pty.path())
        .unwrap()
}

fn set_speed(port: &File, rate: BaudRate) {
    let mut attrs = termios::tcgetattr(port).unwrap();
    termios::cfsetspeed(&mut attrs, rate).unwrap();
    termios::tcsetattr(port, SetArg::TCSANOW, &attrs).unwrap();
}

fn spawn_pty(options: Options) -> (Handle, Master<File>) {
    let pty = Pty::open(Baud::B115200).unwrap();
    let port = open_port(&pty);
    let handle = realtime(options).spawn(Transport::Pty(pty)).unwrap();
    (handle, Master::new(port))
}

fn spawn_tcp(options: Options) -> (Handle, SocketAddr) {
    let server = TcpServer::bind("127.0.0.1:0".parse().unwrap()).unwrap();
    let addr = server.local_addr().unwrap();
    let handle = realtime(options).spawn(Transport::Tcp(server)).unwrap();
    (handle, addr)
}

fn connect(addr: SocketAddr) -> Master<TcpStream> {
    let stream = TcpStream::connect(addr).unwrap();
    stream.set_nodelay(true).unwrap();
    Master::new(stream)
}

/// Wait (bounded) for a run to end by itself.
fn wait_end(handle: Handle, within: Duration) -> Outcome {
    let deadline = Instant::now() + within;
    while !handle.is_finished() {
        assert!(Instant::now() < deadline, "the run did not end");
        std::thread::sleep(Duration::from_millis(10));
    }
    handle.join().unwrap()
}

fn servo(reply: &Reply) -> bool {
    reply.report().unwrap().status.servo()
}

// ----- pseudo-terminal -----

/// `--control` in `rc-sim`: faults injected into a running bus reach the master on the next pass.
#[test]
fn controls_cut_an_axis_off_and_raise_an_alarm_while_running() {
    let pty = Pty::open(Baud::B115200).unwrap();
    let port = open_port(&pty);
    let mut realtime = realtime(Options::default());
    let (sender, receiver) = std::sync::mpsc::channel();
    realtime.set_control(receiver);
    let handle = realtime.spawn(Transport::Pty(pty)).unwrap();
    let mut master = Master::new(port);
    let status = request(1, Command::Status);
    assert_eq!(
        master.transact(&status).report().unwrap().alarm,
        AlarmCode::NONE
    );

    sender.send(Control::Silent(axis(1), true)).unwrap();
    std::thread::sleep(Duration::from_millis(100)); // several passes of the loop
    master.expect_silence(&status);
    master.transact(&request(0, Command::Status)); // the other axis still answers

    sender.send(Control::Silent(axis(1), false)).unwrap();
    sender
        .send(Control::Alarm(axis(1), AlarmCode(0xE0)))
        .unwrap();
    std::thread::sleep(Duration::from_millis(100));
    assert_eq!(
        master.transact(&status).report().unwrap().alarm,
        AlarmCode(0xE0)
    );
    let outcome = handle.stop().unwrap();
    assert_eq!(outcome.ended, Ended::Stopped);
}

#[test]
fn pty_status_servo_and_missing_axis() {
    let (handle, mut master) = spawn_pty(Options::default());

    let status = request(1, Command::Status);
    let sent = Instant::now();
    let reply = master.transact(&status);
    // Lower bound only: the command's wire time, RTIM 3 ms and the reply's wire time (1.39 ms
    // each at 115.2 kbit/s) cannot be skipped, whatever the scheduler does.
    assert!(sent.elapsed() >= Duration::from_micros(5_700), "too early");
    assert_eq!(reply.axis(), axis(1));
    let report = reply.report().unwrap();
    assert!(report.status.power() && servo(&reply) && report.outputs.alm_n());

    assert!(!servo(&master.transact(&request(1, Command::Servo(false)))));
    assert!(!servo(&master.transact(&status)));
    // The other axis is untouched.
    assert!(servo(&master.transact(&request(0, Command::Status))));
    assert!(servo(&master.transact(&request(1, Command::Servo(true)))));
    assert!(servo(&master.transact(&status)));

    master.expect_silence(&request(5, Command::Status));

    let outcome = handle.stop().unwrap();
    assert_eq!(outcome.ended, Ended::Stopped);
    let stats = outcome.realtime.stats();
    assert_eq!(stats.bytes_from_master, 7 * 16);
    assert_eq!(stats.bytes_to_master, 6 * 16);
    assert_eq!(stats.overrun_bytes, 0);
    assert_eq!(outcome.realtime.bus_stats().replies_sent, 6);
    let axis1 = outcome.realtime.bus().controller(axis(1)).unwrap();
    assert!(axis1.servo());
    assert_eq!(axis1.stats().frames_addressed, 5);
}

#[test]
fn pty_master_may_reopen_the_port() {
    let pty = Pty::open(Baud::B115200).unwrap();
    let path = pty.path().to_owned();
    let first = open_port(&pty);
    let handle = realtime(Options::default())
        .spawn(Transport::Pty(pty))
        .unwrap();
    let mut master = Master::new(first);
    master.transact(&request(0, Command::Status));
    drop(master);

    let second = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(nix::libc::O_NOCTTY | nix::libc::O_NONBLOCK)
        .open(&path)
        .unwrap();
    let mut master = Master::new(second);
    master.transact(&request(1, Command::Status));
    assert_eq!(handle.stop().unwrap().ended, Ended::Stopped);
}

#[test]
fn pty_follows_the_masters_speed() {
    let (handle, mut master) = spawn_pty(Options::default());
    master.transact(&request(0, Command::Status));

    // The master at 9.6 kbit/s, the controllers still at 115.2: they do not understand it.
    set_speed(&master.port, BaudRate::B9600);
    master.expect_silence(&request(0, Command::Status));

    set_speed(&master.port, BaudRate::B115200);
    master.transact(&request(0, Command::Status));

    let outcome = handle.stop().unwrap();
    assert_eq!(outcome.realtime.stats().baud_changes, 2);
    assert_eq!(outcome.realtime.stats().emulated_breaks, 0);
    let axis0 = outcome.realtime.bus().controller(axis(0)).unwrap();
    assert_eq!(axis0.baud(), Baud::B115200);
    assert!(axis0.stats().wrong_baud_bytes >= 16);
}

#[test]
fn pty_fixed_baud_ignores_the_masters_speed() {
    let options = Options {
        follow_baud: false,
        ..Options::default()
    };
    let (handle, mut master) = spawn_pty(options);
    set_speed(&master.port, BaudRate::B9600);
    master.transact(&request(0, Command::Status));
    assert_eq!(handle.stop().unwrap().realtime.stats().baud_changes, 0);
}

#[test]
fn pty_slow_baud_is_break() {
    let options = Options {
        slow_baud_is_break: true,
        ..Options::default()
    };
    let (handle, mut master) = spawn_pty(options);
    master.transact(&request(1, Command::Status));

    // As the establishment procedure does: 9.6 kbit/s, then a break the PTY cannot carry
    // (the simulator emulates it), then commands at 9.6 kbit/s and RTIM 255 ms.
    set_speed(&master.port, BaudRate::B9600);
    std::thread::sleep(Duration::from_millis(200));
    let sent = Instant::now();
    master.transact(&request(1, Command::Status));
    assert!(sent.elapsed() >= Duration::from_millis(255), "RTIM 255 ms");

    let outcome = handle.stop().unwrap();
    assert_eq!(outcome.realtime.stats().emulated_breaks, 1);
    assert_eq!(outcome.realtime.bus_stats().breaks, 1);
    for n in [0, 1] {
        let controller = outcome.realtime.bus().controller(axis(n)).unwrap();
        assert_eq!(controller.baud(), Baud::B9600);
        assert_eq!(controller.rtim_ms(), 255);
        assert_eq!(controller.stats().breaks, 1);
    }
}

/// A switch to 9.6 kbit/s with a frame right after it (the gateway's rejoin probe of a lost axis
/// at the power-up settings) is a rate change, not a break: the other controllers stay at their
/// rate and RTIM.
#[test]
fn pty_slow_baud_with_bytes_at_once_is_no_break() {
    let options = Options {
        slow_baud_is_break: true,
        ..Options::default()
    };
    let (handle, mut master) = spawn_pty(options);
    set_speed(&master.port, BaudRate::B9600);
    master.expect_silence(&request(1, Command::Status)); // nobody listens at 9.6 kbit/s
    std::thread::sleep(Duration::from_millis(150)); // silence now, but after bytes
    set_speed(&master.port, BaudRate::B115200);
    master.transact(&request(1, Command::Status));

    let outcome = handle.stop().unwrap();
    assert_eq!(outcome.realtime.stats().emulated_breaks, 0);
    for n in [0, 1] {
        let controller = outcome.realtime.bus().controller(axis(n)).unwrap();
        assert_eq!(controller.baud(), Baud::B115200);
        assert_eq!(controller.rtim_ms(), 3);
    }
}

#[test]
fn pty_echo_returns_the_masters_bytes() {
    let pty = Pty::open(Baud::B115200).unwrap();
    let mut master = Master::new(open_port(&pty));
    let bus = bus_at_line(
        BusConfig {
            host_echo: true,
            ..BusConfig::default()
        },
        &[axis(0)],
        Baud::B115200,
        Rtim::new(3).unwrap(),
    );
    let handle = RealTime::new(bus, Options::default())
        .spawn(Transport::Pty(pty))
        .unwrap();
    let status = request(0, Command::Status);
    master.send(&status);
    assert_eq!(
        master.packet(ANSWER_TIMEOUT),
        Some(Packet::Frame(status.emit()))
    );
    let Some(Packet::Frame(frame)) = master.packet(ANSWER_TIMEOUT) else {
        panic!("no answer");
    };
    Reply::parse(&frame).unwrap().answers(&status).unwrap();
    handle.stop().unwrap();
}

// ----- TCP -----

#[test]
fn tcp_status_then_disconnect_ends_the_run() {
    let (handle, addr) = spawn_tcp(Options::default());
    let mut master = connect(addr);
    let reply = master.transact(&request(0, Command::Status));
    assert!(servo(&reply));
    master.expect_silence(&request(5, Command::Status));
    drop(master);

    let outcome = wait_end(handle, Duration::from_secs(5));
    assert_eq!(outcome.ended, Ended::Disconnected);
    assert_eq!(outcome.realtime.stats().clients, 1);
    assert_eq!(outcome.realtime.bus_stats().replies_sent, 1);
}

#[test]
fn tcp_reconnect_keeps_the_bus() {
    let options = Options {
        reconnect: true,
        ..Options::default()
    };
    let (handle, addr) = spawn_tcp(options);
    let mut master = connect(addr);
    assert!(!servo(&master.transact(&request(1, Command::Servo(false)))));
    drop(master);

    let mut master = connect(addr);
    // The bus carried on: axis 1's servo is still off.
    assert!(!servo(&master.transact(&request(1, Command::Status))));
    drop(master);

    let outcome = handle.stop().unwrap();
    assert_eq!(outcome.ended, Ended::Stopped);
    assert_eq!(outcome.realtime.stats().clients, 2);
}

#[test]
fn tcp_refuses_other_than_loopback() {
    for addr in ["0.0.0.0:0", "[::]:0", "192.0.2.1:5485"] {
        let err = TcpServer::bind(addr.parse().unwrap()).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::InvalidInput, "{addr}");
    }
}

// ----- ending the run -----

#[test]
fn stop_ends_a_run_without_a_client() {
    let (handle, _addr) = spawn_tcp(Options::default());
    std::thread::sleep(Duration::from_millis(50));
    let started = Instant::now();
    let outcome = handle.stop().unwrap();
    assert_eq!(outcome.ended, Ended::Stopped);
    assert!(started.elapsed() < Duration::from_secs(2));
}

#[test]
fn duration_ends_the_run() {
    let options = Options {
        duration: Some(Duration::from_millis(100)),
        ..Options::default()
    };
    let (handle, _master) = spawn_pty(options);
    let outcome = wait_end(handle, Duration::from_secs(5));
    assert_eq!(outcome.ended, Ended::Duration);
    // Virtual time is wall time: the bus ran (at least) the duration.
    assert!(outcome.realtime.bus().now() >= 100_000);
}

#[test]
fn dropping_the_handle_stops_the_thread() {
    let (handle, addr) = spawn_tcp(Options::default());
    let started = Instant::now();
    drop(handle);
    assert!(started.elapsed() < Duration::from_secs(2));
    // The listener went with the thread.
    assert!(TcpStream::connect(addr).is_err());
}

// ----- the rc-sim binary -----

/// Run `rc-sim` with `args`; returns the child and its first line of standard output.
fn rc_sim(args: &[&str]) -> (std::process::Child, String) {
    use std::io::BufRead;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_rc-sim"))
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    let stdout = child.stdout.take().unwrap();
    std::io::BufReader::new(stdout)
        .read_line(&mut line)
        .unwrap();
    (child, line.trim().to_owned())
}

/// Wait (bounded) for the child to exit; kill it and fail if it does not.
fn exit_code(mut child: std::process::Child, within: Duration) -> Option<i32> {
    let deadline = Instant::now() + within;
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return status.code();
        }
        if Instant::now() >= deadline {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("rc-sim did not exit");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn rc_sim_tcp_serves_one_client() {
    let (child, line) = rc_sim(&["--tcp", "127.0.0.1:0", "--axes", "2", "--log"]);
    let addr: SocketAddr = line.strip_prefix("TCP ").unwrap().parse().unwrap();
    let mut master = connect(addr);
    assert_eq!(
        master.transact(&request(1, Command::Status)).axis(),
        axis(1)
    );
    master.expect_silence(&request(2, Command::Status));
    drop(master);
    assert_eq!(exit_code(child, Duration::from_secs(5)), Some(0));
}

#[test]
fn rc_sim_pty_runs_for_its_duration() {
    let (child, line) = rc_sim(&["--pty", "--axes", "3,", "--duration", "1"]);
    let path = line.strip_prefix("PTY ").unwrap();
    assert!(path.starts_with("/dev/pts/"), "{line}");
    let port = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(nix::libc::O_NOCTTY | nix::libc::O_NONBLOCK)
        .open(path)
        .unwrap();
    let mut master = Master::new(port);
    assert_eq!(
        master.transact(&request(3, Command::Status)).axis(),
        axis(3)
    );
    assert_eq!(exit_code(child, Duration::from_secs(5)), Some(0));
}

#[test]
fn rc_sim_refuses_bad_arguments() {
    for args in [
        &["--tcp", "0.0.0.0:5485"][..],
        &["--pty", "--baud", "12345"],
        &["--pty", "--axes", "17"],
        &["--pty", "--corrupt", "1.5"],
        &[],
    ] {
        let output = std::process::Command::new(env!("CARGO_BIN_EXE_rc-sim"))
            .args(args)
            .output()
            .unwrap();
        assert_eq!(output.status.code(), Some(2), "{args:?}");
        assert!(output.stdout.is_empty(), "{args:?}");
    }
}
