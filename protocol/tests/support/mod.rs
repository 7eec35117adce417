//! Test support: the whole gateway ([`Node`]) between scripted Robo Cylinder controllers and a
//! Modbus master, in virtual time, inside this crate (the faithful simulator lives in the host
//! crate; these controllers are deliberately simple: a move takes [`MOVE_US`], homing
//! [`HOME_US`], a servo-on is followed by [`INIT_US`] of motor initialisation).
#![allow(dead_code)]

use std::collections::BTreeMap;

use protocol::engine::timing;
use protocol::frame::FRAME_LEN;
use protocol::line::{Baud, LineAction};
use protocol::memory::{PointField, PNOW};
use protocol::modbus::{client, Adu, Exception, Request as Modbus};
use protocol::node::{Action, Node};
#[cfg(feature = "update")]
use protocol::plc::update::UpdateError;
use protocol::plc::GatewayConfig;
use protocol::time::Instant;
use protocol::{
    AlarmCode, Axis, AxisSet, Command, Frame, Inputs, MemoryCode, Outputs, PositionNo, Pulses,
    Reply, Request, Status, StatusReport, Transfer,
};

pub const MS: u64 = 1_000;
pub const S: u64 = 1_000_000;
/// A move (`a`, `m`, Q3) takes this long.
pub const MOVE_US: u64 = 80 * MS;
/// Homing takes this long.
pub const HOME_US: u64 = 150 * MS;
/// After servo-on, the motor initialises this long: not in position, commands refused (74).
pub const INIT_US: u64 = 30 * MS;

pub fn axis(n: u8) -> Axis {
    Axis::new(n).unwrap()
}

/// One scripted controller.
#[derive(Clone, Debug, Default)]
pub struct Fake {
    pub servo: bool,
    pub homed: bool,
    pub alarm: u8,
    pub position: i32,
    /// A move or homing in progress: target, end time and the point it goes to (Q3).
    pub motion: Option<(i32, u64)>,
    /// The point of the Q3 in progress, and the completed one (PM1-PM8).
    pub going_to: Option<u8>,
    pub pm: u8,
    pub init_until: u64,
    pub points: [[u32; 9]; 16],
    pub edit: [u32; 9],
    pub write_address: u32,
    pub v5_writes: u32,
    pub buffered: Option<Command>,
    /// Commands received, in order.
    pub log: Vec<Command>,
    /// Does not answer.
    pub silent: bool,
}

impl Fake {
    fn moving(&self, now: u64) -> bool {
        self.motion.is_some_and(|(_, end)| now < end)
    }

    fn settle(&mut self, now: u64) {
        if let Some((target, end)) = self.motion {
            if now >= end {
                self.position = target;
                self.motion = None;
                self.homed = true;
                self.pm = self.going_to.take().unwrap_or(0);
            }
        }
    }

    fn report(&self, now: u64) -> StatusReport {
        let ready = self.servo && !self.moving(now) && now >= self.init_until && self.alarm == 0;
        let mut status = Status::POWER;
        if self.servo {
            status = status | Status::SERVO | Status::RUN;
        }
        if self.homed {
            status = status | Status::HOME;
        }
        if self.buffered.is_some() {
            status = status | Status::BUFFERED;
        }
        let mut outputs = Outputs::NONE;
        if ready {
            outputs = outputs | Outputs::PFIN;
        }
        if self.homed {
            outputs = outputs | Outputs::ZFIN;
        }
        if self.alarm == 0 {
            outputs = outputs | Outputs::ALM_N;
        }
        let outputs = Outputs::from_bits(outputs.bits() | (self.pm & 0x0F));
        StatusReport {
            status,
            alarm: AlarmCode(self.alarm),
            inputs: Inputs::default(),
            outputs,
        }
    }

    fn start_move(&mut self, now: u64, target: i32) -> Result<(), u8> {
        if !self.servo || now < self.init_until {
            return Err(0x70);
        }
        if !self.homed {
            return Err(0x71);
        }
        self.motion = Some((target, now + MOVE_US));
        self.pm = 0;
        self.going_to = None;
        Ok(())
    }

    /// The answer to `request` at `now`.
    fn answer(&mut self, now: u64, request: &Request) -> Reply {
        self.settle(now);
        self.log.push(request.command);
        let axis = request.axis;
        let status = |fake: &Fake, rejected: Option<u8>| {
            let mut report = fake.report(now);
            if let Some(code) = rejected {
                report.status = report.status | Status::REJECTED;
                report.alarm = AlarmCode(code);
            }
            Reply::Status {
                axis,
                code: request.command.code(),
                report,
            }
        };
        let memory = |code, value| Reply::Memory { axis, code, value };
        let field = |address: u32| {
            PointField::ALL
                .iter()
                .position(|f| f.address().0 == address)
        };
        match request.command {
            Command::Status => status(self, None),
            Command::Servo(on) => {
                if on && !self.servo {
                    self.init_until = now + INIT_US;
                }
                self.servo = on;
                if !on {
                    self.motion = None;
                }
                status(self, None)
            }
            Command::Home(_) => {
                if !self.servo {
                    return status(self, Some(0x70));
                }
                self.homed = false;
                self.motion = Some((0, now + HOME_US));
                status(self, None)
            }
            Command::MoveAbsolute(Pulses(p)) => {
                let r = self.start_move(now, p).err();
                status(self, r)
            }
            Command::MoveRelative(Pulses(d)) => {
                let r = self.start_move(now, self.position + d).err();
                status(self, r)
            }
            Command::MoveToPoint(point) => {
                let target = self.points[usize::from(point.get())][0] as i32;
                let r = self.start_move(now, target).err();
                if r.is_none() {
                    self.going_to = Some(point.get());
                }
                status(self, r)
            }
            Command::CancelMotion => {
                self.motion = None;
                status(self, None)
            }
            Command::Reset(_) => {
                if self.servo {
                    return status(self, Some(0x73));
                }
                self.alarm = 0;
                status(self, None)
            }
            Command::Buffer(b) => {
                self.buffered = b.command().ok().filter(|c| *c != Command::Status);
                status(self, None)
            }
            Command::ExecuteBuffered => {
                if let Some(Command::MoveToPoint(point)) = self.buffered.take() {
                    let target = self.points[usize::from(point.get())][0] as i32;
                    let _ = self.start_move(now, target);
                }
                status(self, None)
            }
            Command::SetVelocityAcceleration { .. } | Command::SetResponseDelay(_) => {
                status(self, None)
            }
            Command::EditToExecution(_) => status(self, None),
            Command::LoadToEdit(Transfer::Point(p)) => {
                self.edit = self.points[usize::from(p.get())];
                status(self, None)
            }
            Command::LoadToEdit(_) => status(self, None),
            Command::ReadMemory { address } if address == PNOW => {
                memory(MemoryCode::ReadMemory, self.position as u32)
            }
            Command::ReadMemory { address } => {
                let value = field(address.0).map_or(0, |i| self.edit[i]);
                memory(MemoryCode::ReadMemory, value)
            }
            Command::SetWriteAddress { address } => {
                self.write_address = address.0;
                memory(MemoryCode::SetWriteAddress, address.0)
            }
            Command::WriteMemory { value } => {
                if let Some(i) = field(self.write_address) {
                    self.edit[i] = value;
                }
                self.write_address += 1;
                memory(MemoryCode::WriteMemory, self.write_address)
            }
            Command::StoreFromEdit(Transfer::Point(p)) => {
                self.points[usize::from(p.get())] = self.edit;
                self.v5_writes += 1;
                memory(MemoryCode::Store, self.v5_writes)
            }
            Command::StoreFromEdit(_) => memory(MemoryCode::Store, 1),
        }
    }
}

/// How answers travel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Transport {
    /// A wire at the bus rate: the answer's last byte arrives two frame times and RTIM (3 ms)
    /// after the command was handed over, plus 100 µs.
    Wire,
    /// No wire time (a pseudo-terminal): the answer arrives RTIM after the command.
    Instant,
}

/// Scripted controllers on a bus.
#[derive(Debug)]
pub struct FakeBus {
    pub axes: BTreeMap<u8, Fake>,
    pub transport: Transport,
    /// Answers on their way: arrival time and bytes.
    pub inbox: Vec<(u64, [u8; FRAME_LEN])>,
}

impl FakeBus {
    pub fn new(axes: &[u8]) -> FakeBus {
        FakeBus {
            axes: axes.iter().map(|&a| (a, Fake::default())).collect(),
            transport: Transport::Wire,
            inbox: Vec::new(),
        }
    }

    pub fn fake(&mut self, a: u8) -> &mut Fake {
        self.axes.get_mut(&a).expect("a fake controller")
    }

    /// A command handed over at `now`.
    fn command(&mut self, now: u64, bytes: &[u8; FRAME_LEN]) {
        let Ok(request) = Frame::new_checked(bytes).and_then(|f| Request::parse(&f)) else {
            return;
        };
        let Some(fake) = self.axes.get_mut(&request.axis.get()) else {
            return;
        };
        if fake.silent {
            return;
        }
        let frame = timing::frame_time(Baud::B115200).as_micros();
        let delay = match self.transport {
            Transport::Wire => 2 * frame + 3 * MS + 100,
            Transport::Instant => 3 * MS,
        };
        let reply = fake.answer(now, &request);
        if request.command != Command::ExecuteBuffered {
            self.inbox.push((now + delay, reply.emit().to_bytes()));
        } else {
            // `t` reaches every axis; only the addressed one answers.
            self.inbox.push((now + delay, reply.emit().to_bytes()));
            for (_, other) in self
                .axes
                .iter_mut()
                .filter(|(&a, _)| a != request.axis.get())
            {
                if let Some(Command::MoveToPoint(point)) = other.buffered.take() {
                    let target = other.points[usize::from(point.get())][0] as i32;
                    let _ = other.start_move(now, target);
                }
            }
        }
    }

    fn next_arrival(&self) -> Option<u64> {
        self.inbox.iter().map(|(t, _)| *t).min()
    }
}

/// Node + scripted bus + Modbus master + virtual clock.
pub struct Rig {
    pub node: Box<Node>,
    pub bus: FakeBus,
    pub now: u64,
    /// Every frame the node sent, with its time.
    pub sent: Vec<(u64, Request)>,
    /// Line actions, with their time.
    pub lines: Vec<(u64, LineAction)>,
    /// PLC line changes, with their time.
    pub plc_lines: Vec<(u64, protocol::plc::PlcLine)>,
    /// Flash requests (each save succeeds), with their time.
    pub stores: Vec<(u64, protocol::plc::SettingsRequest)>,
    /// The records saved, as the firmware would write them, in order.
    pub saved: Vec<[u8; protocol::plc::settings::RECORD_LEN]>,
    /// Do not report saves: each stays pending until the test calls `node.stored`.
    pub hold_saves: bool,
    replies: Vec<Vec<u8>>,
    /// Modbus TCP replies, with their socket, in order.
    pub tcp_replies: Vec<(usize, Vec<u8>)>,
    /// Sockets the node closed, with the time.
    pub tcp_closes: Vec<(u64, usize)>,
    /// The DFU partition the firmware update writes (feature `update`).
    #[cfg(feature = "update")]
    pub dfu: Dfu,
}

/// A flash job of the firmware update, kept (owned) while the test holds it.
#[cfg(feature = "update")]
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Job {
    Erase(u32),
    Write(u32, Vec<u8>),
    Finish(u32, u32),
}

/// A DFU partition in RAM, as NOR flash: a write must fall inside it, on erased bytes only
/// (a test fails on the spot otherwise).
#[cfg(feature = "update")]
#[derive(Clone, Debug, Default)]
pub struct Dfu {
    pub flash: Vec<u8>,
    /// Jobs carried out, in order, with their time.
    pub jobs: Vec<(u64, Job)>,
    /// The image marked for the bootloader: size and CRC-32.
    pub marked: Option<(u32, u32)>,
    /// Fail the next job, with this reason.
    pub fail_next: Option<UpdateError>,
    /// Keep jobs without carrying them out ([`Rig::release_job`] does).
    pub hold: bool,
    pub held: Option<Job>,
}

#[cfg(feature = "update")]
impl Dfu {
    /// The erase unit (an L475 page).
    pub const PAGE: usize = 2048;

    pub fn new(size: usize) -> Dfu {
        Dfu {
            // Not erased: whatever an earlier image left.
            flash: vec![0x5A; size],
            ..Dfu::default()
        }
    }

    pub fn job(job: protocol::plc::update::UpdateJob<'_>) -> Job {
        use protocol::plc::update::UpdateJob;
        match job {
            UpdateJob::Erase { len } => Job::Erase(len),
            UpdateJob::Write { offset, bytes } => Job::Write(offset, bytes.to_vec()),
            UpdateJob::Finish { len, crc32 } => Job::Finish(len, crc32),
        }
    }

    /// Carries `job` out on the partition.
    pub fn carry_out(&mut self, now: u64, job: Job) -> Result<(), UpdateError> {
        self.jobs.push((now, job.clone()));
        if let Some(error) = self.fail_next.take() {
            return Err(error);
        }
        match job {
            Job::Erase(len) => {
                let len = len as usize;
                assert!(len <= self.flash.len(), "an erase past the partition");
                let end = len.div_ceil(Self::PAGE) * Self::PAGE;
                let end = end.min(self.flash.len());
                self.flash[..end].fill(0xFF);
                self.marked = None;
            }
            Job::Write(offset, bytes) => {
                let start = offset as usize;
                let end = start + bytes.len();
                assert!(end <= self.flash.len(), "a write past the partition");
                assert_eq!(start % 8, 0, "a write off a flash word");
                assert!(
                    self.flash[start..end].iter().all(|&b| b == 0xFF),
                    "a write over bytes not erased"
                );
                self.flash[start..end].copy_from_slice(&bytes);
            }
            Job::Finish(len, crc) => {
                let len = len as usize;
                assert!(len <= self.flash.len(), "a check past the partition");
                if protocol::plc::update::crc32(&self.flash[..len]) != crc {
                    return Err(UpdateError::Flash);
                }
                self.marked = Some((len as u32, crc));
            }
        }
        Ok(())
    }
}

impl Rig {
    pub fn new(config: GatewayConfig, axes: &[u8]) -> Rig {
        Rig::started(config, protocol::plc::Boot::DEFAULT, axes)
    }

    /// [`Rig::new`] for a start the firmware reports as `boot`.
    pub fn started(config: GatewayConfig, boot: protocol::plc::Boot, axes: &[u8]) -> Rig {
        Rig {
            node: Box::new(Node::new(config, &protocol::plc::IDENTITY, boot)),
            bus: FakeBus::new(axes),
            now: 0,
            sent: Vec::new(),
            lines: Vec::new(),
            plc_lines: Vec::new(),
            stores: Vec::new(),
            saved: Vec::new(),
            hold_saves: false,
            replies: Vec::new(),
            tcp_replies: Vec::new(),
            tcp_closes: Vec::new(),
            #[cfg(feature = "update")]
            dfu: Dfu::default(),
        }
    }

    /// Axes 0..n already at the bus' settings (no establishment), homed, servo on, points
    /// 0..15 at 10 mm steps (8 mm lead: 1000 pulses = 10 mm), the PLC watchdog at `watchdog`.
    pub fn ready(n: u8, config: impl FnOnce(&mut GatewayConfig)) -> Rig {
        Rig::ready_after(protocol::plc::Boot::DEFAULT, n, config)
    }

    /// [`Rig::ready`] for a start the firmware reports as `boot`.
    pub fn ready_after(
        boot: protocol::plc::Boot,
        n: u8,
        config: impl FnOnce(&mut GatewayConfig),
    ) -> Rig {
        let mut c = GatewayConfig::new(AxisSet::first(n));
        c.bus.establish = false;
        c.settings.axes = protocol::AxisMap::new(protocol::plc::AxisConfig {
            scale: protocol::units::Scale {
                lead: protocol::units::Lead::from_hundredths(800).unwrap(),
                ..protocol::plc::AxisConfig::DEFAULT.scale
            },
            stroke: protocol::units::Length(200_00),
        });
        config(&mut c);
        let axes: Vec<u8> = (0..n).collect();
        let mut rig = Rig::started(c, boot, &axes);
        for fake in rig.bus.axes.values_mut() {
            fake.servo = true;
            fake.homed = true;
            for (p, row) in fake.points.iter_mut().enumerate() {
                row[0] = (-(p as i32) * 1000) as u32;
            }
        }
        rig.run_for(100 * MS);
        rig
    }

    /// Polls the node at `now` until it is idle, handling what it asks for.
    pub fn drain(&mut self) {
        let now = Instant(self.now);
        for _ in 0..10_000 {
            match self.node.poll(now) {
                None => return,
                Some(Action::Bus(bytes)) => {
                    if let Ok(request) = Frame::new_checked(&bytes).and_then(|f| Request::parse(&f))
                    {
                        self.sent.push((self.now, request));
                    }
                    self.bus.command(self.now, &bytes);
                }
                Some(Action::Line(action)) => self.lines.push((self.now, action)),
                Some(Action::Reply(bytes)) => self.replies.push(bytes.to_vec()),
                Some(Action::PlcLine(line)) => self.plc_lines.push((self.now, line)),
                Some(Action::Settings(store)) => {
                    if let protocol::plc::SettingsRequest::Save = store {
                        self.saved.push(self.node.settings_record());
                    }
                    if let (protocol::plc::SettingsRequest::Save, false) = (store, self.hold_saves)
                    {
                        let saves = self.stores.len() as u32 + 1;
                        self.node.stored(Ok(saves));
                    }
                    self.stores.push((self.now, store));
                }
                #[cfg(feature = "tcp")]
                Some(Action::Tcp(protocol::node::TcpAction::Reply(socket))) => {
                    let bytes = self.node.tcp_reply().to_vec();
                    self.tcp_replies.push((socket.index(), bytes))
                }
                #[cfg(feature = "tcp")]
                Some(Action::Tcp(protocol::node::TcpAction::Close(socket))) => {
                    self.tcp_closes.push((self.now, socket.index()));
                    self.node.tcp_closed(socket);
                }
                #[cfg(feature = "update")]
                Some(Action::Update(job)) => {
                    let job = Dfu::job(job);
                    if self.dfu.hold {
                        assert!(
                            self.dfu.held.is_none(),
                            "a second job before the first's report"
                        );
                        self.dfu.held = Some(job);
                    } else {
                        let result = self.dfu.carry_out(self.now, job);
                        self.node.update_done(result);
                    }
                }
            }
        }
        panic!("the node never went idle");
    }

    /// Carries out the job held back (`dfu.hold`) and reports it.
    #[cfg(feature = "update")]
    pub fn release_job(&mut self) {
        let job = self.dfu.held.take().expect("a job held");
        let result = self.dfu.carry_out(self.now, job);
        self.node.update_done(result);
    }

    /// Run until `until`, polling the node as the firmware does.
    pub fn run_until(&mut self, until: u64) {
        while self.now < until {
            self.drain();
            let wake = [
                self.node.poll_at().map(|t| t.0),
                self.bus.next_arrival(),
                Some(until),
            ]
            .into_iter()
            .flatten()
            .min()
            .unwrap_or(until)
            .max(self.now);
            self.now = wake;
            let (due, later): (Vec<_>, Vec<_>) =
                self.bus.inbox.drain(..).partition(|(t, _)| *t <= wake);
            self.bus.inbox = later;
            for (t, bytes) in due {
                self.node.bus_received(Instant(t), &bytes);
            }
        }
        self.drain();
    }

    pub fn run_for(&mut self, us: u64) {
        self.run_until(self.now + us);
    }

    /// Send a Modbus request and wait for its answer: `None` when there is none.
    pub fn modbus(&mut self, unit: u8, request: &Modbus<'_>) -> Option<Result<Vec<u8>, Exception>> {
        let mut adu = [0u8; 256];
        let len = request.emit(unit, &mut adu).expect("a request that fits");
        self.replies.clear();
        let frames = self.node.plc_counters().frames;
        self.node.plc_received(Instant(self.now), &adu[..len]);
        let until = self.now + 100 * MS;
        while self.now < until && self.node.plc_counters().frames == frames {
            let step = (self.now + 100).min(until);
            self.run_until(step);
        }
        let reply = self.replies.pop()?;
        let adu = Adu::new_checked(&reply).expect("a reply with a good CRC");
        let body = client::answer(&adu, unit, request.function()).expect("the reply to it");
        Some(body.map(<[u8]>::to_vec))
    }

    pub fn read(&mut self, unit: u8, address: u16, quantity: u16) -> Result<Vec<u16>, Exception> {
        let request = Modbus::ReadHoldingRegisters { address, quantity };
        let body = self.modbus(unit, &request).expect("an answer")?;
        Ok(client::registers(&body).collect())
    }

    pub fn read_input(
        &mut self,
        unit: u8,
        address: u16,
        quantity: u16,
    ) -> Result<Vec<u16>, Exception> {
        let request = Modbus::ReadInputRegisters { address, quantity };
        let body = self.modbus(unit, &request).expect("an answer")?;
        Ok(client::registers(&body).collect())
    }

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
        match self.modbus(unit, &request) {
            Some(answer) => answer.map(|_| ()),
            None => Ok(()),
        }
    }

    pub fn coil(&mut self, unit: u8, address: u16, value: bool) -> Result<(), Exception> {
        let request = Modbus::WriteSingleCoil { address, value };
        match self.modbus(unit, &request) {
            Some(answer) => answer.map(|_| ()),
            None => Ok(()),
        }
    }

    /// The commands axis `a` received since `since` (µs).
    pub fn commands_to(&self, a: u8, since: u64) -> Vec<Command> {
        self.sent
            .iter()
            .filter(|(t, r)| *t >= since && r.axis.get() == a)
            .map(|(_, r)| r.command)
            .collect()
    }

    /// Keep reading CMST like a PLC (every 20 ms) until axis `a`'s command settles.
    pub fn settle(&mut self, a: u8, timeout: u64) -> (u16, u16) {
        let until = self.now + timeout;
        while self.now < until {
            self.run_for(20 * MS);
            let r = self.read(a + 1, protocol::plc::map::CMST, 2).unwrap();
            if r[0] >= 2 {
                return (r[0], r[1]);
            }
        }
        panic!("axis {a}: command never settled");
    }
}

/// A position-table point of the fakes: position in pulses.
pub fn point(p: u8) -> PositionNo {
    PositionNo::new(p).unwrap()
}
