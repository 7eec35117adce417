//! The master's side of an exchange, for tests and tools: a request is built with
//! [`Request::emit`](super::Request::emit); its reply is read here.

use super::adu::Adu;
use super::Exception;

/// Why a reply does not answer the request it was waited for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReplyError {
    /// From another unit.
    WrongUnit,
    /// For another function code.
    WrongFunction,
    /// An exception reply with a code this crate does not know, or too short.
    Malformed,
}

/// The body of a reply (after the function code) to a request for `unit` with `function`, or
/// the exception it carries.
pub fn answer<'a>(
    adu: &Adu<'a>,
    unit: u8,
    function: u8,
) -> Result<Result<&'a [u8], Exception>, ReplyError> {
    if adu.unit() != unit {
        return Err(ReplyError::WrongUnit);
    }
    let body = adu.pdu().get(1..).unwrap_or(&[]);
    if adu.function() == function | 0x80 {
        let code = body.first().copied().ok_or(ReplyError::Malformed)?;
        return Exception::from_code(code)
            .map(Err)
            .ok_or(ReplyError::Malformed);
    }
    if adu.function() != function {
        return Err(ReplyError::WrongFunction);
    }
    Ok(Ok(body))
}

/// The registers of an FC03/FC04 reply body (byte count, then big-endian words).
pub fn registers(body: &[u8]) -> impl Iterator<Item = u16> + '_ {
    body.get(1..)
        .unwrap_or(&[])
        .chunks_exact(2)
        .map(|pair| match *pair {
            [high, low] => u16::from_be_bytes([high, low]),
            _ => 0,
        })
}

/// The first `n` bits of an FC01/FC02 reply body (byte count, then packed bits).
pub fn bits(body: &[u8], n: usize) -> impl Iterator<Item = bool> + '_ {
    let bytes = body.get(1..).unwrap_or(&[]);
    (0..n).map(move |i| bytes.get(i / 8).is_some_and(|b| b >> (i % 8) & 1 != 0))
}
