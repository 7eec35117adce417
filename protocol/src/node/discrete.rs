//! The node's discrete I/O: the PIO input pins turned into the PIO axis' jobs and the output
//! pins' word ([`crate::pio`] says what each signal means).

use super::*;

impl Node {
    /// The PIO input pins at `now` (bit n = PCON pattern 0 port INn; *STP high = may run).
    pub fn sample_inputs(&mut self, now: Instant, inputs: PioInputs) {
        let Some(axis) = self.gateway.config().settings.pio_axis else {
            self.outputs = PioOutputs::SAFE;
            return;
        };
        let config = self.gateway.config();
        let (pattern, start) = (config.settings.pio_pattern, config.settings.pio_start);
        if (pattern, start) != (self.pio.config().pattern, self.pio.config().start) {
            // Another pattern: the inputs mean other things, so they start over (each must be
            // seen OFF and ON again before its edge counts, *STP ON before anything moves). A
            // move, jog or hold of the old one is stopped: its release would no longer stop it.
            if self.pio.in_motion() {
                // As the PIO's own stops: a refusal (a full queue) is the gateway's to count.
                let _ = self.gateway.command(axis, JobKind::Stop);
            }
            self.pio = Pio::new(pio::Config {
                pattern,
                start,
                ..*self.pio.config()
            });
        }
        match pattern {
            Pattern::Solenoid3 => {
                let reeds = self.reeds(axis);
                self.pio.set_reeds(reeds);
            }
            Pattern::Teaching if pio::TEACHING => {
                self.pio.set_jog(self.jog(axis));
                if let Some(stored) = self.gateway.take_taught() {
                    self.pio.taught(stored);
                }
            }
            _ => {}
        }
        let state = *self.gateway.engine().axis(axis);
        let link_ok = !self.gateway.engine().establishing();
        let home = self.gateway.config().settings.axes[axis].scale.home;
        let (outputs, job) = self.pio.sample(now, inputs, &state, link_ok, home);
        self.outputs = outputs;
        if let Some(inputs) = self.pio.take_refused() {
            self.gateway.pio_refused(axis, inputs);
        }
        if let Some(point) = self.pio.take_teach().filter(|_| pio::TEACHING) {
            // Refused: WEND stays OFF (another PWRT running: CMST 3, reason 9; an axis that
            // does not answer: nothing recorded, as for any command then).
            if self.gateway.teach(axis, point).is_err() {
                self.pio.taught(false);
            }
            self.dirty = true;
        }
        if self.pio.take_acknowledge() {
            self.gateway.acknowledge_by_wire();
            self.dirty = true;
        }
        if let Some(kind) = job {
            // A refusal is shown in CMST (or, for an axis that went offline between the sample
            // and now, not taken at all), and on the outputs: the PIO stops waiting for it.
            if self.gateway.command(axis, kind).is_err() {
                self.pio.refused(&kind);
            }
            self.dirty = true;
        }
    }

    /// Pattern 5's points 0-2 as the controller holds them (fetched while not cached): a
    /// point with no speed is empty, and has no reed switch.
    fn reeds(&mut self, axis: Axis) -> [Option<Band>; 3] {
        let mut reeds = [None; 3];
        for (n, reed) in (0..).zip(reeds.iter_mut()) {
            let row = PositionNo::new(n).and_then(|p| self.gateway.point_row(axis, p));
            *reed = row
                .filter(|row| row.get(PointField::Velocity) != 0)
                .map(|row| Band {
                    position: Pulses::from_wire(row.get(PointField::Position)),
                    band: row.get(PointField::Band),
                });
        }
        reeds
    }

    /// Pattern 1's jog of `axis` in its units: to 0 mm and to the stroke, one PIOINCH step, at
    /// PIOJOG and [`PIO_ACCEL`]; `None` if the axis' scale cannot express them.
    fn jog(&self, axis: Axis) -> Option<Jog> {
        let config = self.gateway.config();
        let axis = &config.settings.axes[axis];
        let scale = &axis.scale;
        let wire = |at: i32| scale.position_to_wire(Length(at)).ok();
        let step = |distance: i32| scale.distance_to_wire(Length(distance)).ok();
        let inch = config.settings.pio_inch.length().0;
        Some(Jog {
            plus_end: wire(axis.stroke.0)?,
            minus_end: wire(0)?,
            plus_step: step(inch)?,
            minus_step: step(-inch)?,
            velocity: scale.velocity(config.settings.pio_jog.speed()).ok()?,
            acceleration: scale.acceleration(Accel(u32::from(PIO_ACCEL))).ok()?,
        })
    }
}
