//! The commands that talk to the line directly rather than through the bus master: `scan`,
//! which asks every address at every rate once, and `sniff`, which only listens.

use std::time::{Duration, Instant};

use protocol::{Axis, Deframer, Packet, Reply, Request, Rtim};
use rc_tools::rcframe::describe;

use crate::{baud, report_text, Cli};

/// One status query to each axis at each rate, each answer awaited for the §5 response time-out
/// (no retries: a scan only asks who is there).
pub fn scan(cli: &Cli, rates: &[u32], rtim: Rtim) -> Result<(), String> {
    use std::io::{Read, Write};
    let rates: Vec<u32> = if rates.is_empty() {
        vec![9600, 19200, 38400, 57600, 115200]
    } else {
        rates.to_vec()
    };
    let mut port = serialport::new(&cli.port, cli.baud)
        .timeout(Duration::from_millis(2))
        .open()
        .map_err(|e| format!("{}: {e}", cli.port))?;
    let io = |e: std::io::Error| format!("{}: {e}", cli.port);
    let mut found = 0;
    println!("axis  baud    status");
    for bps in rates {
        let rate = baud(bps)?;
        port.set_baud_rate(bps)
            .map_err(|e| format!("{}: {e}", cli.port))?;
        let wait = protocol::engine::timing::frame_time(rate).plus(
            protocol::engine::timing::response_timeout(rate, rtim, false),
        );
        for axis in (0..16).filter_map(Axis::new) {
            let request = Request::new(axis, protocol::Command::Status);
            port.clear(serialport::ClearBuffer::Input)
                .map_err(|e| format!("{}: {e}", cli.port))?;
            port.write_all(&request.emit().to_bytes()).map_err(io)?;
            port.flush().map_err(io)?;
            let deadline = Instant::now() + Duration::from_micros(wait.as_micros());
            let mut deframer = Deframer::new();
            let mut buf = [0u8; 64];
            let mut answer = None;
            while answer.is_none() && Instant::now() < deadline {
                let n = match port.read(&mut buf) {
                    Ok(n) => n,
                    Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
                    Err(e) => return Err(io(e)),
                };
                for &byte in buf.get(..n).unwrap_or(&[]) {
                    if let Ok(Packet::Frame(frame)) = deframer.push(byte) {
                        if let Ok(reply) = Reply::parse(&frame) {
                            if reply.answers(&request).is_ok() {
                                answer = Some(reply);
                            }
                        }
                    }
                }
            }
            if let Some(reply) = answer {
                found += 1;
                let text = reply.report().map_or("answers".into(), report_text);
                println!("{:>4}  {bps:<6}  {text}", axis.get());
            }
        }
    }
    if found == 0 {
        return Err(
            "no axis answered at any rate (check the wiring: A/B, ground, termination, power)"
                .into(),
        );
    }
    Ok(())
}

pub fn sniff(cli: &Cli, seconds: Option<f64>) -> Result<(), String> {
    use std::io::Read;
    let mut port = serialport::new(&cli.port, cli.baud)
        .timeout(Duration::from_millis(50))
        .open()
        .map_err(|e| format!("{}: {e}", cli.port))?;
    let end = seconds.map(|s| Instant::now() + Duration::from_secs_f64(s.max(0.0)));
    let mut deframer = Deframer::new();
    let mut buf = [0u8; 256];
    while end.is_none_or(|end| Instant::now() < end) {
        let n = match port.read(&mut buf) {
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
            Err(e) => return Err(format!("{}: {e}", cli.port)),
        };
        for &byte in buf.get(..n).unwrap_or(&[]) {
            let Ok(packet) = deframer.push(byte) else {
                continue;
            };
            let object = match packet {
                Packet::Frame(frame) => match (Request::parse(&frame), Reply::parse(&frame)) {
                    (Ok(request), _) => describe::request(&request, &cli.scale),
                    (_, Ok(reply)) => describe::reply(&reply, &cli.scale),
                    (Err(e), Err(_)) => {
                        let mut o = describe::Object::new();
                        o.insert("error".into(), format!("{e:?}").into());
                        o
                    }
                },
                other => {
                    let mut o = describe::Object::new();
                    o.insert("packet".into(), format!("{other:?}").into());
                    o
                }
            };
            println!("{}", serde_json::Value::Object(object));
        }
    }
    Ok(())
}
