//! Properties over arbitrary input: valid requests round-trip and get normal replies, parsing
//! is canonical, arbitrary streams never panic.

use proptest::prelude::*;
use proptest::sample::select;
use protocol::modbus::{crc, t3_5, Handled, Receiver, ReplyBuffer, Request, Slave};
use protocol::time::{Duration, Instant};

use crate::{feed, Memory};

// ------------------------------------------------------------------------------ properties

/// A request owning its data, so that a strategy can make one.
#[derive(Clone, Debug)]
enum Owned {
    Read {
        function: u8,
        address: u16,
        quantity: u16,
    },
    Coil {
        address: u16,
        value: bool,
    },
    Register {
        address: u16,
        value: u16,
    },
    Coils {
        address: u16,
        bits: Vec<bool>,
    },
    Registers {
        address: u16,
        values: Vec<u16>,
    },
    Echo {
        data: Vec<u8>,
    },
}

/// `(address, quantity)` with `1 <= quantity <= max` and `address + quantity <= 0x10000`.
fn range(max: u16) -> impl Strategy<Value = (u16, u16)> {
    (1..=max).prop_flat_map(|quantity| {
        (
            (0..=(0x1_0000 - u32::from(quantity)) as u16),
            Just(quantity),
        )
    })
}

fn owned() -> impl Strategy<Value = Owned> {
    prop_oneof![
        (select(vec![1u8, 2]), range(2000)).prop_map(|(function, (address, quantity))| {
            Owned::Read {
                function,
                address,
                quantity,
            }
        }),
        (select(vec![3u8, 4]), range(125)).prop_map(|(function, (address, quantity))| {
            Owned::Read {
                function,
                address,
                quantity,
            }
        }),
        (any::<u16>(), any::<bool>()).prop_map(|(address, value)| Owned::Coil { address, value }),
        (any::<u16>(), any::<u16>())
            .prop_map(|(address, value)| Owned::Register { address, value }),
        range(1968).prop_flat_map(|(address, quantity)| {
            proptest::collection::vec(any::<bool>(), usize::from(quantity))
                .prop_map(move |bits| Owned::Coils { address, bits })
        }),
        range(123).prop_flat_map(|(address, quantity)| {
            proptest::collection::vec(any::<u16>(), usize::from(quantity))
                .prop_map(move |values| Owned::Registers { address, values })
        }),
        proptest::collection::vec(any::<u8>(), 0..=250).prop_map(|data| Owned::Echo { data }),
    ]
}

/// The owned request's bytes (packed coils or big-endian registers), then its `Request`.
fn payload(owned: &Owned) -> Vec<u8> {
    match owned {
        Owned::Coils { bits, .. } => bits
            .chunks(8)
            .map(|chunk| {
                chunk
                    .iter()
                    .enumerate()
                    .fold(0u8, |byte, (i, &bit)| byte | (u8::from(bit) << i))
            })
            .collect(),
        Owned::Registers { values, .. } => values
            .iter()
            .flat_map(|value| value.to_be_bytes())
            .collect(),
        Owned::Echo { data } => data.clone(),
        _ => Vec::new(),
    }
}

fn request<'a>(owned: &Owned, payload: &'a [u8]) -> Request<'a> {
    match *owned {
        Owned::Read {
            function: 1,
            address,
            quantity,
        } => Request::ReadCoils { address, quantity },
        Owned::Read {
            function: 2,
            address,
            quantity,
        } => Request::ReadDiscreteInputs { address, quantity },
        Owned::Read {
            function: 3,
            address,
            quantity,
        } => Request::ReadHoldingRegisters { address, quantity },
        Owned::Read {
            address, quantity, ..
        } => Request::ReadInputRegisters { address, quantity },
        Owned::Coil { address, value } => Request::WriteSingleCoil { address, value },
        Owned::Register { address, value } => Request::WriteSingleRegister { address, value },
        Owned::Coils { address, ref bits } => Request::WriteMultipleCoils {
            address,
            quantity: bits.len() as u16,
            values: payload,
        },
        Owned::Registers { address, .. } => Request::WriteMultipleRegisters {
            address,
            values: payload,
        },
        Owned::Echo { .. } => Request::ReturnQueryData { data: payload },
    }
}

/// The expected reply PDU, from the model (after the request was carried out).
fn expected_reply(owned: &Owned, model: &Memory, request_pdu: &[u8]) -> Vec<u8> {
    let pack = |bits: &[bool]| -> Vec<u8> {
        bits.chunks(8)
            .map(|chunk| {
                chunk
                    .iter()
                    .enumerate()
                    .fold(0u8, |byte, (i, &bit)| byte | (u8::from(bit) << i))
            })
            .collect()
    };
    match *owned {
        Owned::Read {
            function,
            address,
            quantity,
        } => {
            let range = usize::from(address)..usize::from(address) + usize::from(quantity);
            let data: Vec<u8> = match function {
                1 => pack(&model.coils[range]),
                2 => pack(&model.discrete[range]),
                3 => model.holding[range]
                    .iter()
                    .flat_map(|r| r.to_be_bytes())
                    .collect(),
                _ => model.input[range]
                    .iter()
                    .flat_map(|r| r.to_be_bytes())
                    .collect(),
            };
            let mut pdu = vec![function, data.len() as u8];
            pdu.extend(data);
            pdu
        }
        Owned::Coils { .. } | Owned::Registers { .. } => request_pdu[..5].to_vec(),
        _ => request_pdu.to_vec(),
    }
}

/// A model with some content, so that reads are not all zeros.
fn patterned() -> Memory {
    let mut model = Memory::full();
    for address in 0..0x1_0000usize {
        model.coils[address] = address % 3 == 0;
        model.discrete[address] = address % 5 == 1;
        model.holding[address] = (address as u16).wrapping_mul(7);
        model.input[address] = !(address as u16);
    }
    model
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// A valid request goes through emit, the receiver and parse unchanged, and gets its
    /// normal (non-exception) reply; writes land in the model.
    #[test]
    fn valid_requests_round_trip_and_get_normal_replies(
        owned in owned(),
        unit in 1u8..=247,
        baud in select(vec![9_600u32, 19_200, 115_200]),
    ) {
        let payload = payload(&owned);
        let request = request(&owned, &payload);
        let mut frame = [0u8; 256];
        let len = request.emit(unit, &mut frame).unwrap();
        let frame = &frame[..len];
        prop_assert!(crc::is_valid(frame));

        let mut receiver = Receiver::new(baud);
        let char_time = Duration::from_micros(11_000_000u64.div_ceil(u64::from(baud)));
        let last = feed(&mut receiver, Instant(123), frame, char_time);
        let deadline = receiver.next_deadline().unwrap();
        prop_assert_eq!(deadline, last + t3_5(baud));
        let adu = receiver.poll(deadline).unwrap().unwrap();
        prop_assert_eq!(adu.as_bytes(), frame);
        prop_assert_eq!(Request::parse(adu.pdu()), Ok(request));

        let mut model = patterned();
        model.units = vec![unit];
        let mut slave = Slave::new();
        let mut reply = ReplyBuffer::new();
        let handled = slave.handle(&adu, &mut model, &mut reply);
        prop_assert_eq!(handled, Handled::Reply(reply.len()));
        let bytes = reply.as_bytes();
        prop_assert!(crc::is_valid(bytes) && bytes.len() <= 256);
        prop_assert_eq!(bytes[0], unit);
        prop_assert_eq!(&bytes[1..bytes.len() - 2], &expected_reply(&owned, &model, adu.pdu())[..]);
        match owned {
            Owned::Coil { address, value } => prop_assert_eq!(model.coils[usize::from(address)], value),
            Owned::Register { address, value } => prop_assert_eq!(model.holding[usize::from(address)], value),
            Owned::Coils { address, ref bits } => {
                let start = usize::from(address);
                prop_assert_eq!(&model.coils[start..start + bits.len()], &bits[..]);
            }
            Owned::Registers { address, ref values } => {
                let start = usize::from(address);
                prop_assert_eq!(&model.holding[start..start + values.len()], &values[..]);
            }
            _ => prop_assert_eq!(model.writes, 0),
        }
        prop_assert_eq!(slave.counters().replies, 1);
    }

    /// Whatever parses is canonical: emitting it gives back the PDU.
    #[test]
    fn parse_is_canonical(pdu in proptest::collection::vec(any::<u8>(), 0..260)) {
        if let Ok(request) = Request::parse(&pdu) {
            let mut frame = [0u8; 256];
            let len = request.emit(0x11, &mut frame).unwrap();
            prop_assert_eq!(&frame[1..len - 2], &pdu[..]);
        }
    }

    /// Arbitrary bytes at arbitrary times: no panic, replies are whole frames of at most 256
    /// bytes for a served unit, and every burst is accounted for.
    #[test]
    fn arbitrary_streams_never_panic(
        stream in proptest::collection::vec((0u32..5_000, any::<u8>()), 0..1_200),
        baud in select(vec![1_200u32, 9_600, 19_200, 38_400, 115_200]),
        gap_check in any::<bool>(),
        poll_late in any::<bool>(),
    ) {
        let mut receiver = if gap_check { Receiver::new(baud) } else { Receiver::new(baud).without_gap_check() };
        let mut slave = Slave::new();
        let mut model = Memory::new(300);
        model.units = vec![0x11, 0x01];
        let mut reply = ReplyBuffer::new();
        let mut now = Instant(0);
        let mut polled = 0u32;
        for (gap, byte) in stream {
            now = now + Duration::from_micros(u64::from(gap));
            if !poll_late {
                if let Some(deadline) = receiver.next_deadline() {
                    if deadline <= now && slave.poll(&mut receiver, deadline, &mut model, &mut reply).is_some() {
                        polled += 1;
                    }
                }
            }
            if let Some(Ok(Handled::Reply(len))) = slave.poll(&mut receiver, now, &mut model, &mut reply) {
                prop_assert!(len <= 256 && crc::is_valid(reply.as_bytes()));
            }
            receiver.push(now, byte);
        }
        if slave.poll(&mut receiver, now + Duration::from_millis(100), &mut model, &mut reply).is_some() {
            polled += 1;
        }
        let rx = receiver.counters();
        let bursts = rx.frames + rx.too_short + rx.too_long + rx.crc_errors + rx.bad_gaps;
        prop_assert_eq!(bursts - rx.overruns, slave.counters().frames + slave.counters().crc_errors
            + slave.counters().too_short + slave.counters().too_long + slave.counters().bad_gaps);
        prop_assert!(polled <= bursts);
    }
}
