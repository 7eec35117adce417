//! The PIO state machine in virtual time: scripted input sequences against hand-made axis states.
//!
//! A [`Rig`] samples the PIO every millisecond, as the firmware does. Times in the assertions are
//! in milliseconds from the rig's start; the rig first runs a warm-up so that every input is
//! recognised, with *STP and SON ON and the axis ready (servo on, homed, in position at point 3).

mod inputs;
mod outputs;
mod patterns;
mod properties;
// Pattern 1, in the builds that have it (not the F103's).
#[cfg(feature = "teaching")]
mod teaching;

use protocol::engine::{AxisState, Counters, JobKind, Link};
use protocol::pio::{Config, Pio, PioInputs as In, PioOutputs as Out};
use protocol::time::Instant;
use protocol::{
    AlarmCode, HomeDirection, Inputs, Outputs, PositionNo, Status, StatusReport, RTIM_AFTER_BREAK,
};

const MS: u64 = 1000;

/// Status: power, servo, run, home.
const READY_STATUS: u8 = 0x0F;
/// OUT: *ALM on, ZFIN, PFIN.
const DONE_OUT: u8 = 0xB0;

fn p(n: u8) -> PositionNo {
    PositionNo::new(n).unwrap()
}

fn report(status: u8, alarm: u8, out: u8) -> StatusReport {
    StatusReport {
        status: Status::from_bits(status),
        alarm: AlarmCode(alarm),
        inputs: Inputs::default(),
        outputs: Outputs::from_bits(out),
    }
}

fn axis(report: StatusReport, at_us: u64) -> AxisState {
    AxisState {
        link: Link::Online,
        report: Some(report),
        report_at: Some(Instant(at_us)),
        position: None,
        position_at: None,
        rtim: RTIM_AFTER_BREAK,
        last_error: None,
        counters: Counters::default(),
    }
}

/// *STP and SON ON, position 3 selected.
fn base() -> In {
    In::STP_N | In::SON | In::PC1 | In::PC2
}

struct Rig {
    pio: Pio,
    /// Microseconds.
    now: u64,
    start: u64,
    axis: AxisState,
    link_ok: bool,
    /// The axis' home direction (AXISCFG).
    home: HomeDirection,
    inputs: In,
    out: Out,
}

impl Rig {
    fn new(config: Config) -> Rig {
        Rig::with_axis(config, axis(report(READY_STATUS, 0, DONE_OUT | 3), 0))
    }

    fn with_axis(config: Config, axis: AxisState) -> Rig {
        Rig::with_inputs(config, axis, base())
    }

    /// A rig whose warm-up holds `inputs`.
    fn with_inputs(config: Config, axis: AxisState, inputs: In) -> Rig {
        let mut rig = Rig {
            pio: Pio::new(config),
            now: 0,
            start: 0,
            axis,
            link_ok: true,
            home: HomeDirection::MotorEnd,
            inputs,
            out: Out::SAFE,
        };
        let jobs = rig.run(30);
        assert_eq!(jobs, vec![], "warm-up");
        rig.start = rig.now;
        rig
    }

    /// Milliseconds since the warm-up.
    fn t(&self) -> u64 {
        (self.now - self.start) / MS
    }

    /// One sample at the current time, then 1 ms passes.
    fn tick(&mut self) -> Option<JobKind> {
        let (out, job) = self.pio.sample(
            Instant(self.now),
            self.inputs,
            &self.axis,
            self.link_ok,
            self.home,
        );
        self.out = out;
        self.now += MS;
        job
    }

    /// `n` samples; the jobs with the time (ms) of the sample that returned them.
    fn run(&mut self, n: u64) -> Vec<(u64, JobKind)> {
        let mut jobs = vec![];
        for _ in 0..n {
            let t = self.t();
            if let Some(job) = self.tick() {
                jobs.push((t, job));
            }
        }
        jobs
    }

    fn set(&mut self, flag: In, on: bool) {
        self.inputs = self.inputs.with(flag, on);
    }

    fn select(&mut self, n: u8) {
        self.inputs = self.inputs.with_position(p(n));
    }

    /// A new status, received now.
    fn status(&mut self, status: u8, alarm: u8, out: u8) {
        self.axis.report = Some(report(status, alarm, out));
        self.axis.report_at = Some(Instant(self.now));
    }
}
