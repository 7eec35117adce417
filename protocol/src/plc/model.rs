//! The gateway as the Modbus slave's [`DataModel`]: which unit a request is for, and that every
//! address of it exists, before anything is read, fetched or written.
//!
//! [`Registers`] is the gateway seen by one request: it carries the time the request arrived
//! (UPTIME, the fail-safe) and the PLC link's counters (PLCLINK), so that the gateway itself
//! never needs to be told either out of band.

use super::axis_unit::readable;
use super::gateway::Gateway;
use super::map::{DRG1, POSR};
use super::refused::Refused;
use super::table;
use super::write::{nth, AxisWrite};
use crate::modbus::{
    BitTable, Bits, BitsMut, DataModel, Exception, Identity, RegisterTable, SlaveCounters,
    BROADCAST,
};
use crate::time::Instant;

/// The gateway answering one Modbus request; see the module documentation (`protocol/src/plc/model.rs`).
#[derive(Debug)]
pub struct Registers<'a> {
    gateway: &'a mut Gateway,
    link: SlaveCounters,
    /// The TCP server's counters and connections (TCPLINK, TCPCONN).
    #[cfg(feature = "tcp")]
    tcp: TcpView,
}

/// What the gateway unit shows of the Modbus TCP server.
#[cfg(feature = "tcp")]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TcpView {
    /// Its counters.
    pub counters: crate::modbus::tcp::TcpCounters,
    /// Connections open now.
    pub connections: u8,
}

impl Gateway {
    /// The gateway as the data model of a Modbus request received at `now`; `link` is what
    /// the slave has counted so far (PLCLINK).
    pub fn registers(&mut self, now: Instant, link: SlaveCounters) -> Registers<'_> {
        self.now = now;
        Registers {
            gateway: self,
            link,
            #[cfg(feature = "tcp")]
            tcp: TcpView::default(),
        }
    }
}

#[cfg(feature = "tcp")]
impl Registers<'_> {
    /// The same request, with the TCP server's counters and connections to show.
    #[must_use]
    pub fn with_tcp(mut self, tcp: TcpView) -> Self {
        self.tcp = tcp;
        self
    }

    /// A register of the network block or TCPLINK, if `address` is one.
    fn tcp_read(&self, address: u16) -> Option<u16> {
        use super::map::{G_NET, G_NET_LEN, G_TCP, G_TCP_LEN};
        if let Some(offset) = address.checked_sub(G_NET).filter(|&o| o < G_NET_LEN) {
            return match offset {
                crate::net::registers::CONNECTIONS => Some(u16::from(self.tcp.connections)),
                _ => self.gateway.config.settings.net.register(offset),
            };
        }
        let offset = address.checked_sub(G_TCP).filter(|&o| o < G_TCP_LEN)?;
        let c = self.tcp.counters;
        let values = [
            c.accepted,
            c.refused,
            c.replaced,
            c.idle_closed,
            c.mbap_errors,
            c.frames,
        ];
        Some(super::gateway_unit::counter_register(&values, offset))
    }
}

/// FC08 sub-function 02, the diagnostic register: bits that say what needs attention.
pub mod diagnostic {
    /// FAILSAFE bit 0: the PLC watchdog tripped (latched).
    pub const WATCHDOG: u16 = 1 << 0;
    /// FAILSAFE bit 1: the stop input was activated (latched).
    pub const STOP_INPUT: u16 = 1 << 1;
    /// An axis (the unit's own, or any for the gateway unit) is offline.
    pub const OFFLINE: u16 = 1 << 2;
    /// An axis (the unit's own, or any) is in alarm.
    pub const ALARM: u16 = 1 << 3;
    /// The communication establishment (§6-1) is running.
    pub const ESTABLISHING: u16 = 1 << 4;
    /// The stop input is active now.
    pub const STOPPED: u16 = 1 << 5;
}

/// The one place a [`Refused`] becomes what a Modbus master sees: 02 for an address that is
/// not there, 03 for a value it cannot take, 04 for "not now" (ask again). (A write whose
/// command STP or the stop input holds is not refused: `Gateway::command_written`.)
fn exception(refused: Refused) -> Exception {
    match refused {
        Refused::NoSuchAddress => Exception::IllegalDataAddress,
        Refused::OutOfRange => Exception::IllegalDataValue,
        // (`Stopped` does not reach a Modbus answer: every write path takes a held command as
        // taken, `Gateway::command_written`; were it to, "not now" is what it means.)
        Refused::Offline
        | Refused::QueueFull
        | Refused::Busy
        | Refused::NotReady
        | Refused::Stopped => Exception::ServerDeviceFailure,
    }
}

/// A broadcast write (unit 0), parsed once and checked before any effect, then given to every
/// axis on the bus as if written to it alone: a stop in it is taken by each (owed by one that
/// does not answer), and the rest is judged per axis. It never ends early: an axis that
/// refuses (one that does not answer a command, a full queue) is counted (BUS, broadcast
/// refusals) and the next axis still gets the write. (A broadcast gets no reply.)
fn broadcast(
    gateway: &mut Gateway,
    write: Result<AxisWrite<'_>, Refused>,
) -> Result<(), Exception> {
    let write = write.map_err(exception)?;
    for axis in gateway.config.bus.axes.iter() {
        if gateway.axis_write(axis, &write).is_err() {
            gateway.broadcast_refusals = gateway.broadcast_refusals.wrapping_add(1);
        }
    }
    Ok(())
}

impl Registers<'_> {
    /// The axes a unit speaks for: its own, or all for the gateway unit.
    fn axes_of(&self, unit: u8) -> crate::AxisSet {
        let config = &self.gateway.config;
        match config.axis_of_unit(unit) {
            Some(axis) => crate::AxisSet::EMPTY.with(axis),
            None => config.bus.axes,
        }
    }
}

impl DataModel for Registers<'_> {
    fn diagnostic_register(&self, unit: u8) -> u16 {
        let gateway = &*self.gateway;
        let (offline, alarm) = gateway.trouble(self.axes_of(unit));
        let bit = |on: bool, mask: u16| if on { mask } else { 0 };
        gateway.failsafe.latched() & (diagnostic::WATCHDOG | diagnostic::STOP_INPUT)
            | bit(offline, diagnostic::OFFLINE)
            | bit(alarm, diagnostic::ALARM)
            | bit(gateway.engine().establishing(), diagnostic::ESTABLISHING)
            | bit(gateway.failsafe.stop_input(), diagnostic::STOPPED)
    }

    fn identity(&self, _unit: u8) -> Option<Identity> {
        Some(*self.gateway.identity)
    }

    /// The gateway unit runs unless the fail-safe is latched; an axis unit while its axis
    /// answers and is not in alarm.
    fn running(&self, unit: u8) -> bool {
        let gateway = &*self.gateway;
        match gateway.config.axis_of_unit(unit) {
            Some(axis) => {
                let state = gateway.engine().axis(axis);
                state.link == crate::engine::Link::Online
                    && !state.report.is_some_and(|r| r.outputs.alarm_active())
            }
            None => gateway.failsafe.latched() == 0,
        }
    }

    fn serves(&self, unit: u8) -> bool {
        let config = &self.gateway.config;
        unit == config.settings.unit.get() || config.axis_of_unit(unit).is_some()
    }

    fn read_bits(
        &mut self,
        unit: u8,
        table: BitTable,
        address: u16,
        out: &mut BitsMut<'_>,
    ) -> Result<(), Exception> {
        let gateway = &mut *self.gateway;
        let axis = gateway
            .config
            .axis_of_unit(unit)
            .ok_or(Exception::IllegalDataAddress)?;
        if table != BitTable::Coils {
            return Err(Exception::IllegalDataAddress);
        }
        for i in 0..out.len() {
            let a = nth(address, i).ok_or(Exception::IllegalDataAddress)?;
            out.set(i, gateway.axis_coil(axis, a).map_err(exception)?);
        }
        Ok(())
    }

    fn read_registers(
        &mut self,
        unit: u8,
        table: RegisterTable,
        address: u16,
        out: &mut [u16],
    ) -> Result<(), Exception> {
        let gateway = &mut *self.gateway;
        let axis = gateway.config.axis_of_unit(unit);
        if let Some(axis) = axis {
            // Every address must exist in this table before anything is fetched from the bus.
            let mut touches_table = false;
            for i in 0..out.len() {
                let a = nth(address, i).ok_or(Exception::IllegalDataAddress)?;
                let in_table = table::locate(a).is_some();
                touches_table |= in_table;
                if (in_table && table != RegisterTable::Holding)
                    || (!in_table && !readable(a, table))
                {
                    return Err(Exception::IllegalDataAddress);
                }
            }
            if touches_table && !gateway.table_rows_ready(axis, address, out.len()) {
                // Not read from the controller yet: it is being fetched; ask again shortly.
                return Err(exception(Refused::NotReady));
            }
        }
        // One loop for both kinds of unit.
        for (i, slot) in out.iter_mut().enumerate() {
            let a = nth(address, i).ok_or(Exception::IllegalDataAddress)?;
            #[cfg(feature = "tcp")]
            if axis.is_none() {
                if let Some(value) = self.tcp_read(a) {
                    *slot = value;
                    continue;
                }
            }
            let gateway = &mut *self.gateway;
            *slot = match axis {
                Some(axis) => gateway.axis_read(axis, a),
                None => gateway.gateway_read(a, &self.link),
            }
            .map_err(exception)?;
        }
        Ok(())
    }

    fn write_bits(&mut self, unit: u8, address: u16, values: Bits<'_>) -> Result<(), Exception> {
        let gateway = &mut *self.gateway;
        if unit == BROADCAST {
            return broadcast(gateway, AxisWrite::coils(address, values));
        }
        let axis = gateway
            .config
            .axis_of_unit(unit)
            .ok_or(Exception::IllegalDataAddress)?;
        AxisWrite::coils(address, values)
            .and_then(|write| gateway.axis_write(axis, &write))
            .map_err(exception)
    }

    fn write_registers(&mut self, unit: u8, address: u16, values: &[u16]) -> Result<(), Exception> {
        let gateway = &mut *self.gateway;
        if unit == BROADCAST {
            // DRG1 or POSR only. Not a direct move: travel differs between axes.
            let (DRG1 | POSR, [_]) = (address, values) else {
                return Err(Exception::IllegalDataAddress);
            };
            return broadcast(gateway, AxisWrite::registers(address, values));
        }
        match gateway.config.axis_of_unit(unit) {
            Some(axis) => AxisWrite::registers(address, values)
                .and_then(|write| gateway.axis_write(axis, &write)),
            None => gateway.gateway_write(address, values),
        }
        .map_err(exception)
    }
}
