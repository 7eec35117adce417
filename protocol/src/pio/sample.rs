//! [`Pio::sample`]: one reading of the inputs, turned into the job to submit and the outputs
//! to drive.

use super::*;

impl Pio {
    /// Read the inputs at `now`: the outputs to drive and the job to submit for the axis, if any.
    ///
    /// `axis` is the engine's state of the axis; `link_ok` is the gateway's verdict on it (for
    /// example `false` while the bus is being set up). The link counts as up only if `link_ok`,
    /// the engine has the axis [`Online`](Link::Online) and a status has been received. `home`
    /// is the direction the axis homes in (its configuration's, the one fact for every face).
    pub fn sample(
        &mut self,
        now: Instant,
        inputs: PioInputs,
        axis: &AxisState,
        link_ok: bool,
        home: HomeDirection,
    ) -> (PioOutputs, Option<JobKind>) {
        let report = axis.report.filter(|_| link_ok && axis.link == Link::Online);

        let known_before = self.inputs.known;
        let changed = self.inputs.update(now, inputs.bits(), self.config.debounce);
        let pattern = self.config.pattern;
        let select = if pattern.solenoid() {
            pattern.st_inputs()
        } else {
            PioInputs::MASK & 0x3F
        };
        if changed & select != 0 {
            self.pc_since = now;
        }
        let may_run = self.inputs.on(PioInputs::STP_N);
        let stp_known = self.inputs.known(PioInputs::STP_N);

        // *STP: the fail-safe path first.
        if changed & PioInputs::STP_N.bits() != 0 && !may_run {
            self.stop_due = true;
            self.cut_short();
        }
        if stp_known
            && !may_run
            && report.is_some()
            && axis.moving()
            && self.last_stop.is_none_or(|t| now.since(t) >= STOP_REPEAT)
        {
            self.stop_due = true;
        }

        if let Some(report) = report {
            // SON: on a change, and while the status disagrees (rate-limited).
            let son = self.inputs.on(PioInputs::SON);
            let son_bit = PioInputs::SON.bits();
            let son_changed = changed & known_before & son_bit != 0;
            let disagrees = self.pending_servo.is_none()
                && !report.outputs.alarm_active()
                && report.status.servo() != son
                && self
                    .last_servo
                    .is_none_or(|t| now.since(t) >= self.config.servo_retry);
            if self.inputs.known(PioInputs::SON) && (son_changed || disagrees) {
                self.pending_servo = Some(son);
            }
            if self.inputs.rose(PioInputs::RES, changed, known_before) {
                self.refusal = false;
                if report.outputs.alarm_active() {
                    self.pending_reset = true;
                } else {
                    self.acknowledge = true;
                }
            }
            let st_rose = changed & known_before & self.inputs.stable & pattern.st_inputs();
            let start = if pattern.solenoid() {
                // A refused strobe holds the ST inputs until RES, as IAI's alarm 085.
                st_rose != 0 && !self.refusal
            } else {
                self.inputs.rose(PioInputs::CSTR, changed, known_before)
            };
            if may_run && start {
                self.strobe = true;
                self.st_rose |= st_rose;
                self.pending_home = false;
            }
            if may_run && !self.refusal && self.inputs.rose(PioInputs::HOME, changed, known_before)
            {
                self.pending_home = true;
                self.strobe = false;
                self.st_rose = 0;
                self.pending_move = None;
            }
        } else {
            // Nothing is kept for an axis that cannot hear it.
            self.pending_servo = None;
            self.pending_reset = false;
            self.waiting = None;
            self.at = None;
        }
        if report.is_none() || !may_run {
            self.strobe = false;
            self.st_rose = 0;
            self.pending_move = None;
            self.pending_home = false;
        }
        if !may_run {
            // *STP's stop ends a level-mode hold (a hold survives a link down: its release
            // still stops the axis).
            self.held = None;
        }
        if TEACHING && pattern == Pattern::Teaching {
            self.teaching(changed, known_before, may_run, report.is_some(), axis);
        }
        if self.strobe && now.since(self.pc_since) >= self.config.settle {
            self.strobe = false;
            let point = self.strobe_point();
            match point {
                // In teaching mode, CSTR's port is PWRT.
                Some(point) if TEACHING && self.teach.active => self.teach.write(point),
                _ => self.pending_move = point,
            }
        }
        if let (Some(waiting), Some(report)) = (self.waiting.as_mut(), report.as_ref()) {
            let target = waiting.target;
            if let Some(end) = waiting.update(axis, report) {
                self.waiting = None;
                self.held = None;
                match end {
                    End::Reached => {
                        self.short = false;
                        if let Target::Point(point) = target {
                            self.at = Some(point);
                        }
                    }
                    End::Short => self.short = true,
                    End::Other => {}
                }
            }
        }
        if self.waiting.is_none() && axis.moving() {
            // Moved by something else than the PIO's move: not at the PIO's point any more.
            self.at = None;
        }
        // Level mode: the ST input released before its point is reached stops the move (the
        // wait is updated first: a release on the sample that shows the point reached is after
        // the arrival). A hold outlives a link down, whose wait is dropped: it stops then too.
        if let Some(point) = self.held {
            if self.inputs.stable & 1 << point.get() == 0 {
                self.held = None;
                self.stop_due = true;
            }
        }

        let job = self.next_job(now, axis, report, home);

        self.outputs = self.outputs_for(axis, report);
        (self.outputs, job)
    }

    /// Pattern 1: MODE enters and leaves teaching mode, the JOG inputs jog (see
    /// [`teach`](teach)).
    fn teaching(
        &mut self,
        changed: u16,
        known_before: u16,
        may_run: bool,
        heard: bool,
        axis: &AxisState,
    ) {
        let mode = self.inputs.on(PioInputs::ST6);
        if !mode && self.teach.active {
            // Leaving stops a jog under way, and drops a PWRT still waiting for PC1-PC8 to
            // settle (it must not become a CSTR).
            self.stop_due |= self.teach.leave();
            self.strobe = false;
        } else if mode
            && !self.teach.active
            && heard
            && !axis.moving()
            && self.waiting.is_none()
            && !self.motion_pending()
        {
            self.teach.active = true;
        }
        if !self.inputs.on(PioInputs::CSTR) {
            self.teach.wend = false;
        }
        if !self.teach.active {
            return;
        }
        if !may_run {
            // *STP's own rule stops the axis.
            self.teach.drop_motion();
            return;
        }
        // No new jog for an axis that does not answer; but a jog outlives a link down, and its
        // release still stops the axis.
        let rose = |flag| heard && self.inputs.rose(flag, changed, known_before);
        let jog = JogInputs {
            plus: self.inputs.on(PioInputs::JOG_PLUS),
            minus: self.inputs.on(PioInputs::JOG_MINUS),
            plus_rose: rose(PioInputs::JOG_PLUS),
            minus_rose: rose(PioInputs::JOG_MINUS),
            inch: self.inputs.on(PioInputs::JISL),
        };
        self.stop_due |= self.teach.jog_inputs(jog);
    }

    /// The point a strobe selects, taken once the inputs that select it have settled: `None`,
    /// and the inputs kept for CMST, for a selection the gateway refuses.
    fn strobe_point(&mut self) -> Option<PositionNo> {
        let pattern = self.config.pattern;
        let rose = core::mem::take(&mut self.st_rose);
        let word = if pattern.solenoid() {
            let on = self.inputs.stable & pattern.st_inputs();
            match self.config.start {
                // A pulse shorter than the settle time is still a start.
                StartMode::Edge if on == 0 => rose,
                _ => on,
            }
        } else {
            self.inputs.stable & 0x3F
        };
        let point = if pattern.solenoid() {
            // Exactly one ST input (none: released before it was taken, in level mode).
            match word.count_ones() {
                0 => return None,
                1 => u8::try_from(word.trailing_zeros()).ok(),
                _ => {
                    // As IAI's alarm 085: nothing more moves, a move under way stops.
                    self.refusal = true;
                    self.stop_due |= self.held.take().is_some() || self.waiting.is_some();
                    return self.refuse(word);
                }
            }
        } else {
            // PC16/PC32 ON: refused (the RC has 16 positions).
            self.inputs().position().map(PositionNo::get)
        };
        let Some(point) = point.and_then(PositionNo::new) else {
            return self.refuse(word);
        };
        if self.config.start == StartMode::Level && pattern.solenoid() {
            self.held = Some(point);
        }
        Some(point)
    }

    /// A strobe refused: its inputs kept for CMST.
    fn refuse(&mut self, inputs: u16) -> Option<PositionNo> {
        self.refused_inputs = u8::try_from(inputs).ok();
        None
    }

    /// The most urgent job due, if any; the others stay pending.
    fn next_job(
        &mut self,
        now: Instant,
        axis: &AxisState,
        report: Option<StatusReport>,
        home: HomeDirection,
    ) -> Option<JobKind> {
        if self.stop_due {
            // A start that came with it (a level-mode ST changed for another, a JOG input for
            // the other) still runs after it: *STP's own rule drops what it must not.
            self.stop_due = false;
            self.last_stop = Some(now);
            self.cut_short();
            return Some(JobKind::Stop);
        }
        let report = report?;
        if self.pending_servo == Some(false) {
            self.pending_servo = None;
            self.last_servo = Some(now);
            return Some(JobKind::Servo(false));
        }
        if self.pending_reset {
            self.pending_reset = false;
            return Some(JobKind::AlarmReset);
        }
        if self.pending_servo == Some(true) {
            self.pending_servo = None;
            self.last_servo = Some(now);
            return Some(JobKind::Servo(true));
        }
        if self.pending_home {
            self.pending_home = false;
            self.at = None;
            self.waiting = Some(Await::new(Target::Home, now, axis, &report));
            return Some(JobKind::Home(home));
        }
        if let Some(point) = self.pending_move.take() {
            self.at = None;
            self.waiting = Some(Await::new(Target::Point(point), now, axis, &report));
            return Some(JobKind::MoveToPoint(point, None));
        }
        if TEACHING {
            self.teach.take_job()
        } else {
            None
        }
    }

    fn outputs_for(&self, axis: &AxisState, report: Option<StatusReport>) -> PioOutputs {
        let Some(report) = report else {
            return PioOutputs::SAFE;
        };
        let out = report.outputs;
        let alarm = out.alarm_active();
        let masked = self.waiting.is_some() || self.short;
        let homing = self
            .waiting
            .is_some_and(|w| matches!(w.target, Target::Home));
        let pm = if alarm || !masked { out.pm() } else { 0 };
        let pattern = self.config.pattern;
        let cstr_held = !pattern.solenoid() && self.inputs.on(PioInputs::CSTR);
        let word = PioOutputs::NONE
            .with_pm(pm)
            .with(PioOutputs::MOVE, axis.moving())
            .with(PioOutputs::ZONE1, out.zone())
            .with(PioOutputs::HEND, out.zfin() && !homing)
            .with(PioOutputs::PEND, out.pfin() && !masked && !cstr_held)
            .with(PioOutputs::SV, report.status.servo())
            .with(PioOutputs::LINK, true)
            .with(PioOutputs::ALM_N, !alarm && !self.refusal);
        // The pattern's own outputs on OUT0-OUT6.
        let own = match pattern {
            Pattern::Positioning => return word,
            // Teaching mode: MODES, and WEND on PEND's port.
            Pattern::Teaching if TEACHING && self.teach.active => {
                return word
                    .with(PioOutputs::MODES, true)
                    .with(PioOutputs::PEND, self.teach.wend)
            }
            Pattern::Teaching => return word,
            // PEn: point n complete, reached by the PIO's move; OFF with *ALM.
            Pattern::Solenoid7 => match self.at {
                Some(point) if word.pend() && word.alm_n() => 1 << point.get(),
                _ => 0,
            },
            // LSn: within point n's band, however the axis got there.
            Pattern::Solenoid3 => axis.position.map_or(0, |position| {
                self.reeds
                    .iter()
                    .enumerate()
                    .filter(|(_, band)| band.is_some_and(|b| b.holds(position)))
                    .fold(0, |bits, (n, _)| bits | 1 << n)
            }),
        };
        let own = own & pattern.st_inputs();
        PioOutputs::from_bits(word.bits() & pattern.outputs() & !pattern.st_inputs() | own)
    }
}
