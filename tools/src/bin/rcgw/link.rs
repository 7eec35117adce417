//! The Modbus master: RTU frames on a serial port (or a pseudo-terminal) or MBAP frames over
//! TCP, built with the protocol crate's `Request::emit`; and the gateway's registers on top of
//! it, with every error naming the port, the unit and the register.

use std::fmt;
use std::io::{Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

use protocol::modbus::client;
use protocol::modbus::{Adu, Diagnostic, Exception, Request};
use protocol::plc::map::{self, Unit};
use serialport::{ClearBuffer, Parity, SerialPort};

/// Why a command failed, with its exit status.
#[derive(Debug)]
pub enum Fail {
    /// The line or the device (exit 1).
    Device(String),
    /// Bad input: arguments or a file (exit 2).
    Input(String),
}

impl fmt::Display for Fail {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Fail::Device(m) | Fail::Input(m) => f.write_str(m),
        }
    }
}

/// How long a reply may take beyond the time its frames take on the line (the gateway's own
/// delay, a busy PC, a TCP round trip).
const REPLY_MARGIN: Duration = Duration::from_millis(1000);

/// How long a request and its reply of `bytes` in all take at `baud` (11 bits a character:
/// start, 8 data, parity or a second stop bit, stop), plus [`REPLY_MARGIN`]: at 1200 bit/s a
/// 64-register reply alone takes 1.2 s.
pub fn reply_timeout(bytes: usize, baud: Option<u32>) -> Duration {
    let line = baud.filter(|&b| b > 0).map_or(Duration::ZERO, |b| {
        Duration::from_micros(bytes as u64 * 11 * 1_000_000 / u64::from(b))
    });
    REPLY_MARGIN + line
}

enum Wire {
    /// The port and its rate (bit/s).
    Rtu(Box<dyn SerialPort>, u32),
    Tcp(TcpStream, u16),
}

/// One connection to the gateway's PLC side.
pub struct Link {
    wire: Wire,
    /// The port or address, for messages.
    pub name: String,
}

/// A parity by name.
pub fn parity_of(name: &str) -> Option<Parity> {
    match name {
        "none" => Some(Parity::None),
        "odd" => Some(Parity::Odd),
        "even" => Some(Parity::Even),
        _ => None,
    }
}

impl Link {
    /// Modbus RTU on `path`.
    pub fn rtu(path: &str, baud: u32, parity: Parity) -> Result<Link, Fail> {
        let port = serialport::new(path, baud)
            .parity(parity)
            .timeout(Duration::from_millis(5))
            .open()
            .map_err(|e| {
                if e.description == nix::errno::Errno::ENOTTY.desc() {
                    Fail::Device(format!("{path}: not a serial port ({e})"))
                } else {
                    Fail::Device(format!("{path}: {e}"))
                }
            })?;
        Ok(Link {
            wire: Wire::Rtu(port, baud),
            name: path.to_string(),
        })
    }

    /// Modbus TCP to `addr` (HOST:PORT).
    pub fn tcp(addr: &str) -> Result<Link, Fail> {
        let sockets: Vec<_> = addr
            .to_socket_addrs()
            .map_err(|e| Fail::Input(format!("--tcp {addr}: not a HOST:PORT address ({e})")))?
            .collect();
        let mut last = None;
        for socket in sockets {
            match TcpStream::connect_timeout(&socket, Duration::from_secs(3)) {
                Ok(stream) => {
                    let _ = stream.set_nodelay(true);
                    return Ok(Link {
                        wire: Wire::Tcp(stream, 0),
                        name: addr.to_string(),
                    });
                }
                Err(e) => last = Some(e),
            }
        }
        Err(Fail::Device(match last {
            Some(e) => format!("{addr}: cannot connect ({e})"),
            None => format!("{addr}: no address"),
        }))
    }

    /// Whether it is a serial line (FC08 answers only there).
    pub fn is_rtu(&self) -> bool {
        matches!(self.wire, Wire::Rtu(..))
    }

    /// A new rate and parity on the serial line (after an APPLY that changed them).
    pub fn set_line(&mut self, baud: u32, parity: Parity) -> Result<(), Fail> {
        if let Wire::Rtu(port, rate) = &mut self.wire {
            port.set_baud_rate(baud)
                .and_then(|()| port.set_parity(parity))
                .map_err(|e| Fail::Device(format!("{}: {e}", self.name)))?;
            *rate = baud;
        }
        Ok(())
    }

    /// One request to `unit`: the reply's body after the function code, or its exception. The
    /// error is a sentence without the port's name.
    fn exchange(
        &mut self,
        unit: u8,
        request: &Request,
    ) -> Result<Result<Vec<u8>, Exception>, String> {
        let function = request.function();
        let mut frame = [0u8; 260];
        let len = request
            .emit(unit, &mut frame)
            .ok_or("request too long for a frame")?;
        let frame = frame.get(..len).unwrap_or(&[]);
        // The longest reply the request can get: registers read, device identification, or
        // an echo of 8 bytes.
        let reply_len = match request {
            Request::ReadHoldingRegisters { quantity, .. } => 5 + 2 * usize::from(*quantity),
            Request::ReadDeviceId { .. } => 256,
            _ => 8,
        };
        match &mut self.wire {
            Wire::Rtu(port, baud) => {
                let timeout = reply_timeout(len + reply_len, Some(*baud));
                let _ = port.clear(ClearBuffer::Input);
                // t3.5 of silence before a frame, at any rate down to 9600 bit/s.
                std::thread::sleep(Duration::from_millis(4));
                port.write_all(frame).map_err(|e| e.to_string())?;
                let _ = port.flush();
                let reply = read_rtu(port.as_mut(), timeout)?;
                let adu = Adu::new_checked(&reply).map_err(|e| format!("{e} in the reply"))?;
                match client::answer(&adu, unit, function) {
                    Ok(Ok(body)) => Ok(Ok(body.to_vec())),
                    Ok(Err(exception)) => Ok(Err(exception)),
                    Err(e) => Err(format!("a reply that does not answer the request ({e:?})")),
                }
            }
            Wire::Tcp(stream, transaction) => {
                *transaction = transaction.wrapping_add(1);
                let pdu = frame.get(1..len.saturating_sub(2)).unwrap_or(&[]);
                let mut out = Vec::with_capacity(7 + pdu.len());
                out.extend_from_slice(&transaction.to_be_bytes());
                out.extend_from_slice(&[0, 0]);
                out.extend_from_slice(&(pdu.len() as u16 + 1).to_be_bytes());
                out.push(unit);
                out.extend_from_slice(pdu);
                stream.write_all(&out).map_err(|e| e.to_string())?;
                let timeout = reply_timeout(len + reply_len, None);
                let deadline = Instant::now() + timeout;
                loop {
                    let mut header = [0u8; 7];
                    read_exact_by(stream, &mut header, deadline, timeout)?;
                    let [t0, t1, p0, p1, l0, l1, reply_unit] = header;
                    let length = usize::from(u16::from_be_bytes([l0, l1]));
                    if !(2..=254).contains(&length) {
                        return Err(format!("an MBAP header with length {length}"));
                    }
                    let mut body = vec![0u8; length - 1];
                    read_exact_by(stream, &mut body, deadline, timeout)?;
                    if u16::from_be_bytes([t0, t1]) != *transaction || [p0, p1] != [0, 0] {
                        continue; // a late reply to an earlier request
                    }
                    if reply_unit != unit {
                        return Err(format!("a reply from unit {reply_unit}"));
                    }
                    return pdu_answer(&body, function);
                }
            }
        }
    }
}

/// The body of a reply PDU to `function`, or its exception.
fn pdu_answer(pdu: &[u8], function: u8) -> Result<Result<Vec<u8>, Exception>, String> {
    match pdu.split_first() {
        Some((&f, rest)) if f == function => Ok(Ok(rest.to_vec())),
        Some((&f, rest)) if f == function | 0x80 => rest
            .first()
            .and_then(|&c| Exception::from_code(c))
            .map(Err)
            .ok_or_else(|| "a malformed exception reply".to_string()),
        _ => Err("a reply for another function".to_string()),
    }
}

fn read_exact_by(
    stream: &mut TcpStream,
    buf: &mut [u8],
    deadline: Instant,
    timeout: Duration,
) -> Result<(), String> {
    let mut got = 0;
    while got < buf.len() {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(format!("no reply within {} ms", timeout.as_millis()));
        }
        let _ = stream.set_read_timeout(Some(left));
        match stream.read(buf.get_mut(got..).unwrap_or(&mut [])) {
            Ok(0) => return Err("the connection was closed by the gateway".into()),
            Ok(n) => got += n,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(e) => return Err(e.to_string()),
        }
    }
    Ok(())
}

/// The length of an RTU reply from its first bytes, if they tell it.
fn rtu_len(buf: &[u8]) -> Option<usize> {
    let function = *buf.get(1)?;
    if function & 0x80 != 0 {
        return Some(5);
    }
    match function {
        1..=4 | 0x11 => buf.get(2).map(|&n| 3 + usize::from(n) + 2),
        5 | 6 | 8 | 0x0F | 0x10 => Some(8),
        _ => None,
    }
}

/// One reply: until its length is there, or (a function whose length the first bytes do not
/// tell) a silence of 30 ms after the last byte.
fn read_rtu(port: &mut dyn SerialPort, timeout: Duration) -> Result<Vec<u8>, String> {
    let deadline = Instant::now() + timeout;
    let mut reply = Vec::new();
    let mut last_byte = Instant::now();
    let mut buf = [0u8; 256];
    loop {
        if let Some(len) = rtu_len(&reply) {
            if reply.len() >= len {
                reply.truncate(len);
                return Ok(reply);
            }
        } else if !reply.is_empty() && last_byte.elapsed() > Duration::from_millis(30) {
            return Ok(reply);
        }
        if Instant::now() > deadline {
            return Err(if reply.is_empty() {
                format!("no reply within {} ms", timeout.as_millis())
            } else {
                format!("an incomplete reply ({} bytes)", reply.len())
            });
        }
        match port.read(&mut buf) {
            Ok(n) => {
                reply.extend_from_slice(buf.get(..n).unwrap_or(&[]));
                last_byte = Instant::now();
            }
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(e) => return Err(e.to_string()),
        }
    }
}

/// The gateway: its own unit and its axes' units.
pub struct Gw {
    pub link: Link,
    /// The gateway unit.
    pub unit: u8,
    /// The unit of axis 0.
    pub base: u8,
}

/// A register's name from the map.
pub fn register_name(gateway: bool, address: u16) -> Option<&'static str> {
    let kind = if gateway { Unit::Gateway } else { Unit::Axis };
    map::MAP
        .iter()
        .find(|e| {
            e.unit == kind
                && address
                    .checked_sub(e.address)
                    .is_some_and(|offset| offset < e.count)
        })
        .map(|e| e.name)
}

impl Gw {
    /// "PORT unit U register 0xAAAA (NAME)".
    pub fn at(&self, unit: u8, address: u16) -> String {
        let name = register_name(unit == self.unit, address)
            .map(|n| format!(" ({n})"))
            .unwrap_or_default();
        format!(
            "{} unit {unit} register {address:#06x}{name}",
            self.link.name
        )
    }

    /// The unit of axis `axis`.
    pub fn axis_unit(&self, axis: u8) -> u8 {
        self.base.saturating_add(axis)
    }

    fn call(
        &mut self,
        unit: u8,
        address: u16,
        request: &Request,
    ) -> Result<Result<Vec<u8>, Exception>, Fail> {
        self.link.exchange(unit, request).map_err(|e| {
            let hint = if e.starts_with("no reply") {
                ": check the port, the rate and parity, and the gateway's unit id (--unit)"
            } else {
                ""
            };
            Fail::Device(format!("{}: {e}{hint}", self.at(unit, address)))
        })
    }

    /// Registers, or the exception the gateway answered.
    pub fn try_read(
        &mut self,
        unit: u8,
        address: u16,
        quantity: u16,
    ) -> Result<Result<Vec<u16>, Exception>, Fail> {
        let request = Request::ReadHoldingRegisters { address, quantity };
        Ok(match self.call(unit, address, &request)? {
            Ok(body) => {
                let values: Vec<u16> = client::registers(&body).collect();
                if values.len() != usize::from(quantity) {
                    return Err(Fail::Device(format!(
                        "{}: {} registers in the reply, {quantity} asked",
                        self.at(unit, address),
                        values.len()
                    )));
                }
                Ok(values)
            }
            Err(e) => Err(e),
        })
    }

    /// Registers of a unit the gateway may not serve (an axis unit before an APPLY, or a pending
    /// AXISBASE): `None` when it is not served (exception 0A or 02, or no reply on a serial
    /// line, where the gateway stays silent for a unit it does not serve).
    pub fn probe(
        &mut self,
        unit: u8,
        address: u16,
        quantity: u16,
    ) -> Result<Option<Vec<u16>>, Fail> {
        let request = Request::ReadHoldingRegisters { address, quantity };
        let body = match self.link.exchange(unit, &request) {
            Err(e) if e.starts_with("no reply") => return Ok(None),
            Err(e) => return Err(Fail::Device(format!("{}: {e}", self.at(unit, address)))),
            Ok(Err(Exception::GatewayPathUnavailable | Exception::IllegalDataAddress)) => {
                return Ok(None)
            }
            Ok(Err(e)) => return Err(Fail::Device(format!("{}: {e}", self.at(unit, address)))),
            Ok(Ok(body)) => body,
        };
        let values: Vec<u16> = client::registers(&body).collect();
        if values.len() != usize::from(quantity) {
            return Err(Fail::Device(format!(
                "{}: {} registers in the reply, {quantity} asked",
                self.at(unit, address),
                values.len()
            )));
        }
        Ok(Some(values))
    }

    /// Registers; an exception is an error.
    pub fn read(&mut self, unit: u8, address: u16, quantity: u16) -> Result<Vec<u16>, Fail> {
        self.try_read(unit, address, quantity)?
            .map_err(|e| Fail::Device(format!("{}: {e}", self.at(unit, address))))
    }

    /// Registers, waiting out exception 04 (no data yet) for at most `limit`.
    pub fn read_wait(
        &mut self,
        unit: u8,
        address: u16,
        quantity: u16,
        limit: Duration,
    ) -> Result<Vec<u16>, Fail> {
        let deadline = Instant::now() + limit;
        loop {
            match self.try_read(unit, address, quantity)? {
                Ok(values) => return Ok(values),
                Err(Exception::ServerDeviceFailure) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(20));
                }
                Err(e) => {
                    return Err(Fail::Device(format!(
                        "{}: {e} (for {} ms)",
                        self.at(unit, address),
                        limit.as_millis()
                    )))
                }
            }
        }
    }

    /// One register of the gateway unit.
    pub fn get(&mut self, address: u16) -> Result<u16, Fail> {
        let unit = self.unit;
        Ok(self
            .read(unit, address, 1)?
            .first()
            .copied()
            .unwrap_or_default())
    }

    /// Registers written (FC06 for one, FC10 for more), or the exception answered.
    pub fn try_write(
        &mut self,
        unit: u8,
        address: u16,
        values: &[u16],
    ) -> Result<Result<(), Exception>, Fail> {
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
        let request = match values {
            &[value] => Request::WriteSingleRegister { address, value },
            _ => Request::WriteMultipleRegisters {
                address,
                values: &bytes,
            },
        };
        Ok(self.call(unit, address, &request)?.map(|_| ()))
    }

    /// Registers written; an exception is an error.
    pub fn write(&mut self, unit: u8, address: u16, values: &[u16]) -> Result<(), Fail> {
        self.try_write(unit, address, values)?.map_err(|e| {
            Fail::Device(format!(
                "{}: {e} writing {}",
                self.at(unit, address),
                values
                    .iter()
                    .map(|v| v.to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ))
        })
    }

    /// One register of the gateway unit written.
    pub fn set(&mut self, address: u16, value: u16) -> Result<(), Fail> {
        let unit = self.unit;
        self.write(unit, address, &[value])
    }

    /// An FC08 counter or the diagnostic register (serial line only).
    pub fn diagnostic(&mut self, sub: Diagnostic) -> Result<u16, Fail> {
        let unit = self.unit;
        let request = Request::Diagnostic { sub, data: 0 };
        match self.call(unit, 0, &request)? {
            Ok(body) => match *body.as_slice() {
                [_, _, hi, lo] => Ok(u16::from_be_bytes([hi, lo])),
                _ => Err(Fail::Device(format!(
                    "{} unit {unit}: a malformed FC08 reply",
                    self.link.name
                ))),
            },
            Err(e) => Err(Fail::Device(format!(
                "{} unit {unit}: FC08 sub-function {:02X}: {e}",
                self.link.name, sub as u16
            ))),
        }
    }

    /// The device identification objects (FC2B/0E, regular: 00-05).
    pub fn identity(&mut self) -> Result<Vec<(u8, String)>, Fail> {
        let unit = self.unit;
        let mut objects = Vec::new();
        let mut next = 0u8;
        for _ in 0..8 {
            let request = Request::ReadDeviceId {
                code: protocol::modbus::ReadDevId::Regular,
                object: next,
            };
            let body = self.call(unit, 0, &request)?.map_err(|e| {
                Fail::Device(format!("{} unit {unit}: FC2B/0E: {e}", self.link.name))
            })?;
            // MEI type, code, conformity, more follows, next object, count, objects.
            let malformed = || {
                Fail::Device(format!(
                    "{} unit {unit}: a malformed FC2B reply",
                    self.link.name
                ))
            };
            let more = *body.get(3).ok_or_else(malformed)?;
            next = *body.get(4).ok_or_else(malformed)?;
            let count = *body.get(5).ok_or_else(malformed)?;
            let mut at = 6;
            for _ in 0..count {
                let id = *body.get(at).ok_or_else(malformed)?;
                let len = usize::from(*body.get(at + 1).ok_or_else(malformed)?);
                let text = body.get(at + 2..at + 2 + len).ok_or_else(malformed)?;
                objects.push((id, String::from_utf8_lossy(text).into_owned()));
                at += 2 + len;
            }
            if more == 0 {
                break;
            }
        }
        Ok(objects)
    }
}
