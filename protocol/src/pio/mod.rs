//! Discrete I/O (PIO) for one axis, compatible with IAI PCON PIO patterns 0, 1, 4 and 5: the 24 V
//! signals a PLC wires to an IAI controller, turned into engine jobs, and the axis' status turned
//! back into output signals.
//!
//! # Patterns
//!
//! [`Config::pattern`] says which port carries which signal ([`Pattern`], IAI's numbers). This
//! documentation describes pattern 0; the others share its debounce, *STP, HOME, RES, SON, the
//! outputs' link and alarm rules, and differ in how a move starts and what OUT0-OUT6 show:
//!
//! - **4 and 5** (solenoid valve modes): an ST input (IN0-IN6, or IN0-IN2) takes the place of
//!   PC1-PC8 and CSTR: its rising edge selects and starts the move, once the ST inputs have been
//!   stable for [`Config::settle`] (exactly one ON, else refused until RES: *ALM OFF). In level
//!   mode ([`StartMode`]) releasing it before the point is reached stops the move. Pattern 4's
//!   PE0-PE6 show the point the PIO's move reached (with PEND); pattern 5's LS0-LS2 are reed
//!   switches: ON while the position is within a point's band ([`Pio::set_reeds`]). CSTR's mask
//!   of PEND does not apply.
//! - **1** (teaching, `pio/teach.rs`, [`Jog`]): pattern 0 while MODE is OFF; with MODE ON, the JOG inputs jog
//!   and CSTR's port is PWRT, which asks the gateway to store the position
//!   ([`Pio::take_teach`], [`Pio::taught`]); MODES and WEND show it.
//!
//! Sans-IO like the [`engine`](crate::engine): the firmware reads the input pins into a
//! [`PioInputs`] word, calls [`Pio::sample`] with the time and the engine's
//! [`AxisState`] (about every millisecond: every time in this module is only as fine as the
//! sample period), submits the returned [`JobKind`] for the axis, and writes the returned
//! [`PioOutputs`] word to the output pins. The Modbus map can expose the same words as DIPM
//! (0x9003, [`Pio::inputs`]) and DOPM (0x9004).
//!
//! ```text
//! let inputs = PioInputs::from_bits(read_pins());
//! let (outputs, job) = pio.sample(now, inputs, engine.axis(axis), true, home);
//! if let Some(kind) = job { engine.submit(Job { axis, kind })?; }
//! write_pins(outputs.bits());
//! ```
//!
//! # Signals
//!
//! Bit n of the word is port INn / OUTn of PCON pattern 0 (field-research §2), so a PLC program
//! and a wiring plan for a PCON fit unchanged as far as the 16-position Robo Cylinder allows. Bits not
//! listed are ignored (inputs) or always OFF (outputs).
//!
//! | Signal | Bit | Logic | Meaning | PCON pattern 0 |
//! |---|---|---|---|---|
//! | PC1 | IN0 | ON = 1 | Position number bit 0 | IN0 PC1 |
//! | PC2 | IN1 | ON = 1 | Position number bit 1 | IN1 PC2 |
//! | PC4 | IN2 | ON = 1 | Position number bit 2 | IN2 PC4 |
//! | PC8 | IN3 | ON = 1 | Position number bit 3 (positions 0-15) | IN3 PC8 |
//! | PC16, PC32 | IN4, IN5 | ON = 1 | The Robo Cylinder has 16 positions: ON when a strobe latches refuses that strobe (no move) | IN4 PC16, IN5 PC32 |
//! | HOME | IN11 | rising edge | Home (`o`, in the axis' direction, AXISCFG) | IN11 HOME |
//! | *STP | IN12 | negative: OFF = stop | OFF: cancel the motion (`d`) at once; while OFF, CSTR and HOME are ignored. ON again does not resume | IN12 *STP (pause) |
//! | CSTR | IN13 | rising edge | Start: latch PC1-PC8, move to that point (Q3) | IN13 CSTR |
//! | RES | IN14 | rising edge | Alarm reset (servo off, `r03`) while an alarm is active; else acknowledges FAILSAFE once its cause is gone | IN14 RES |
//! | SON | IN15 | level | Servo on while ON, off while OFF | IN15 SON |
//! | PM1-PM8 | OUT0-OUT3 | ON = 1 | Completed position number; the abbreviated alarm code while *ALM is OFF (the gateway's FAILSAFE, 1-3, when that is why) | OUT0-OUT3 PM1-PM8 |
//! | MOVE | OUT6 | ON = moving | Servo on, positioning not complete, no alarm | OUT6 MOVE |
//! | ZONE1 | OUT7 | ON = inside | The controller's ZONE (between ZONL and ZONM, homed) | OUT7 ZONE1 |
//! | HEND | OUT10 | ON = homed | ZFIN | OUT10 HEND |
//! | PEND | OUT11 | ON = complete | PFIN, OFF from a start until the move is complete, after a move cut short and while CSTR is ON | OUT11 PEND |
//! | SV | OUT12 | ON = servo on | Status servo bit | OUT12 SV |
//! | LINK | OUT13 | ON = link OK | The gateway hears the axis (the RC has no emergency-stop signal; same polarity as *EMGS: ON = able to run) | OUT13 *EMGS |
//! | *ALM | OUT14 | negative: OFF = alarm | OFF while the controller is in alarm, the link is down, or the gateway's fail-safe is latched | OUT14 *ALM |
//!
//! # Inputs
//!
//! Every input is debounced ([`Config::debounce`], default 6 ms: the input time constant IAI
//! documents for its own controllers, which recognise an input only after it has held its new
//! level for 6 ms, ERC2 manual §3.5.1 "Recognition of input signals"): a change counts only once
//! the pin has read the new level on every sample for that long; 0 turns debouncing off. An
//! input that is ON when the gateway starts must go OFF and ON again before its edge counts, so a
//! CSTR or HOME held at power-up starts nothing.
//!
//! **CSTR** acts on its rising edge. The position number is latched from PC1-PC8 then, if they
//! have been unchanged for [`Config::settle`] (default 6 ms); if they changed more recently, the
//! strobe waits until they have been stable that long and then latches (it is never dropped, even
//! if CSTR falls meanwhile). Neither the project's notes nor the sources searched give IAI's
//! figure for how long before CSTR the number must be set, so the default is a choice: 6 ms, IAI's
//! input time constant, the time an IAI controller itself needs to see a changed PC bit; a PLC
//! program that sets the number early enough for an IAI controller is then early enough here.
//! The job is [`JobKind::MoveToPoint`].
//!
//! **HOME** acts on its rising edge: [`JobKind::Home`]. A CSTR strobe waiting to latch is
//! dropped.
//!
//! ***STP** is the fail-safe path. The sample on which it is recognised OFF returns
//! [`JobKind::Stop`] (before anything else; it also drops a waiting strobe). The Robo Cylinder
//! protocol has no pause: `d` cancels the remaining motion, so turning *STP ON again does **not**
//! resume the interrupted move; the PLC strobes CSTR again (PEND stays OFF until then: see
//! [Outputs](#outputs)). While *STP is OFF (or not yet
//! recognised after start-up), CSTR and HOME are ignored, and if the axis reports moving anyway
//! (a command from elsewhere, a stop lost while the link was down) the stop is repeated every
//! [`STOP_REPEAT`]. The stop is returned even while the link is down (it can only help).
//!
//! **RES** acts on its rising edge. While the axis reports an alarm it resets the alarm. The
//! Robo Cylinder resets an alarm only with the servo off ([`JobKind::AlarmReset`] turns it off
//! first), so an unconditional reset would drop the servo of a healthy axis whenever a PLC
//! program pulses RES without an alarm (at start-up, say). Without an alarm, the edge is the
//! gateway's fail-safe acknowledgement by wire ([`Pio::take_acknowledge`]): the gateway clears
//! FAILSAFE if its cause is gone, as a safety relay's reset.
//!
//! **SON** is a level: [`JobKind::Servo`]`(SON)` when SON changes, and again whenever the axis'
//! reported servo state differs from SON and no servo job was returned for
//! [`Config::servo_retry`] (default 1 s), while no alarm is active. This keeps a PCON's behaviour
//! without extra state: the servo comes on at start-up and after the link returns if SON is ON,
//! and comes back on after an alarm reset (which turns it off) while SON stays ON. SON is the
//! owner of the servo: a servo changed by other means (Modbus) is brought back to SON.
//!
//! Nothing is queued for an axis whose link is down: CSTR, HOME and RES edges are ignored then
//! (a move must not start minutes later when the link returns), and SON is re-applied by the
//! retry rule once it is back.
//!
//! One job per sample: when several are due on the same sample, they go in the order Stop,
//! servo off, alarm reset, servo on, home, move, one per sample (the others wait for the next
//! samples, if still allowed then).
//!
//! # Outputs
//!
//! While the link is down (`link_ok` false, the engine's [`Link`] not
//! [`Online`](Link::Online)) or before the first status, every output is OFF: *ALM OFF
//! (alarm), LINK OFF, PEND, HEND, SV, MOVE, ZONE1 and PM OFF. A PLC then sees an alarm and
//! nothing complete, which stops any sequence that waits for PEND or checks *ALM.
//!
//! Otherwise the outputs come from the axis' last status (complete edition §4-2): *ALM, ZONE1,
//! HEND (ZFIN), PEND (PFIN), SV (status servo bit), MOVE ([`AxisState::moving`]) and PM1-PM8
//! from the controller's own OUT byte. PM is never made up from the latched number: the
//! controller turns PM off when it receives the Q3 and shows the number when PFIN comes on, so
//! PM is the point it actually reached; while *ALM is OFF, PM is the abbreviated alarm code
//! (§8-1-1). Two masks make the outputs follow the PLC's handshake before the status catches up:
//!
//! - from the sample that returns a move or home until the status shows it done, PEND is OFF and
//!   PM is 0 (and HEND OFF for a home), as the controller does once it has the command (§4-2:
//!   "PM1-PM8 turn off ... after a new PTP move command"). "Done" is judged on statuses
//!   received after the command was returned: PFIN on with PM equal to the point (for a home,
//!   PFIN going off and on again with ZFIN on); the wait ends early on an alarm, a rejected
//!   command (the axis' rejection count changes), a new move or home, or the link going down;
//! - after a move or home the PIO returned was cut short, PEND stays OFF and PM 0 until a move
//!   or home reaches its point (HEND, SV, MOVE and *ALM follow the status). Cut short: *STP
//!   turned OFF while it was awaited, or the status showed the move running and then PFIN
//!   without its point (the gateway's stop input, the PLC watchdog's stop, a Modbus stop). On
//!   PCON, *STP is a pause (field-research §2: IN12 *STP): the move is held, not complete, and
//!   PEND (positioning complete) comes on only within the positioning band of the target (the
//!   RC's PFIN likewise: complete edition §4-2, "turns on ... when axis is within the
//!   Positioning Band of the set point data"). The Robo Cylinder has no pause: `d` cancels the
//!   move, and the controller then shows PFIN with PM 0 where the axis stopped, which a PLC
//!   waiting for PEND would take for the move done. A move cut short when the PIO did not start
//!   it (over Modbus) leaves PEND to the status;
//! - while CSTR is ON, PEND is OFF (PM still shows the number), as on IAI's controllers: their
//!   manuals say PEND is withheld while the start signal stays ON, even inside the positioning
//!   band, while the completed position number is output (ROBONET manual, Modbus start command
//!   CSTR, part 1 p. 135).
//!
//! A strobe while a move is still running is sent by the engine after that move (one job per
//! axis at a time); PEND stays OFF until the new point is reached or, if the status showed the
//! axis moving when the strobe came, until it has stopped and moved again.
//!
//! # Why [`JobKind`]
//!
//! [`Pio::sample`] returns the engine's own [`JobKind`] (only `Stop`, `Servo`, `AlarmReset`,
//! `Home` and `MoveToPoint`) rather than a PIO-specific action: the gateway submits it as it is,
//! there is no second vocabulary to map and keep in step, and tests compare exactly what the
//! engine will run.

mod completion;
mod debounce;
mod pattern;
mod sample;
mod signals;
mod teach;

pub use completion::Band;
use completion::{Await, End, Target};
pub use pattern::{Pattern, Ports, StartMode, TEACHING};
pub use signals::{PioInputs, PioOutputs};
pub use teach::Jog;
use teach::{JogInputs, Teach};

use crate::engine::{AxisState, JobKind, Link};
use crate::time::{Duration, Instant};
use crate::{HomeDirection, PositionNo, StatusReport};
use debounce::Debouncer;

/// The inputs are sampled this often (about: every time in this module is only as fine as
/// the sample period): 1 ms, so that the 6 ms debounce is six samples.
pub const SAMPLE_PERIOD: Duration = Duration::from_millis(1);

/// While *STP is OFF and the axis still reports moving, the stop is repeated this often.
pub const STOP_REPEAT: Duration = Duration::from_millis(100);

/// [`Config::servo_retry`] is at least this, so that a status that lags a servo command cannot
/// make the retry rule submit a job on every sample.
pub const SERVO_RETRY_MIN: Duration = Duration::from_millis(100);

/// How the PIO behaves; see the [module documentation](self).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// An input changes only after reading its new level this long (0: at once). Default 6 ms,
    /// IAI's input time constant.
    pub debounce: Duration,
    /// PC1-PC8 must have been stable this long when a CSTR strobe latches them; a strobe waits
    /// until they have (0: latch at the edge). Default 6 ms.
    pub settle: Duration,
    /// While the reported servo state differs from SON, the servo job is repeated this often
    /// (at least [`SERVO_RETRY_MIN`]). Default 1 s.
    pub servo_retry: Duration,
    /// The signals' ports, by IAI's pattern number. Default 0, positioning.
    pub pattern: Pattern,
    /// How the solenoid patterns' ST inputs start a move. Default level, as PCON.
    pub start: StartMode,
}

impl Config {
    /// 6 ms debounce and settle (IAI's input time constant), 1 s servo retry.
    pub const DEFAULT: Config = Config {
        debounce: Duration::from_millis(6),
        settle: Duration::from_millis(6),
        servo_retry: Duration::from_millis(1000),
        pattern: Pattern::Positioning,
        start: StartMode::Level,
    };
}

impl Default for Config {
    fn default() -> Config {
        Config::DEFAULT
    }
}

/// The PIO of one axis; see the [module documentation](self).
#[derive(Clone, Debug)]
pub struct Pio {
    config: Config,
    inputs: Debouncer,
    /// When the inputs that select a point (PC1-PC32, or the ST inputs) last changed
    /// (recognised levels).
    pc_since: Instant,
    /// A CSTR edge (or an ST edge) waiting for the inputs that select the point to settle.
    strobe: bool,
    /// The ST inputs that rose since the last strobe was taken (edge mode takes a pulse shorter
    /// than the settle time from these).
    st_rose: u16,
    /// Level mode: the ST input of the move under way; releasing it stops the move.
    held: Option<PositionNo>,
    /// The point the PIO's last move reached, while the axis has not moved since: pattern 4's
    /// PE output (the controller's PM reads 0 after a home or a direct move, as after a move
    /// to point 0).
    at: Option<PositionNo>,
    /// Two or more ST inputs at once were refused: *ALM OFF until RES (IAI's alarm 085).
    refusal: bool,
    /// The inputs of a refused strobe, not yet taken by the gateway (CMST/CMER shows them).
    refused_inputs: Option<u8>,
    /// Pattern 5: points 0-2, where known.
    reeds: [Option<Band>; 3],
    /// Pattern 1: teaching mode.
    teach: Teach,
    /// A latched move not yet returned.
    pending_move: Option<PositionNo>,
    pending_home: bool,
    pending_reset: bool,
    pending_servo: Option<bool>,
    stop_due: bool,
    last_stop: Option<Instant>,
    last_servo: Option<Instant>,
    waiting: Option<Await>,
    /// A move or home was stopped short: PEND OFF and PM 0 until one reaches its point.
    short: bool,
    outputs: PioOutputs,
    /// A RES edge while the axis showed no alarm, not taken yet.
    acknowledge: bool,
}

impl Pio {
    /// A PIO with every input not yet recognised (as OFF: *STP OFF, so nothing may move until
    /// it has read ON for the debounce time).
    pub const fn new(config: Config) -> Pio {
        let servo_retry = if config.servo_retry.0 < SERVO_RETRY_MIN.0 {
            SERVO_RETRY_MIN
        } else {
            config.servo_retry
        };
        let config = Config {
            servo_retry,
            ..config
        };
        Pio {
            config,
            inputs: Debouncer::new(),
            pc_since: Instant(0),
            strobe: false,
            st_rose: 0,
            held: None,
            at: None,
            refusal: false,
            refused_inputs: None,
            reeds: [None; 3],
            teach: Teach::new(),
            pending_move: None,
            pending_home: false,
            pending_reset: false,
            pending_servo: None,
            stop_due: false,
            last_stop: None,
            last_servo: None,
            waiting: None,
            short: false,
            outputs: PioOutputs::SAFE,
            acknowledge: false,
        }
    }

    /// The configuration in force.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// The recognised (debounced) inputs; inputs not recognised yet read OFF.
    pub fn inputs(&self) -> PioInputs {
        PioInputs::from_bits(self.inputs.stable)
    }

    /// The outputs of the last sample.
    pub fn outputs(&self) -> PioOutputs {
        self.outputs
    }

    /// The gateway refused `job`, which the last [`sample`](Pio::sample) returned (the stop
    /// input holds the axis, the queue is full: CMST shows why). For a move or a home nothing
    /// will run, so the outputs follow the status again from the next sample rather than wait,
    /// PEND off, for a move that is not coming: a PLC that strobed a point then sees PEND with
    /// the point the axis is at. Any other refused job leaves a wait for an accepted move as it
    /// is.
    pub fn refused(&mut self, job: &JobKind) {
        if matches!(job, JobKind::Home(_) | JobKind::MoveToPoint(..)) {
            self.waiting = None;
            self.held = None;
        }
    }

    /// The inputs of a strobe the PIO refused since the last call, for CMST/CMER: PC1-PC32
    /// with PC16 or PC32 ON (pattern 0), or the ST inputs when more than one was ON (patterns
    /// 4 and 5; bit n = STn).
    pub fn take_refused(&mut self) -> Option<u8> {
        self.refused_inputs.take()
    }

    /// Pattern 1: where and how fast the JOG inputs move the axis (`None`: not known; the JOG
    /// inputs then do nothing).
    pub fn set_jog(&mut self, jog: Option<Jog>) {
        self.teach.jog = jog;
    }

    /// Pattern 1: the point a PWRT asks the gateway to store the axis' position into, once.
    pub fn take_teach(&mut self) -> Option<PositionNo> {
        self.teach.take_request()
    }

    /// Pattern 1: how the store [`take_teach`](Pio::take_teach) asked for ended: WEND turns ON
    /// if it was stored (until PWRT turns OFF).
    pub fn taught(&mut self, stored: bool) {
        self.teach.wend = stored && self.inputs.on(PioInputs::CSTR);
    }

    /// Pattern 5: where points 0-2 are (`None`: not known, or the controller holds no such
    /// point). LSn is OFF for a point not known.
    pub fn set_reeds(&mut self, reeds: [Option<Band>; 3]) {
        self.reeds = reeds;
    }

    /// A stop drops the wait for a move or home the PIO returned: that one is cut short.
    fn cut_short(&mut self) {
        self.short |= self.waiting.take().is_some();
    }

    /// Whether RES rose while the axis showed no alarm since the last call: the gateway's
    /// fail-safe acknowledgement by wire (see RES in the [module documentation](self)).
    pub fn take_acknowledge(&mut self) -> bool {
        core::mem::take(&mut self.acknowledge)
    }

    /// Whether the PIO has motion of its own under way or coming: a move or home it started and
    /// waits for, a level-mode hold, a held jog, or a start not yet returned. A PIO replaced
    /// (another pattern) while it is stops the axis: nothing else would stop it on a release.
    pub fn in_motion(&self) -> bool {
        self.waiting.is_some()
            || self.held.is_some()
            || self.teach.jogging()
            || self.motion_pending()
    }

    /// Whether a CSTR strobe waits for PC1-PC8 to settle, or a move or home waits to be returned.
    pub fn motion_pending(&self) -> bool {
        self.strobe || self.pending_move.is_some() || self.pending_home
    }
}
