//! The whole gateway ([`Node`]) between a simulated bus and a scripted PLC, in virtual time.
//!
//! This is the firmware's loop (ingress, poll until idle, sleep until `poll_at`) with the
//! simulator in place of the RS485 UART and a Modbus RTU master in place of the PLC: requests
//! are real RTU frames (CRC and all) handed to [`Node::plc_received`], replies are what
//! [`Action::Reply`] hands back, decoded. So a test here exercises exactly the object the
//! firmware runs, down to the bytes on both lines.

use protocol::frame::COMM_CHANGE;
use protocol::line::{LineAction, BREAK_MS};
use protocol::modbus::tcp::SocketHandle;
use protocol::modbus::{client, Adu, Exception, Request as Modbus, MAX_ADU_LEN};
use protocol::node::{Action, Node, TcpAction};
use protocol::pio::{PioInputs, PioOutputs};
use protocol::plc::{Boot, GatewayConfig, IDENTITY};
use protocol::time::Instant;
use protocol::Request;
use rc_tools::sim::Bus;

/// How long a request may wait for its reply before the master gives up (virtual µs).
const REPLY_TIMEOUT_US: u64 = 500_000;

/// What a Modbus request got back.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Answer {
    /// A normal reply: the PDU after the function code.
    Data(Vec<u8>),
    /// An exception reply.
    Exception(Exception),
    /// Nothing (a broadcast, or a unit nobody serves).
    Silence,
}

/// Node + simulated bus + a Modbus master + virtual clock.
pub struct NodeHarness {
    /// The gateway under test.
    pub node: Box<Node>,
    /// The simulated line and controllers.
    pub bus: Bus,
    /// Virtual time, microseconds.
    pub now: u64,
    /// Every frame the node transmitted on the bus, with its time.
    pub sent: Vec<(u64, Request)>,
    /// The PIO input pins, sampled every millisecond (none when `None`).
    pub inputs: Option<PioInputs>,
    /// The PIO outputs as of the last sample.
    pub outputs: PioOutputs,
    /// PLC line changes the node asked for, with their time.
    pub plc_lines: Vec<(u64, protocol::plc::PlcLine)>,
    /// Flash requests (each save succeeds), with their time.
    pub stores: Vec<(u64, protocol::plc::SettingsRequest)>,
    /// Modbus replies not yet taken, with the time they were sent.
    replies: Vec<(u64, Vec<u8>)>,
    /// Modbus TCP replies, with their socket and time, in order.
    pub tcp_replies: Vec<(u64, SocketHandle, Vec<u8>)>,
    /// Sockets the node closed, with the time.
    pub tcp_closes: Vec<(u64, SocketHandle)>,
    /// The next input sample is due then.
    next_sample: u64,
}

impl NodeHarness {
    /// A node for `config` as a board starts it the first time (the gateway's identity,
    /// nothing stored), with the bus at time 0; the bus' host side starts at the node's rate.
    pub fn new(config: GatewayConfig, mut bus: Bus) -> NodeHarness {
        let node = Box::new(Node::new(config, &IDENTITY, Boot::DEFAULT));
        bus.set_host_baud(node.gateway().engine().line_baud());
        NodeHarness {
            node,
            bus,
            now: 0,
            sent: Vec::new(),
            inputs: None,
            outputs: PioOutputs::SAFE,
            plc_lines: Vec::new(),
            stores: Vec::new(),
            replies: Vec::new(),
            tcp_replies: Vec::new(),
            tcp_closes: Vec::new(),
            next_sample: 0,
        }
    }

    /// Carry out everything the node has to do now.
    fn drain(&mut self) {
        let now = Instant(self.now);
        for _ in 0..10_000 {
            match self.node.poll(now) {
                None => return,
                Some(Action::Bus(bytes)) => {
                    if let Ok(frame) = protocol::Frame::new_checked(&bytes) {
                        if let Ok(request) = Request::parse(&frame) {
                            self.sent.push((self.now, request));
                        }
                    }
                    self.bus.host_send(self.now, &bytes);
                }
                Some(Action::Line(LineAction::SetBaud(baud))) => self.bus.set_host_baud(baud),
                Some(Action::Line(LineAction::BreakStart)) => {
                    // The node ends the break BREAK_MS later; the simulated line takes the
                    // whole break at once.
                    self.bus
                        .host_break(self.now, u64::from(BREAK_MS).saturating_mul(1000));
                }
                Some(Action::Line(LineAction::BreakEnd)) => {}
                Some(Action::Line(LineAction::CommChange)) => {
                    self.bus.host_send(self.now, &COMM_CHANGE);
                }
                Some(Action::Reply(bytes)) => self.replies.push((self.now, bytes.to_vec())),
                Some(Action::PlcLine(line)) => self.plc_lines.push((self.now, line)),
                Some(Action::Tcp(TcpAction::Reply(socket))) => {
                    let bytes = self.node.tcp_reply().to_vec();
                    self.tcp_replies.push((self.now, socket, bytes))
                }
                Some(Action::Tcp(TcpAction::Close(socket))) => {
                    self.tcp_closes.push((self.now, socket));
                    self.node.tcp_closed(socket);
                }
                Some(Action::Settings(store)) => {
                    if let protocol::plc::SettingsRequest::Save = store {
                        let saves = self.stores.len() as u32 + 1;
                        self.node.stored(Ok(saves));
                    }
                    self.stores.push((self.now, store));
                }
                // No DFU partition is set here (`Node::set_update_target`): never asked.
                Some(Action::Update(_)) => self
                    .node
                    .update_done(Err(protocol::plc::update::UpdateError::Flash)),
            }
        }
        panic!("the node never went idle at {} µs", self.now);
    }

    /// Run one pass: act on the node, then advance time to the next thing that happens (a
    /// byte arrives, the node's deadline, an input sample) but not beyond `limit`.
    pub fn step(&mut self, limit: u64) {
        self.drain();
        let wake = [
            self.node.poll_at().map(|t| t.0),
            self.bus.next_event(),
            self.inputs.map(|_| self.next_sample),
            Some(limit),
        ]
        .into_iter()
        .flatten()
        .min()
        .unwrap_or(limit)
        .max(self.now);
        for (at, byte) in self.bus.advance(wake) {
            self.node.bus_received(Instant(at), &[byte]);
        }
        self.now = wake;
        if let Some(inputs) = self.inputs {
            if self.now >= self.next_sample {
                self.node.sample_inputs(Instant(self.now), inputs);
                self.outputs = self.node.outputs();
                self.next_sample = self.now + 1_000;
            }
        }
    }

    /// Run until virtual time `until`.
    pub fn run_until(&mut self, until: u64) {
        let mut guard = 0u64;
        while self.now < until {
            self.step(until);
            guard += 1;
            assert!(guard < 50_000_000, "no progress at {} µs", self.now);
        }
        self.drain();
    }

    /// Run for `us` microseconds.
    pub fn run_for(&mut self, us: u64) {
        self.run_until(self.now + us);
    }

    /// Send one Modbus request and wait for its answer.
    pub fn request(&mut self, unit: u8, request: &Modbus<'_>) -> Answer {
        let mut adu = [0u8; MAX_ADU_LEN];
        let len = request.emit(unit, &mut adu).expect("a request that fits");
        self.replies.clear();
        let handled = self.node.plc_counters().frames;
        self.node.plc_received(Instant(self.now), &adu[..len]);
        let until = self.now + REPLY_TIMEOUT_US;
        // The slave answers in the same poll that takes the frame in: once it has counted the
        // frame, the reply is there or there is none (a broadcast, another unit).
        while self.now < until && self.node.plc_counters().frames == handled {
            self.step(until);
            self.drain();
        }
        let Some((_, reply)) = self.replies.pop() else {
            return Answer::Silence;
        };
        let adu = Adu::new_checked(&reply).expect("a reply with a good CRC");
        match client::answer(&adu, unit, request.function()).expect("the reply to the request") {
            Ok(body) => Answer::Data(body.to_vec()),
            Err(exception) => Answer::Exception(exception),
        }
    }

    /// FC03 (or FC04 with `input`): `n` registers.
    pub fn read_registers(
        &mut self,
        unit: u8,
        address: u16,
        n: u16,
        input: bool,
    ) -> Result<Vec<u16>, Exception> {
        let request = if input {
            Modbus::ReadInputRegisters {
                address,
                quantity: n,
            }
        } else {
            Modbus::ReadHoldingRegisters {
                address,
                quantity: n,
            }
        };
        match self.request(unit, &request) {
            Answer::Data(body) => Ok(client::registers(&body).collect()),
            Answer::Exception(e) => Err(e),
            Answer::Silence => panic!("no answer to {request:?} at unit {unit}"),
        }
    }

    /// FC03: `n` holding registers.
    pub fn read(&mut self, unit: u8, address: u16, n: u16) -> Result<Vec<u16>, Exception> {
        self.read_registers(unit, address, n, false)
    }

    /// FC06 for one value, FC10 for several; a broadcast (unit 0) returns `Ok` unanswered.
    pub fn write(&mut self, unit: u8, address: u16, values: &[u16]) -> Result<(), Exception> {
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
        let request = match values {
            [value] => Modbus::WriteSingleRegister {
                address,
                value: *value,
            },
            _ => Modbus::WriteMultipleRegisters {
                address,
                values: &bytes,
            },
        };
        self.answer_to_write(unit, &request)
    }

    /// FC05: one coil.
    pub fn write_coil(&mut self, unit: u8, address: u16, on: bool) -> Result<(), Exception> {
        self.answer_to_write(unit, &Modbus::WriteSingleCoil { address, value: on })
    }

    /// FC0F: several coils.
    pub fn write_coils(
        &mut self,
        unit: u8,
        address: u16,
        values: &[bool],
    ) -> Result<(), Exception> {
        let mut bytes = vec![0u8; values.len().div_ceil(8)];
        for (i, &on) in values.iter().enumerate() {
            bytes[i / 8] |= u8::from(on) << (i % 8);
        }
        let request = Modbus::WriteMultipleCoils {
            address,
            quantity: u16::try_from(values.len()).expect("at most 1968 coils"),
            values: &bytes,
        };
        self.answer_to_write(unit, &request)
    }

    /// FC01: `n` coils.
    pub fn read_coils(&mut self, unit: u8, address: u16, n: u16) -> Result<Vec<bool>, Exception> {
        let request = Modbus::ReadCoils {
            address,
            quantity: n,
        };
        match self.request(unit, &request) {
            Answer::Data(body) => Ok(client::bits(&body, usize::from(n)).collect()),
            Answer::Exception(e) => Err(e),
            Answer::Silence => panic!("no answer to FC01 at unit {unit}"),
        }
    }

    fn answer_to_write(&mut self, unit: u8, request: &Modbus<'_>) -> Result<(), Exception> {
        match self.request(unit, request) {
            Answer::Data(_) => Ok(()),
            Answer::Exception(e) => Err(e),
            Answer::Silence if unit == 0 => Ok(()),
            Answer::Silence => panic!("no answer to {request:?} at unit {unit}"),
        }
    }
}
