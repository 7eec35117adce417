//! The serial-line functions a Modbus master expects of a slave beyond the data tables:
//! FC08 diagnostics (Serial Line §6.1, Application Protocol §6.8), FC11 Report Server ID
//! (§6.13) and FC2B/0E Read Device Identification (§6.21), each byte by byte, with their
//! exceptions; then the gateway's own answers through the Node.

#![allow(clippy::inconsistent_digit_grouping)]

mod support;

use protocol::modbus::{
    client, crc, Adu, BitTable, Bits, BitsMut, DataModel, Diagnostic, Exception, Handled, Identity,
    ReadDevId, RegisterTable, ReplyBuffer, Request, Slave,
};
use protocol::plc::{diagnostic, map::*};
use support::*;

const ID: Identity = Identity {
    vendor_name: "ACME",
    product_code: "GW-1",
    revision: "2.5.1",
    vendor_url: "http://acme.example",
    product_name: "Gateway",
    model_name: "Model 7",
};

/// Unit 5: one holding register, an identity, a diagnostic register of 0xA5A5.
#[derive(Default)]
struct One {
    register: u16,
}

impl DataModel for One {
    fn serves(&self, unit: u8) -> bool {
        unit == 5
    }
    fn read_bits(&mut self, _: u8, _: BitTable, _: u16, _: &mut BitsMut) -> Result<(), Exception> {
        Err(Exception::IllegalFunction)
    }
    fn read_registers(
        &mut self,
        _: u8,
        _: RegisterTable,
        address: u16,
        out: &mut [u16],
    ) -> Result<(), Exception> {
        match (address, out) {
            (0, [slot]) => {
                *slot = self.register;
                Ok(())
            }
            _ => Err(Exception::IllegalDataAddress),
        }
    }
    fn write_bits(&mut self, _: u8, _: u16, _: Bits) -> Result<(), Exception> {
        Err(Exception::IllegalFunction)
    }
    fn write_registers(&mut self, _: u8, address: u16, values: &[u16]) -> Result<(), Exception> {
        match (address, values) {
            (0, [value]) => {
                self.register = *value;
                Ok(())
            }
            _ => Err(Exception::IllegalDataAddress),
        }
    }
    fn diagnostic_register(&self, _: u8) -> u16 {
        0xA5A5
    }
    fn identity(&self, _: u8) -> Option<Identity> {
        Some(ID)
    }
}

struct Line {
    slave: Slave,
    model: One,
    reply: ReplyBuffer,
}

impl Line {
    fn new() -> Line {
        Line {
            slave: Slave::new(),
            model: One::default(),
            reply: ReplyBuffer::new(),
        }
    }

    /// Hand a whole frame (CRC added) to the slave: the reply's bytes, if any.
    fn raw(&mut self, unit: u8, pdu: &[u8]) -> Option<Vec<u8>> {
        let mut frame = vec![unit];
        frame.extend_from_slice(pdu);
        frame.extend_from_slice(&crc::to_wire(crc::checksum(&frame)));
        let adu = Adu::new_checked(&frame).unwrap();
        match self.slave.handle(&adu, &mut self.model, &mut self.reply) {
            Handled::Reply(_) => Some(self.reply.as_bytes().to_vec()),
            _ => None,
        }
    }

    fn send(&mut self, unit: u8, request: &Request) -> Option<Result<Vec<u8>, Exception>> {
        let mut buf = [0u8; 256];
        let len = request.emit(unit, &mut buf).unwrap();
        let pdu = &buf[1..len - 2];
        let reply = self.raw(unit, pdu)?;
        let adu = Adu::new_checked(&reply).unwrap();
        Some(
            client::answer(&adu, unit, request.function())
                .unwrap()
                .map(<[u8]>::to_vec),
        )
    }

    fn count(&mut self, sub: Diagnostic) -> u16 {
        let body = self
            .send(5, &Request::Diagnostic { sub, data: 0 })
            .unwrap()
            .unwrap();
        assert_eq!(
            u16::from_be_bytes([body[0], body[1]]),
            sub.code(),
            "sub echoed"
        );
        u16::from_be_bytes([body[2], body[3]])
    }
}

fn read(quantity: u16) -> Request<'static> {
    Request::ReadHoldingRegisters {
        address: 0,
        quantity,
    }
}

#[test]
fn fc08_sub_functions_are_checked_as_the_spec_says() {
    let mut line = Line::new();
    let cases: [(&[u8], Exception); 7] = [
        (&[0x08, 0x00, 0x03, 0x00, 0x00], Exception::IllegalFunction), // ASCII delimiter
        (&[0x08, 0x00, 0x15, 0x00, 0x00], Exception::IllegalFunction), // undefined
        (&[0x08, 0x00, 0x0B, 0x12, 0x34], Exception::IllegalDataValue), // data not 0
        (&[0x08, 0x00, 0x01, 0x12, 0x34], Exception::IllegalDataValue), // restart data
        (
            &[0x08, 0x00, 0x0B, 0x00, 0x00, 0x00, 0x00],
            Exception::IllegalDataValue,
        ), // too long
        (&[0x08, 0x00, 0x0B, 0x00], Exception::IllegalDataValue),      // too short
        (&[0x08, 0x00], Exception::IllegalDataValue),                  // no sub-function
    ];
    for (pdu, exception) in cases {
        let reply = line.raw(5, pdu).expect("an exception reply");
        assert_eq!(&reply[1..3], &[0x88, exception.code()], "{pdu:02X?}");
    }
    // The restart accepts 0xFF00 (clear the event log too) as well as 0x0000.
    let reply = line.raw(5, &[0x08, 0x00, 0x01, 0xFF, 0x00]).unwrap();
    assert_eq!(&reply[1..6], &[0x08, 0x00, 0x01, 0xFF, 0x00], "echoed");
}

#[test]
fn fc08_counters_count_what_the_spec_defines_and_clear() {
    let mut line = Line::new();
    // 3 good requests, 1 exception, 1 for another unit, 1 broadcast, 1 malformed to us.
    for _ in 0..3 {
        assert!(line.send(5, &read(1)).unwrap().is_ok());
    }
    assert_eq!(
        line.send(5, &read(2)).unwrap(),
        Err(Exception::IllegalDataAddress)
    );
    assert!(line.raw(9, &[0x03, 0, 0, 0, 1]).is_none());
    assert!(line.raw(0, &[0x06, 0, 0, 0, 7]).is_none());
    assert!(line.raw(5, &[0x83, 0x02]).is_none());
    // Bus messages: every good frame so far (7) and this query itself.
    assert_eq!(line.count(Diagnostic::BusMessageCount), 8);
    assert_eq!(line.count(Diagnostic::BusExceptionErrorCount), 1);
    // Server messages: all but the other unit's, and the queries.
    assert_eq!(line.count(Diagnostic::ServerMessageCount), 6 + 3);
    // No response: the broadcast and the malformed one.
    assert_eq!(line.count(Diagnostic::ServerNoResponseCount), 2);
    assert_eq!(line.count(Diagnostic::ServerNakCount), 0);
    assert_eq!(line.count(Diagnostic::ServerBusyCount), 0);
    assert_eq!(line.count(Diagnostic::BusCommunicationErrorCount), 0);
    assert_eq!(line.count(Diagnostic::DiagnosticRegister), 0xA5A5);
    // Clear: everything counts from zero again (the clear's own reply aside).
    line.count(Diagnostic::ClearCounters);
    assert_eq!(
        line.count(Diagnostic::BusMessageCount),
        1,
        "just this query"
    );
    assert_eq!(line.count(Diagnostic::BusExceptionErrorCount), 0);
    assert_eq!(line.count(Diagnostic::ServerNoResponseCount), 0);
    // The PLC link's own (never cleared) counts are untouched.
    assert_eq!(line.slave.counters().illegal_data_address, 1);
}

#[test]
fn crc_errors_and_overruns_are_the_bus_error_counts() {
    use protocol::modbus::Receiver;
    use protocol::time::{Duration, Instant};
    let mut line = Line::new();
    let mut receiver = Receiver::new(115_200).without_gap_check();
    let mut now = Instant(0);
    let mut feed = |line: &mut Line, bytes: &[u8]| {
        for &b in bytes {
            receiver.push(now, b);
        }
        now = now + Duration::from_millis(5);
        let _ = line
            .slave
            .poll(&mut receiver, now, &mut line.model, &mut line.reply);
    };
    feed(&mut line, &[5, 3, 0, 0, 0, 1, 0xDE, 0xAD]); // bad CRC
    feed(&mut line, &[0x55; 300]); // longer than any frame
    feed(&mut line, &[0x55; 300]);
    assert_eq!(line.count(Diagnostic::BusCommunicationErrorCount), 1);
    assert_eq!(line.count(Diagnostic::BusCharacterOverrunCount), 2);
    line.count(Diagnostic::ClearOverrunCounter);
    assert_eq!(line.count(Diagnostic::BusCharacterOverrunCount), 0);
    assert_eq!(
        line.count(Diagnostic::BusCommunicationErrorCount),
        1,
        "not cleared"
    );
}

#[test]
fn listen_only_answers_and_does_nothing_until_a_restart() {
    let mut line = Line::new();
    let listen = Request::Diagnostic {
        sub: Diagnostic::ForceListenOnly,
        data: 0,
    };
    assert_eq!(line.send(5, &listen), None, "entering is not answered");
    assert!(line.slave.listen_only());
    assert_eq!(line.send(5, &read(1)), None);
    let write = Request::WriteSingleRegister {
        address: 0,
        value: 42,
    };
    assert_eq!(line.send(5, &write), None);
    assert_eq!(line.model.register, 0, "nothing carried out");
    // The restart leaves it, unanswered (it came in Listen Only mode).
    let restart = Request::Diagnostic {
        sub: Diagnostic::RestartCommunications,
        data: 0,
    };
    assert_eq!(line.send(5, &restart), None);
    assert!(!line.slave.listen_only());
    assert_eq!(line.send(5, &read(1)), Some(Ok(vec![2, 0, 0])));
    // Counters started afresh with the restart.
    assert_eq!(line.count(Diagnostic::ServerMessageCount), 2);
    // A restart outside Listen Only mode is echoed first.
    assert_eq!(line.send(5, &restart), Some(Ok(vec![0, 1, 0, 0])));
}

#[test]
fn report_server_id_and_read_device_identification() {
    let mut line = Line::new();
    let body = line.send(5, &Request::ReportServerId).unwrap().unwrap();
    let mut expected = vec![2 + 10, 5, 0xFF];
    expected.extend_from_slice(b"GW-1 2.5.1");
    assert_eq!(body, expected);
    let stream = |code, object| Request::ReadDeviceId { code, object };
    // Basic stream: objects 0-2.
    let body = line.send(5, &stream(ReadDevId::Basic, 0)).unwrap().unwrap();
    let mut expected = vec![0x0E, 0x01, 0x82, 0x00, 0x00, 3];
    for (id, value) in [(0u8, "ACME"), (1, "GW-1"), (2, "2.5.1")] {
        expected.push(id);
        expected.push(value.len() as u8);
        expected.extend_from_slice(value.as_bytes());
    }
    assert_eq!(body, expected);
    // Regular stream from object 4: 4 and 5.
    let body = line
        .send(5, &stream(ReadDevId::Regular, 4))
        .unwrap()
        .unwrap();
    assert_eq!(&body[..6], &[0x0E, 0x02, 0x82, 0x00, 0x00, 2]);
    assert_eq!(&body[6..8], &[4, 7]);
    // A stream from an object it does not have starts at 0.
    let body = line.send(5, &stream(ReadDevId::Basic, 9)).unwrap().unwrap();
    assert_eq!(body[5], 3);
    assert_eq!(body[6], 0);
    // Extended: there is nothing beyond the regular objects.
    let body = line
        .send(5, &stream(ReadDevId::Extended, 0))
        .unwrap()
        .unwrap();
    assert_eq!(body[5], 6);
    // One object; an unknown one is 02.
    let body = line
        .send(5, &stream(ReadDevId::Individual, 5))
        .unwrap()
        .unwrap();
    assert_eq!(
        &body[5..],
        &[1, 5, 7, b'M', b'o', b'd', b'e', b'l', b' ', b'7']
    );
    assert_eq!(
        line.send(5, &stream(ReadDevId::Individual, 6)),
        Some(Err(Exception::IllegalDataAddress))
    );
    // Malformed requests: other MEI types 01, bad codes and lengths 03.
    let reply = line.raw(5, &[0x2B, 0x0D, 0x01, 0x00]).unwrap();
    assert_eq!(&reply[1..3], &[0xAB, 0x01]);
    let reply = line.raw(5, &[0x2B, 0x0E, 0x05, 0x00]).unwrap();
    assert_eq!(&reply[1..3], &[0xAB, 0x03]);
    let reply = line.raw(5, &[0x2B, 0x0E, 0x01]).unwrap();
    assert_eq!(&reply[1..3], &[0xAB, 0x03]);
    let reply = line.raw(5, &[0x11, 0x00]).unwrap();
    assert_eq!(&reply[1..3], &[0x91, 0x03]);
}

// ---------------------------------------------------------------- through the Node

#[test]
fn the_gateway_identifies_itself_on_every_unit() {
    let mut rig = Rig::ready(2, |_| {});
    for unit in [63, 1, 2] {
        let request = Request::ReadDeviceId {
            code: ReadDevId::Regular,
            object: 0,
        };
        let body = rig.modbus(unit, &request).unwrap().unwrap();
        assert_eq!(body[5], 6, "unit {unit}: six objects");
        let revision = env!("CARGO_PKG_VERSION");
        assert!(body
            .windows(revision.len())
            .any(|w| w == revision.as_bytes()));
    }
    // VERSION is the identity's revision.
    let v = rig.read(63, G_VERSION, 2).unwrap();
    let (major, minor, patch) = protocol::plc::IDENTITY.version();
    assert_eq!(v, [u16::from(major) << 8 | u16::from(minor), patch]);
    // The run indicator: on while all is well, off on a unit whose axis is offline.
    let id = rig.modbus(2, &Request::ReportServerId).unwrap().unwrap();
    assert_eq!(id[2], 0xFF);
    rig.bus.fake(1).silent = true;
    rig.run_for(300 * MS);
    let id = rig.modbus(2, &Request::ReportServerId).unwrap().unwrap();
    assert_eq!(id[2], 0x00, "axis 1 offline");
    let id = rig.modbus(63, &Request::ReportServerId).unwrap().unwrap();
    assert_eq!(id[2], 0xFF, "the gateway itself runs");
}

#[test]
fn the_diagnostic_register_says_what_needs_attention() {
    let mut rig = Rig::ready(2, |_| {});
    let register = |rig: &mut Rig, unit: u8| {
        let request = Request::Diagnostic {
            sub: Diagnostic::DiagnosticRegister,
            data: 0,
        };
        let body = rig.modbus(unit, &request).unwrap().unwrap();
        u16::from_be_bytes([body[2], body[3]])
    };
    assert_eq!(register(&mut rig, 63), 0);
    rig.bus.fake(1).alarm = 0xD8;
    rig.run_for(50 * MS);
    assert_eq!(register(&mut rig, 63), diagnostic::ALARM);
    assert_eq!(register(&mut rig, 1), 0, "axis 0 is fine");
    assert_eq!(register(&mut rig, 2), diagnostic::ALARM);
    rig.node
        .set_stop_input(protocol::time::Instant(rig.now), true);
    assert_eq!(
        register(&mut rig, 63),
        diagnostic::ALARM | diagnostic::STOP_INPUT | diagnostic::STOPPED
    );
}

#[test]
fn listen_only_silences_the_node_but_keeps_the_watchdog_fed() {
    let mut rig = Rig::ready(1, |c| {
        c.settings.watchdog = protocol::plc::WatchdogTime::from_millis(300).unwrap()
    });
    let listen = Request::Diagnostic {
        sub: Diagnostic::ForceListenOnly,
        data: 0,
    };
    assert_eq!(rig.modbus(63, &listen), None);
    for _ in 0..5 {
        rig.run_for(100 * MS);
        let write = Request::WriteSingleRegister {
            address: POSR,
            value: 7,
        };
        assert_eq!(rig.modbus(1, &write), None, "not answered");
    }
    assert_eq!(rig.node.gateway().failsafe(), 0, "the PLC is alive");
    let restart = Request::Diagnostic {
        sub: Diagnostic::RestartCommunications,
        data: 0,
    };
    assert_eq!(rig.modbus(63, &restart), None);
    assert_eq!(
        rig.read(1, POSR, 1),
        Ok(vec![0]),
        "the writes were not carried out"
    );
}
