//! `rcframe decode`: one frame in detail, or a whole capture through the deframer.
//!
//! One frame is the 14 characters between STX and ETX, or a hex dump of its 16 bytes; its
//! fields are decoded even when its BCC is wrong. Anything else is a capture: hex bytes fed one
//! by one through [`Deframer`], which resynchronises over noise, one JSON line per candidate.

use crate::rcframe::describe::{self, Object};
use crate::rcframe::units::ScaleArgs;
use clap::Args;
use protocol::frame::{DATA_LEN, ENQ, ETX, FRAME_LEN, STX};
use protocol::{Axis, Deframer, Error, Frame, Packet, Reply, Request};
use serde_json::{json, Value};
use std::io::Read;
use std::path::PathBuf;

/// Characters between STX and ETX: the data and the two BCC digits.
const TEXT_LEN: usize = DATA_LEN + 2;

/// `rcframe decode [FRAME...] [--file F] [--summary] [scale options]`.
#[derive(Args, Debug)]
pub struct DecodeArgs {
    /// A frame (14 characters, or its 16 bytes in hex), a hex dump of several frames, or `-`
    /// to read a capture from standard input
    input: Vec<String>,
    /// Read a hex capture from this file
    #[arg(long, short, conflicts_with = "input")]
    file: Option<PathBuf>,
    /// In capture mode, end with {"summary": {"packets", "errors", "noise_bytes"}}
    #[arg(long)]
    summary: bool,
    #[command(flatten)]
    scale: ScaleArgs,
}

/// What the arguments ask to decode.
enum Input {
    /// The 14 (or, for an error report, however many) characters between STX and ETX.
    Text(Vec<u8>),
    /// Bytes of a capture.
    Capture(Vec<u8>),
}

/// Print the JSON lines; `Ok(true)` if everything decoded was valid. `Err` is bad input.
pub fn run(args: &DecodeArgs) -> Result<bool, String> {
    match input(args)? {
        Input::Text(text) => {
            let (obj, valid) = text_frame(&text, &args.scale);
            println!("{}", Value::from(obj));
            Ok(valid)
        }
        Input::Capture(bytes) => Ok(capture(&bytes, args)),
    }
}

fn input(args: &DecodeArgs) -> Result<Input, String> {
    let input = read_input(args)?;
    match input {
        Input::Capture(ref bytes) if bytes.is_empty() => {
            let source = match (&args.file, args.input.as_slice()) {
                (Some(path), _) => format!("{} holds", path.display()),
                (None, [dash]) if dash == "-" => "standard input holds".to_owned(),
                (None, _) => "the argument holds".to_owned(),
            };
            Err(format!(
                "nothing to decode: {source} no frame and no hex bytes (only blanks or # comments)"
            ))
        }
        input => Ok(input),
    }
}

fn read_input(args: &DecodeArgs) -> Result<Input, String> {
    if let Some(path) = &args.file {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        return parse_hex(&text)
            .map(Input::Capture)
            .map_err(|e| format!("{}: {e}", path.display()));
    }
    match args.input.as_slice() {
        [] => Err("nothing to decode: give a frame, a hex dump, `-` or --file".to_owned()),
        [dash] if dash == "-" => {
            let mut text = String::new();
            std::io::stdin()
                .read_to_string(&mut text)
                .map_err(|e| format!("cannot read standard input: {e}"))?;
            parse_hex(&text).map(Input::Capture)
        }
        words => classify(&words.join(" ")),
    }
}

/// One word of 14 characters is a frame as the documents print it, even if it is all hex
/// (`0aFFFF65430025`); one word that is not hex is a frame of the wrong length. The rest is hex:
/// exactly one frame's 16 bytes (02 ... 03) is decoded as a frame, anything else as a capture.
fn classify(joined: &str) -> Result<Input, String> {
    let trimmed = joined.trim();
    let one_word = !trimmed.contains(|c: char| c.is_whitespace() || c == ',');
    if one_word && trimmed.len() == TEXT_LEN {
        return Ok(Input::Text(trimmed.as_bytes().to_vec()));
    }
    let bytes = match parse_hex(trimmed) {
        Ok(bytes) => bytes,
        Err(_) if one_word => return Ok(Input::Text(trimmed.as_bytes().to_vec())),
        Err(e) => return Err(e),
    };
    match bytes.as_slice() {
        [STX, text @ .., ETX] if bytes.len() == FRAME_LEN => Ok(Input::Text(text.to_vec())),
        _ => Ok(Input::Capture(bytes)),
    }
}

/// Hex bytes: whitespace, commas and `0x` prefixes are allowed, `#` starts a comment.
pub fn parse_hex(text: &str) -> Result<Vec<u8>, String> {
    let mut bytes = Vec::new();
    for (number, line) in text.lines().enumerate() {
        let code = line.split_once('#').map_or(line, |(code, _)| code);
        let tokens = code
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|t| !t.is_empty());
        for token in tokens {
            push_token(token, &mut bytes).map_err(|e| format!("line {}: {e}", number + 1))?;
        }
    }
    Ok(bytes)
}

/// One token: `0x02`, `2`, `02`, or a run of digit pairs (`02306E`).
fn push_token(token: &str, bytes: &mut Vec<u8>) -> Result<(), String> {
    let digits = token
        .strip_prefix("0x")
        .or_else(|| token.strip_prefix("0X"))
        .unwrap_or(token);
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(format!("`{token}` is not hex"));
    }
    if digits.len() > 1 && digits.len() % 2 == 1 {
        return Err(format!("`{token}` has an odd number of hex digits"));
    }
    for pair in digits.as_bytes().chunks(2) {
        let pair = std::str::from_utf8(pair).map_err(|e| e.to_string())?;
        bytes.push(u8::from_str_radix(pair, 16).map_err(|e| format!("`{token}`: {e}"))?);
    }
    Ok(())
}

/// Decode the characters between STX and ETX; `true` if the BCC is right and the data valid.
fn text_frame(text: &[u8], scale: &ScaleArgs) -> (Object, bool) {
    if text == [ENQ; TEXT_LEN] {
        return (comm_change(), true);
    }
    let mut obj = Object::new();
    obj.insert("frame".into(), printable(text).into());
    let Ok(text) = <[u8; TEXT_LEN]>::try_from(text) else {
        let len = text.len().saturating_add(2);
        obj.insert(
            "error".into(),
            Error::WrongLength { len }.to_string().into(),
        );
        return (obj, false);
    };
    let mut data = [0; DATA_LEN];
    data.copy_from_slice(&text[..DATA_LEN]);
    let valid = data_fields(&Frame::from_data(data), scale, &mut obj);
    let bcc_ok = bcc_fields(&text, &mut obj);
    (obj, valid && bcc_ok)
}

/// The fields of the 12 data characters, whatever the BCC; `false` (and "error") if invalid.
fn data_fields(frame: &Frame, scale: &ScaleArgs, obj: &mut Object) -> bool {
    let data = frame.data();
    let response = data[0] == b'U';
    let decoded = if response {
        Reply::parse(frame).map(|reply| describe::reply(&reply, scale))
    } else {
        Request::parse(frame).map(|request| describe::request(&request, scale))
    };
    match decoded {
        Ok(fields) => {
            obj.extend(fields);
            true
        }
        Err(e) => {
            let axis_char = data[usize::from(response)];
            if let Ok(axis) = Axis::from_char(axis_char) {
                obj.insert("axis".into(), u8::from(axis).into());
            }
            let direction = if response { "response" } else { "request" };
            obj.insert("direction".into(), direction.into());
            obj.insert("error".into(), e.to_string().into());
            false
        }
    }
}

/// "bcc_ok", and when it is wrong the BCC expected and the two characters received.
fn bcc_fields(text: &[u8; TEXT_LEN], obj: &mut Object) -> bool {
    let mut bytes = [STX; FRAME_LEN];
    bytes[1..=TEXT_LEN].copy_from_slice(text);
    bytes[FRAME_LEN - 1] = ETX;
    let ok = Frame::new_checked(&bytes).is_ok();
    obj.insert("bcc_ok".into(), ok.into());
    if !ok {
        let mut data = [0; DATA_LEN];
        data.copy_from_slice(&text[..DATA_LEN]);
        let expected = format!("{:02X}", protocol::frame::bcc(&data));
        obj.insert("bcc_expected".into(), expected.into());
        obj.insert("bcc_received".into(), printable(&text[DATA_LEN..]).into());
    }
    ok
}

fn comm_change() -> Object {
    let mut obj = Object::new();
    obj.insert("packet".into(), "comm_change".into());
    obj
}

/// Text for people: printable ASCII as is, anything else as `\xNN`.
fn printable(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|&b| match b {
            0x20..=0x7E => char::from(b).to_string(),
            _ => format!("\\x{b:02X}"),
        })
        .collect()
}

/// What a capture contained.
#[derive(Default)]
struct Tally {
    packets: u32,
    errors: u32,
}

/// Feed every byte through the deframer, print a line per packet or rejected candidate.
fn capture(bytes: &[u8], args: &DecodeArgs) -> bool {
    let mut deframer = Deframer::new();
    let mut tally = Tally::default();
    for &byte in bytes {
        let line = match deframer.push(byte) {
            Err(protocol::nb::Error::WouldBlock) => continue,
            Ok(packet) => packet_line(packet, &args.scale, &mut tally),
            Err(protocol::nb::Error::Other(e)) => {
                rejected_line(deframer.rejected(), e, &args.scale, &mut tally)
            }
        };
        println!("{}", Value::from(line));
    }
    let counters = deframer.counters();
    if let Some(line) = unfinished(&deframer) {
        tally.errors += 1;
        println!("{}", Value::from(line));
    }
    if args.summary {
        let summary = json!({"summary": {
            "packets": counters.packets,
            "errors": tally.errors,
            "noise_bytes": counters.noise_bytes,
        }});
        println!("{summary}");
    }
    if tally.packets == 0 && tally.errors == 0 {
        // Nothing printed above: say why the exit status is 1.
        eprintln!(
            "rcframe: no frame in the capture's {} bytes (noise only)",
            bytes.len()
        );
    }
    tally.errors == 0 && tally.packets > 0
}

fn packet_line(packet: Packet, scale: &ScaleArgs, tally: &mut Tally) -> Object {
    tally.packets += 1;
    match packet {
        Packet::CommChange => comm_change(),
        Packet::Frame(frame) => {
            let (obj, valid) = text_frame(&frame.to_text(), scale);
            if !valid {
                tally.errors += 1;
            }
            obj
        }
    }
}

/// A candidate the deframer rejected: its fields if it is a whole frame, its bytes, the error.
fn rejected_line(bytes: &[u8], error: Error, scale: &ScaleArgs, tally: &mut Tally) -> Object {
    tally.errors += 1;
    let mut obj = Object::new();
    let mut errors = vec![error.to_string()];
    if let [STX, text @ .., ETX] = bytes {
        if bytes.len() == FRAME_LEN {
            let (fields, _) = text_frame(text, scale);
            obj.extend(fields);
        }
    }
    if let Some(Value::String(data_error)) = obj.remove("error") {
        errors.push(data_error);
    }
    obj.insert(
        "rejected".into(),
        crate::rcframe::encode::hex_bytes(bytes).into(),
    );
    obj.insert("error".into(), errors.join("; ").into());
    obj
}

/// The candidate still open when the capture ends (the deframer waits for more bytes).
fn unfinished(deframer: &Deframer) -> Option<Object> {
    let open = deframer.pending();
    let len = u8::try_from(open.len()).ok().filter(|&n| n > 0)?;
    let mut obj = Object::new();
    obj.insert(
        "rejected".into(),
        crate::rcframe::encode::hex_bytes(open).into(),
    );
    let error = format!("{} (end of input)", Error::Truncated { len });
    obj.insert("error".into(), error.into());
    Some(obj)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hex_with_comments_commas_and_prefixes() {
        let text = "# header\n02 0x30,6E # status\n30303030 3\n";
        assert_eq!(
            parse_hex(text),
            Ok(vec![0x02, 0x30, 0x6E, 0x30, 0x30, 0x30, 0x30, 0x03])
        );
        assert!(parse_hex("0x").is_err());
        assert!(parse_hex("123").is_err());
        assert!(parse_hex("zz").is_err());
    }

    #[test]
    fn classify_text_dump_and_capture() {
        assert!(matches!(classify("0aFFFF65430025"), Ok(Input::Text(t)) if t == b"0aFFFF65430025"));
        let dump = "02 30 6E 30 30 30 30 30 30 30 30 30 30 38 32 03";
        assert!(matches!(classify(dump), Ok(Input::Text(t)) if t == b"0n000000000082"));
        assert!(matches!(classify("0Q3010B00000089"), Ok(Input::Text(_))));
        assert!(matches!(classify("02 30 03 02"), Ok(Input::Capture(b)) if b.len() == 4));
        assert!(classify("02 zz").is_err());
    }
}
