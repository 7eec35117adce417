//! Bytes with timing through the Modbus RTU receiver and slave.
//!
//! Input: a control byte, then `(gap, byte)` pairs. The byte is received `gap / 128` t3.5 after
//! the previous one, so gaps below 55 are within a frame, 55..128 are between t1.5 and t3.5
//! (at 19200 baud and above) and 128 and more end the frame.
//!
//! Control bits: 0–2 baud rate; 3 "fix the CRC": before each frame-ending gap, and at the end,
//! the two CRC bytes of the burst so far are received first, so that the PDU decoder and the
//! slave see many valid frames; 4 turns the t1.5 check off; 5 polls only at the end, not
//! before each byte, which exercises overruns.
//!
//! Checks: nothing panics; every reply is a whole frame of at most 256 bytes with a valid CRC,
//! for the unit asked, with the function code or its exception; the model is only asked for
//! quantities and ranges within the Modbus limits; every burst is accounted for once. The raw
//! input is also decoded directly as a PDU (canonical if it parses) and, with a CRC appended,
//! as a frame.
#![no_main]

use libfuzzer_sys::fuzz_target;
use protocol::modbus::{
    crc, Adu, BitTable, Bits, BitsMut, DataModel, Exception, Handled, Identity, Receiver,
    RegisterTable, ReplyBuffer, Request, Slave,
};
use protocol::time::{Duration, Instant};

const BAUDS: [u32; 8] = [
    1_200, 4_800, 9_600, 19_200, 38_400, 57_600, 115_200, 230_400,
];
const SIZE: usize = 512;

/// A small model with every kind of answer: units 1, 0x11 and 247; 512 entries per table;
/// a register value of 0xDEAD is refused (03); writes to coils 500.. fail (04).
struct Model {
    coils: [bool; SIZE],
    discrete: [bool; SIZE],
    holding: [u16; SIZE],
    input: [u16; SIZE],
}

fn range(address: u16, len: usize, max: usize) -> Result<core::ops::Range<usize>, Exception> {
    assert!(
        (1..=max).contains(&len),
        "quantity {len} out of the Modbus limits"
    );
    let start = usize::from(address);
    assert!(start + len <= 0x1_0000, "range past 0xFFFF");
    if start + len <= SIZE {
        Ok(start..start + len)
    } else {
        Err(Exception::IllegalDataAddress)
    }
}

impl DataModel for Model {
    fn serves(&self, unit: u8) -> bool {
        assert_ne!(unit, 0);
        matches!(unit, 1 | 0x11 | 247)
    }

    fn read_bits(
        &mut self,
        _: u8,
        table: BitTable,
        address: u16,
        out: &mut BitsMut<'_>,
    ) -> Result<(), Exception> {
        let range = range(address, out.len(), 2000)?;
        let bits = match table {
            BitTable::Coils => &self.coils[range],
            BitTable::DiscreteInputs => &self.discrete[range],
        };
        for (i, &bit) in bits.iter().enumerate() {
            out.set(i, bit);
        }
        Ok(())
    }

    fn read_registers(
        &mut self,
        _: u8,
        table: RegisterTable,
        address: u16,
        out: &mut [u16],
    ) -> Result<(), Exception> {
        let range = range(address, out.len(), 125)?;
        out.copy_from_slice(match table {
            RegisterTable::Holding => &self.holding[range],
            RegisterTable::Input => &self.input[range],
        });
        Ok(())
    }

    fn write_bits(&mut self, _: u8, address: u16, values: Bits<'_>) -> Result<(), Exception> {
        let range = range(address, values.len(), 1968)?;
        if range.end > 500 {
            return Err(Exception::ServerDeviceFailure);
        }
        for (slot, bit) in self.coils[range].iter_mut().zip(values.iter()) {
            *slot = bit;
        }
        Ok(())
    }

    fn write_registers(&mut self, _: u8, address: u16, values: &[u16]) -> Result<(), Exception> {
        let range = range(address, values.len(), 123)?;
        if values.contains(&0xDEAD) {
            return Err(Exception::IllegalDataValue);
        }
        self.holding[range].copy_from_slice(values);
        Ok(())
    }

    /// Unit 0x11 identifies itself (FC11, FC2B/0E), the others answer those with 01.
    fn identity(&self, unit: u8) -> Option<Identity> {
        (unit == 0x11).then_some(Identity {
            vendor_name: "fuzz",
            product_code: "F-1",
            revision: "1.2.3",
            vendor_url: "",
            product_name: "a model under fuzzing",
            model_name: "M",
        })
    }

    fn diagnostic_register(&self, unit: u8) -> u16 {
        u16::from(unit)
    }
}

struct Harness {
    receiver: Receiver,
    slave: Slave,
    model: Model,
    reply: ReplyBuffer,
    polled: u32,
}

impl Harness {
    fn poll(&mut self, now: Instant) {
        if self
            .receiver
            .next_deadline()
            .is_none_or(|deadline| deadline > now)
        {
            assert!(self.receiver.poll(now).is_none());
            return;
        }
        // A copy, to deliver the frame again and know what was asked.
        let request = self.receiver.clone();
        let Some(result) =
            self.slave
                .poll(&mut self.receiver, now, &mut self.model, &mut self.reply)
        else {
            return;
        };
        self.polled += 1;
        let bytes = self.reply.as_bytes();
        match result {
            Ok(Handled::Reply(len)) => {
                let mut copy = request;
                let adu = copy.poll(now).unwrap().unwrap();
                check_reply(&adu, bytes, len);
            }
            Ok(_) | Err(_) => assert!(bytes.is_empty()),
        }
    }
}

fn check_reply(adu: &Adu<'_>, reply: &[u8], len: usize) {
    assert_eq!(reply.len(), len);
    assert!((5..=256).contains(&len), "reply of {len} bytes");
    assert!(crc::is_valid(reply));
    assert_eq!(reply[0], adu.unit());
    assert_ne!(adu.unit(), 0);
    if reply[1] == adu.function() | 0x80 {
        assert_eq!(len, 5);
        assert!(Exception::from_code(reply[2]).is_some());
    } else {
        assert_eq!(reply[1], adu.function());
    }
}

fn model() -> Model {
    let mut model = Model {
        coils: [false; SIZE],
        discrete: [false; SIZE],
        holding: [0; SIZE],
        input: [0; SIZE],
    };
    for i in 0..SIZE {
        model.discrete[i] = i % 3 == 0;
        model.input[i] = (i as u16).wrapping_mul(257);
    }
    model
}

fuzz_target!(|data: &[u8]| {
    let Some((&control, stream)) = data.split_first() else {
        return;
    };
    direct(stream);

    let baud = BAUDS[usize::from(control & 7)];
    let fix_crc = control & 0x08 != 0;
    let receiver = if control & 0x10 != 0 {
        Receiver::new(baud).without_gap_check()
    } else {
        Receiver::new(baud)
    };
    let poll_at_end_only = control & 0x20 != 0;
    let t35 = receiver.t3_5().as_micros();
    let mut h = Harness {
        receiver,
        slave: Slave::new(),
        model: model(),
        reply: ReplyBuffer::new(),
        polled: 0,
    };
    let mut now = Instant(0);
    let mut burst = [0u8; 512];
    let mut burst_len = 0usize;
    let push =
        |h: &mut Harness, now: Instant, byte: u8, burst: &mut [u8; 512], burst_len: &mut usize| {
            if !poll_at_end_only {
                if let Some(deadline) = h.receiver.next_deadline() {
                    if deadline <= now {
                        h.poll(deadline);
                    }
                }
                h.poll(now);
            }
            h.receiver.push(now, byte);
            if let Some(slot) = burst.get_mut(*burst_len) {
                *slot = byte;
                *burst_len += 1;
            }
        };
    for pair in stream.chunks_exact(2) {
        let (gap, byte) = (u64::from(pair[0]), pair[1]);
        if fix_crc && gap >= 128 && burst_len > 0 {
            let wire = crc::to_wire(crc::checksum(&burst[..burst_len]));
            for b in wire {
                push(&mut h, now, b, &mut burst, &mut burst_len);
            }
        }
        if gap >= 128 {
            burst_len = 0;
        }
        now = now + Duration::from_micros(gap * t35 / 128);
        push(&mut h, now, byte, &mut burst, &mut burst_len);
    }
    if fix_crc && burst_len > 0 {
        let wire = crc::to_wire(crc::checksum(&burst[..burst_len]));
        for b in wire {
            push(&mut h, now, b, &mut burst, &mut burst_len);
        }
    }
    let end = now + Duration::from_micros(t35);
    h.poll(end);
    assert!(h.receiver.next_deadline().is_none());

    let rx = h.receiver.counters();
    let bursts = rx.frames + rx.too_short + rx.too_long + rx.crc_errors + rx.bad_gaps;
    let sc = h.slave.counters();
    assert_eq!(bursts - rx.overruns, h.polled);
    assert_eq!(
        h.polled,
        sc.frames + sc.crc_errors + sc.too_short + sc.too_long + sc.bad_gaps
    );
    let exceptions = sc.illegal_function
        + sc.illegal_data_address
        + sc.illegal_data_value
        + sc.server_device_failure;
    assert!(exceptions <= sc.replies);
    assert_eq!(sc.frames, sc.replies + sc.ignored + sc.unanswered);
    assert!(sc.broadcasts + sc.malformed <= sc.unanswered);
});

/// The raw bytes as a PDU, and as a frame with its CRC appended.
fn direct(bytes: &[u8]) {
    if let Ok(request) = Request::parse(bytes) {
        let mut frame = [0u8; 256];
        let len = request.emit(0x11, &mut frame).unwrap();
        assert_eq!(&frame[1..len - 2], bytes, "{request:?} is not canonical");
        let _ = (request.is_write(), format!("{request:?}"));
    }
    if bytes.is_empty() || bytes.len() > 254 {
        return;
    }
    let mut frame = [0u8; 256];
    frame[..bytes.len()].copy_from_slice(bytes);
    let wire = crc::to_wire(crc::checksum(bytes));
    frame[bytes.len()..bytes.len() + 2].copy_from_slice(&wire);
    let frame = &frame[..bytes.len() + 2];
    match Adu::new_checked(frame) {
        Ok(adu) => {
            let mut slave = Slave::new();
            let mut model = model();
            let mut reply = ReplyBuffer::new();
            match slave.handle(&adu, &mut model, &mut reply) {
                Handled::Reply(len) => check_reply(&adu, reply.as_bytes(), len),
                _ => assert!(reply.is_empty()),
            }
        }
        Err(error) => assert!(frame.len() < 4, "{error}"),
    }
}
