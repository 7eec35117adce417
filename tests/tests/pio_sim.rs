//! The PIO logic driven by scripted input sequences against the simulator, through the
//! gateway, in virtual time: what a PLC wired to the 24 V inputs and outputs would see.
#![allow(clippy::inconsistent_digit_grouping)]

use protocol::line::Baud;
use protocol::memory::PointField;
use protocol::pio::{Pattern, PioInputs, PioOutputs};
use protocol::plc::{AxisConfig, CommandState, GatewayConfig};
use protocol::time::Instant;
use protocol::units::{Lead, Length, Scale};
use protocol::{Axis, AxisSet, HomeDirection, PositionNo, Rtim};
use rc_host::node_harness::NodeHarness;
use rc_tools::sim::memory::pi;
use rc_tools::sim::realtime::bus_at_line;
use rc_tools::sim::{BusConfig, ControllerConfig};

const MS: u64 = 1000;

struct Rig {
    h: NodeHarness,
    inputs: PioInputs,
    outputs: PioOutputs,
}

fn axis0() -> Axis {
    Axis::new(0).unwrap()
}

fn rig() -> Rig {
    rig_with(|_| {})
}

/// [`rig`] with its configuration changed by `change` first.
fn rig_with(change: impl FnOnce(&mut GatewayConfig)) -> Rig {
    let scale = Scale::new(Lead::from_hundredths(800).unwrap(), HomeDirection::MotorEnd);
    let mut bus = bus_at_line(BusConfig::default(), &[], Baud::B115200, Rtim::MIN);
    let mut row = [0u32; 10];
    row[0] = scale.position_to_wire(Length(30_00)).unwrap().to_wire();
    let controller = ControllerConfig {
        stored_line: Some((Baud::B115200, Rtim::MIN)),
        points: vec![(PositionNo::new(5).unwrap(), row)],
        ..ControllerConfig::default()
    };
    bus.add_controller(axis0(), controller);
    let mut config = GatewayConfig::new(AxisSet::first(1));
    config.bus.establish = false;
    config.settings.watchdog = protocol::plc::WatchdogTime::OFF; // wired I/O: no Modbus watchdog
    config.settings.pio_axis = Some(axis0());
    config.settings.axes[axis0()] = AxisConfig {
        scale,
        stroke: Length(100_00),
    };
    change(&mut config);
    Rig {
        h: NodeHarness::new(config, bus),
        // *STP is negative logic: ON means "run".
        inputs: PioInputs::STP_N,
        outputs: PioOutputs::SAFE,
    }
}

impl Rig {
    /// Run `ms` milliseconds: the node samples the inputs every millisecond, as the firmware
    /// does. *STP is wired to the gateway's stop input too (one PLC output to both terminals).
    fn run(&mut self, ms: u64) {
        self.run_stop_input(ms, !self.inputs.stp_n());
    }

    /// Run `ms` milliseconds with the stop input `active` whatever *STP is (two terminals).
    fn run_stop_input(&mut self, ms: u64, active: bool) {
        for _ in 0..ms {
            self.h.inputs = Some(self.inputs);
            self.h.node.set_stop_input(Instant(self.h.now), active);
            self.h.run_for(MS);
            self.outputs = self.h.outputs;
        }
    }

    /// SON until SV, a HOME pulse until HEND and PEND: what every wired sequence starts with.
    fn servo_on_and_home(&mut self) {
        self.set(PioInputs::SON, true);
        self.until(500, |o| o.sv());
        self.set(PioInputs::HOME, true);
        self.run(20);
        self.set(PioInputs::HOME, false);
        self.until(5_000, |o| o.hend() && o.pend());
    }

    fn set(&mut self, input: PioInputs, on: bool) {
        self.inputs = self.inputs.with(input, on);
    }

    /// Run until `done(outputs)` or `limit_ms`; the time it took.
    fn until(&mut self, limit_ms: u64, done: impl Fn(PioOutputs) -> bool) -> u64 {
        for t in 0..limit_ms {
            if done(self.outputs) {
                return t;
            }
            self.run(1);
        }
        panic!("outputs never reached the state: {:?}", self.outputs);
    }
}

#[test]
fn son_home_strobe_a_position_and_read_pm() {
    let mut r = rig();
    r.run(100);
    assert!(
        r.outputs.link() && r.outputs.alm_n(),
        "link up, no alarm: {:?}",
        r.outputs
    );
    r.servo_on_and_home();
    assert!(r.h.bus.controller(axis0()).unwrap().homed());
    // Position 5, with the PC bits set only 2 ms before CSTR: the strobe waits for settling.
    r.inputs = r.inputs.with_position(PositionNo::new(5).unwrap());
    r.run(2);
    r.set(PioInputs::CSTR, true);
    r.run(30);
    r.set(PioInputs::CSTR, false);
    assert!(
        !r.outputs.pend() || r.outputs.moving(),
        "PEND drops while the move runs"
    );
    r.until(5_000, |o| o.pend() && o.pm() == 5);
    let scale = r.h.node.gateway().config().settings.axes[axis0()].scale;
    let target = scale.position_to_wire(Length(30_00)).unwrap();
    let c = r.h.bus.controller(axis0()).unwrap();
    assert_eq!(c.position(), i64::from(target.0), "point 5 is 30 mm");
}

/// The rig with the servo on (SON) and the axis homed by a HOME pulse.
fn homed() -> Rig {
    let mut r = rig();
    r.set(PioInputs::SON, true);
    r.run(100);
    r.set(PioInputs::HOME, true);
    r.run(20);
    r.set(PioInputs::HOME, false);
    r.until(5_000, |o| o.hend() && o.pend());
    r
}

#[test]
fn stop_input_stops_at_once_and_blocks_the_next_strobe() {
    let mut r = homed();
    r.inputs = r.inputs.with_position(PositionNo::new(5).unwrap());
    r.run(10);
    r.set(PioInputs::CSTR, true);
    r.run(60);
    r.set(PioInputs::CSTR, false);
    assert!(r.h.bus.controller(axis0()).unwrap().moving());
    // *STP drops (input OFF): the stop goes out, the fail-safe latches.
    r.set(PioInputs::STP_N, false);
    r.run(200);
    let c = r.h.bus.controller(axis0()).unwrap();
    assert!(!c.moving(), "stopped");
    assert!(c.position() > -3001, "short of the 30 mm target");
    assert_eq!(r.h.node.gateway().failsafe() & 2, 2, "stop input latched");
    // A strobe while *STP is OFF starts nothing.
    let before = c.position();
    r.set(PioInputs::CSTR, true);
    r.run(300);
    r.set(PioInputs::CSTR, false);
    assert_eq!(r.h.bus.controller(axis0()).unwrap().position(), before);
    assert!(!r.h.bus.controller(axis0()).unwrap().moving());
}

#[test]
fn alarm_shows_on_pm_and_res_clears_it() {
    let mut r = rig();
    r.set(PioInputs::SON, true);
    r.run(100);
    r.h.bus
        .inject_alarm(axis0(), protocol::AlarmCode(0xD8))
        .unwrap();
    r.until(500, |o| !o.alm_n());
    assert_eq!(r.outputs.pm(), 0x0B, "abbreviated code of D8 (deviation)");
    r.set(PioInputs::RES, true);
    r.run(20);
    r.set(PioInputs::RES, false);
    r.until(2_000, |o| o.alm_n());
    assert_eq!(
        r.h.bus.controller(axis0()).unwrap().alarm(),
        protocol::AlarmCode::NONE
    );
    // SON is still on: the PIO turns the servo back on after the reset turned it off.
    r.until(3_000, |o| o.sv());
}

/// A strobe the gateway refuses (the cabinet's stop input is open while *STP is ON: two
/// terminals) does not leave PEND off waiting for a move that will not come: PEND and PM show
/// where the axis is, and CMST says why (failed, reason 10).
#[test]
fn a_refused_strobe_shows_pend_at_the_point_the_axis_is_at() {
    let mut r = homed();
    let at = r.h.bus.controller(axis0()).unwrap().position();
    // The stop input opens; *STP stays ON.
    r.run_stop_input(50, true);
    r.inputs = r.inputs.with_position(PositionNo::new(5).unwrap());
    r.run_stop_input(10, true);
    r.set(PioInputs::CSTR, true);
    r.run_stop_input(30, true);
    r.set(PioInputs::CSTR, false);
    r.run_stop_input(200, true);
    assert_eq!(
        r.h.bus.controller(axis0()).unwrap().position(),
        at,
        "nothing moved"
    );
    assert_eq!(
        r.h.node.gateway().command_state(axis0()),
        (protocol::plc::CommandState::Failed, 10 << 8),
        "CMST: failed, STP/EMG or the stop input"
    );
    assert!(r.outputs.pend(), "PEND back on: {:?}", r.outputs);
    // The latched stop input is what *ALM and PM show (FAILSAFE = 2), not point 5.
    assert!(!r.outputs.alm_n(), "*ALM OFF: the fail-safe is latched");
    assert_eq!(r.outputs.pm(), 2, "PM = FAILSAFE: the stop input");
}

/// A machine wired by 24 V only acknowledges the fail-safe with a RES pulse, as a safety
/// relay's reset: refused while the stop input is still open, taken once it is closed; until
/// then no strobe moves the axis, even with the stop input closed again.
#[test]
fn a_res_pulse_acknowledges_the_fail_safe_once_the_stop_input_is_closed() {
    let mut r = homed();
    let at = r.h.bus.controller(axis0()).unwrap().position();
    let pulse = |r: &mut Rig, input: PioInputs, stop: bool| {
        for on in [true, false] {
            r.set(input, on);
            r.run_stop_input(30, stop);
        }
    };
    // The stop input opens (*STP stays ON) and latches FAILSAFE bit 1.
    pulse(&mut r, PioInputs::RES, true);
    assert_eq!(
        r.h.node.gateway().failsafe(),
        2,
        "RES refused: the stop input is open"
    );
    assert!(!r.outputs.alm_n() && r.outputs.pm() == 2, "{:?}", r.outputs);
    // Closed again: still latched, and a strobe does not move the axis (CMST: reason 12).
    r.inputs = r.inputs.with_position(PositionNo::new(5).unwrap());
    pulse(&mut r, PioInputs::CSTR, false);
    r.run(200);
    assert_eq!(
        r.h.node.gateway().failsafe(),
        2,
        "latched until acknowledged"
    );
    assert!(!r.outputs.alm_n(), "*ALM OFF while latched");
    assert_eq!(
        r.h.bus.controller(axis0()).unwrap().position(),
        at,
        "nothing moved"
    );
    assert_eq!(
        r.h.node.gateway().command_state(axis0()),
        (protocol::plc::CommandState::Failed, 12 << 8),
        "CMST: failed, the fail-safe is latched"
    );
    // RES now acknowledges: *ALM back ON, PM the point the axis is at, and a strobe moves.
    pulse(&mut r, PioInputs::RES, false);
    assert_eq!(r.h.node.gateway().failsafe(), 0, "acknowledged by wire");
    assert!(r.outputs.alm_n() && r.outputs.pm() == 0, "{:?}", r.outputs);
    assert!(
        r.h.bus.controller(axis0()).unwrap().servo(),
        "no alarm reset ran"
    );
    pulse(&mut r, PioInputs::CSTR, false);
    r.until(5_000, |o| o.pend() && o.pm() == 5);
}

/// Pattern 1 against the simulated controller: a held jog and an inching step move the axis,
/// and PWRT stores where it is into the point PC1-PC8 select (the row the controller then
/// holds, read from its memory), compared first: a PWRT at the same place writes nothing.
#[test]
fn teaching_jogs_and_pwrt_stores_the_position_into_the_selected_point() {
    let mut r = rig_with(|c| c.settings.pio_pattern = Pattern::Teaching);
    r.run(100);
    r.servo_on_and_home();
    r.set(PioInputs::ST6, true); // MODE
    r.until(100, |o| o.modes());
    // JOG+ held for 300 ms at 100 mm/s (PIOJOG's default), then released.
    r.set(PioInputs::JOG_PLUS, true);
    r.run(300);
    assert!(r.h.bus.controller(axis0()).unwrap().moving(), "jogging");
    r.set(PioInputs::JOG_PLUS, false);
    r.run(500);
    let c = r.h.bus.controller(axis0()).unwrap();
    assert!(!c.moving(), "stopped on release");
    let scale = r.h.node.gateway().config().settings.axes[axis0()].scale;
    let at = scale.position_from_wire(protocol::Pulses(c.position() as i32));
    assert!(
        at.0 > 10_00 && at.0 < 50_00,
        "jogged toward the stroke end: {at:?}"
    );
    // PWRT into point 9, which holds nothing.
    let nine = PositionNo::new(9).unwrap();
    r.inputs = r.inputs.with_position(nine);
    r.run(10);
    r.set(PioInputs::CSTR, true); // PWRT
    r.until(2_000, |o| o.pend()); // WEND
    let stored = |r: &Rig| {
        let c = r.h.bus.controller(axis0()).unwrap();
        let nv = &c.memory().nv;
        (nv.points[9], nv.point_writes[9])
    };
    let (row, writes) = stored(&r);
    assert_eq!(row[0], c_position(&r), "the position the axis is at");
    assert_ne!(row[pi(PointField::Velocity)], 0, "a speed: the jog speed");
    assert_eq!(writes, 1);
    r.set(PioInputs::CSTR, false);
    r.run(10);
    assert!(!r.outputs.pend(), "WEND OFF with PWRT");
    // One inching step toward home (JISL), PWRT again: the row follows.
    r.set(PioInputs::JISL, true);
    r.set(PioInputs::JOG_MINUS, true);
    r.run(300);
    r.set(PioInputs::JOG_MINUS, false);
    let step = scale.position_from_wire(protocol::Pulses(c_position(&r) as i32));
    assert_eq!(at.0 - step.0, 10, "one 0.10 mm step");
    r.set(PioInputs::CSTR, true);
    r.until(2_000, |o| o.pend());
    assert_eq!(
        stored(&r),
        (
            {
                let mut row = row;
                row[0] = c_position(&r);
                row
            },
            2
        )
    );
    // Again, without moving: compared, nothing written, WEND all the same.
    r.set(PioInputs::CSTR, false);
    r.run(10);
    r.set(PioInputs::CSTR, true);
    r.until(2_000, |o| o.pend());
    assert_eq!(stored(&r).1, 2, "no V5 for the same position");
    assert_eq!(
        r.h.node.gateway().command_state(axis0()).0,
        CommandState::Done
    );
}

/// The simulated axis' position as the controller stores it (the wire's 32 bits).
fn c_position(r: &Rig) -> u32 {
    r.h.bus.controller(axis0()).unwrap().position() as i32 as u32
}
