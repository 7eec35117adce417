//! The command channel on the gateway unit (REQ at 0x0200, RESP at 0x0210): point-table fields
//! read and written one at a time, with ROBONET's five-step handshake (field research §2):
//! 1. the PLC writes a request while the response is 0;
//! 2. the gateway runs it;
//! 3. the gateway posts the response;
//! 4. the PLC clears the request (code 0);
//! 5. the gateway clears the response.
//!
//! Code 1 reads a field, code 2 writes it, in the register map's units: the position from home
//! and the band in 0.01 mm, the velocity in 0.01 mm/s, the acceleration in 0.01 G, converted
//! with the axis' AXISCFG and checked as the position table's registers are
//! ([`table::field_to_plc`], [`table::field_from_plc`]): a value out of range (a position
//! outside 0..stroke) refuses the request's write with 03, as a table row is refused, and nothing
//! reaches the bus. A field without a unit is the same in any code. Code 3 reads a field as the
//! controller stores it (pulses, 0.2 rpm, 0.1 rpm/ms); there is no raw write, so every value
//! the channel stores is checked.
//!
//! A write reads the point first and skips the write when the controller already holds the value
//! it would store (RESP word 4 = 0xFFFF), so its non-volatile memory (about 100,000 writes per
//! area) is never worn by unchanged data. The response's value is the field as the controller
//! holds it after the request, in the request's units: a write of a value the controller cannot
//! hold exactly answers the nearest one it holds.

use super::command::Reason;
use super::config::{AxisConfig, GatewayConfig};
use super::map::{CHANNEL, G_REQUEST, G_REQUEST_LEN, G_RESPONSE, G_RESPONSE_LEN};
use super::refused::Refused;
use super::registers::{join, split};
use super::table;
use crate::axes::AxisMap;
use crate::engine::{Engine, Job, JobError, JobId, JobKind, JobOutput};
use crate::memory::PointField;
use crate::{Address, Axis, PositionNo};

/// Registers of the request block: code, axis, point, field, value high, value low.
pub(super) const REQ_LEN: usize = G_REQUEST_LEN as usize;
/// Registers of the response block: code, error, value high, value low, V5 write count.
pub(super) const RESP_LEN: usize = G_RESPONSE_LEN as usize;

/// Request code: read a field, in the register map's units.
const READ_FIELD: u16 = 1;
/// Request code: write a field, in the register map's units, checked.
const WRITE_FIELD: u16 = 2;
/// Request code: read a field as the controller stores it.
const READ_RAW: u16 = 3;
/// In RESP word 4: the write was skipped because the value was already stored (no V5 spent).
const UNCHANGED: u16 = 0xFFFF;
/// In RESP word 0: the request failed (word 1 says why, as CMER).
const FAILED: u16 = 0x8000;

type Request = [u16; REQ_LEN];

/// What a checked request starts: the axis, the point and the value a write stores (in the
/// controller's units; 0 for a read).
pub(super) type Start = (Axis, PositionNo, u32);

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
enum State {
    #[default]
    Idle,
    /// Reading the point (every code starts so: a write compares first), for this request;
    /// the value a write stores, in the controller's units.
    Reading(JobId, Request, u32),
    /// Writing the field, for this request: the value stored.
    Writing(JobId, Request, u32),
    /// Response posted; waiting for the PLC to clear the request.
    Answered,
}

/// The command channel.
#[derive(Clone, Copy, Debug)]
pub(super) struct Channel {
    request: Request,
    response: [u16; RESP_LEN],
    state: State,
}

/// The point field a request names: its offset from 0x400.
fn field(offset: u16) -> Option<PointField> {
    PointField::from_address(Address(0x400 + u32::from(offset)))
}

impl Channel {
    pub(super) const fn new() -> Channel {
        Channel {
            request: [0; REQ_LEN],
            response: [0; RESP_LEN],
            state: State::Idle,
        }
    }

    /// REQ or RESP register `address`, if it is one.
    pub(super) fn read(&self, address: u16) -> Option<u16> {
        if !CHANNEL {
            return None;
        }
        let at = |base: u16, block: &[u16]| {
            address
                .checked_sub(base)
                .and_then(|i| block.get(usize::from(i)))
                .copied()
        };
        at(G_REQUEST, &self.request).or_else(|| at(G_RESPONSE, &self.response))
    }

    /// The request block as it stands (a write changes a copy of it, which [`check`] and
    /// [`store`] take).
    ///
    /// [`check`]: Channel::check
    /// [`store`]: Channel::store
    pub(super) fn request(&self) -> Request {
        self.request
    }

    /// Check a new request block before anything is stored: the axis and point it would
    /// start on and the value a write stores (in the controller's units), if it starts
    /// something. Step 1 requires the response to be clear: a request while one runs or is
    /// answered is refused with 04.
    pub(super) fn check(
        &self,
        request: Request,
        config: &GatewayConfig,
    ) -> Result<Option<Start>, Refused> {
        let [code, axis, point, offset, hi, lo] = request;
        if code == 0 {
            return Ok(None);
        }
        if request == self.request && !matches!(self.state, State::Idle) {
            // The same request written again while it runs or is answered: nothing new.
            return Ok(None);
        }
        if !matches!(self.state, State::Idle) || self.response[0] != 0 {
            return Err(Refused::Busy);
        }
        let axis = u8::try_from(axis)
            .ok()
            .and_then(Axis::new)
            .filter(|&a| config.bus.axes.contains(a))
            .ok_or(Refused::OutOfRange)?;
        let point = u8::try_from(point)
            .ok()
            .and_then(PositionNo::new)
            .ok_or(Refused::OutOfRange)?;
        let field = field(offset).ok_or(Refused::OutOfRange)?;
        let value = match code {
            READ_FIELD | READ_RAW => 0,
            WRITE_FIELD => table::field_from_plc(field, join(hi, lo), &config.settings.axes[axis])?,
            _ => return Err(Refused::OutOfRange),
        };
        Ok(Some((axis, point, value)))
    }

    /// Store the checked request block and act on it: start a request, or step 4 -> 5.
    pub(super) fn store(
        &mut self,
        request: Request,
        start: Option<Start>,
        engine: &mut Engine,
    ) -> Result<(), Refused> {
        let Some((axis, point, value)) = start else {
            self.request = request;
            if request[0] == 0 && matches!(self.state, State::Answered) {
                // Step 4 -> 5: the PLC cleared its request, the gateway clears the response.
                self.response = [0; RESP_LEN];
                self.state = State::Idle;
            }
            return Ok(());
        };
        if !engine.online(axis) {
            return Err(Refused::Offline);
        }
        let id = engine
            .submit(Job {
                axis,
                kind: JobKind::ReadPoint(point),
            })
            .map_err(|_| Refused::QueueFull)?;
        self.request = request;
        self.state = State::Reading(id, request, value);
        Ok(())
    }

    /// A job finished: the next step if it is the channel's. Returns the point a write was
    /// submitted to (its cached row is stale from now on).
    pub(super) fn job_done(
        &mut self,
        id: JobId,
        result: &Result<JobOutput, JobError>,
        config: &AxisMap<AxisConfig>,
        engine: &mut Engine,
    ) -> Option<(Axis, PositionNo)> {
        if !CHANNEL {
            // A build without the channel never starts a job (`Channel::store` is not called
            // there): said here too, so that such a build has none of this code (520 B of the
            // F103's flash).
            return None;
        }
        let (request, wanted) = match self.state {
            State::Reading(r, request, wanted) | State::Writing(r, request, wanted) if r == id => {
                (request, wanted)
            }
            _ => return None,
        };
        if self.request != request {
            // The PLC cleared (or changed) its request while it ran: drop the result, and never
            // write on behalf of a request that is gone.
            self.state = State::Idle;
            return None;
        }
        let [code, axis, point, offset, _, _] = request;
        let unexpected = Reason::Unexpected.code(0);
        // The response, or the CMER code it fails with: posted in one place.
        let response: Result<[u16; RESP_LEN], u16> = 'response: {
            let (Some(field), Some(axis), Some(point)) = (
                field(offset),
                u8::try_from(axis).ok().and_then(Axis::new),
                u8::try_from(point).ok().and_then(PositionNo::new),
            ) else {
                break 'response Err(unexpected);
            };
            // A value as the controller holds it, in the request's units.
            let shown = |stored: u32| match code {
                READ_RAW => split(stored),
                _ => split(table::field_to_plc(field, stored, &config[axis])),
            };
            match (self.state, result) {
                (State::Reading(..), Ok(JobOutput::Point(readback))) => {
                    let stored = readback.get(field);
                    if code != WRITE_FIELD || stored == wanted {
                        let count = if code == WRITE_FIELD { UNCHANGED } else { 0 };
                        let [h, l] = shown(stored);
                        break 'response Ok([code, 0, h, l, count]);
                    }
                    let job = Job {
                        axis,
                        kind: JobKind::WriteField {
                            point,
                            field,
                            value: wanted,
                        },
                    };
                    match engine.submit(job) {
                        Ok(w) => {
                            self.state = State::Writing(w, request, wanted);
                            return Some((axis, point));
                        }
                        Err(_) => Err(Reason::QueueFull.code(0)),
                    }
                }
                (State::Writing(..), Ok(output)) => {
                    let count = match output {
                        JobOutput::Value(v) => u16::try_from(*v).unwrap_or(u16::MAX - 1),
                        _ => 0,
                    };
                    let [h, l] = shown(wanted);
                    Ok([code, 0, h, l, count])
                }
                (_, Err(e)) => Err(Reason::of(*e)),
                _ => Err(unexpected),
            }
        };
        self.response = match response {
            Ok(response) => response,
            Err(error) => [code | FAILED, error, 0, 0, 0],
        };
        self.state = State::Answered;
        None
    }
}

#[cfg(test)]
mod tests {
    use super::super::map::CHANNEL;
    use super::super::map::{G_REQUEST, G_RESPONSE};
    use super::super::{Gateway, GatewayConfig};
    use crate::modbus::{DataModel, Exception, RegisterTable, SlaveCounters};
    use crate::time::Instant;
    use crate::AxisSet;

    /// With the channel, its blocks read and a request is taken; without it (the F103's build)
    /// they do not exist: 02, nothing stored.
    #[test]
    fn the_channel_registers_exist_only_with_the_channel() {
        let mut gateway = Gateway::new(
            GatewayConfig::new(AxisSet::first(1)),
            &crate::plc::IDENTITY,
            crate::plc::Boot::DEFAULT,
        );
        let mut registers = gateway.registers(Instant::ZERO, SlaveCounters::default());
        let mut out = [0u16; 1];
        let read = registers.read_registers(63, RegisterTable::Holding, G_RESPONSE, &mut out);
        let write = registers.write_registers(63, G_REQUEST, &[0]);
        if CHANNEL {
            assert_eq!((read, write), (Ok(()), Ok(())));
        } else {
            let missing = Err(Exception::IllegalDataAddress);
            assert_eq!((read, write), (missing, missing));
        }
    }
}
