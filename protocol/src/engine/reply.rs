//! What an answer changes: the bytes received are deframed into a reply; its transaction
//! ends, and the reply updates the axis' status, link and position, its job and its move's
//! estimate ([`approach`](super::approach)).

use super::*;

impl Engine {
    /// Bytes received from the line at `now`. Whether they completed anything (a frame, or a
    /// candidate rejected): until then the engine has nothing new to do, so a caller that
    /// polls only when something changed may skip its poll (bytes arrive one interrupt at a
    /// time, 32 per transaction).
    pub fn receive(&mut self, now: Instant, bytes: &[u8]) -> bool {
        self.received_at = now;
        let mut changed = false;
        for &byte in bytes {
            match self.deframer.push(byte) {
                Ok(Packet::Frame(frame)) => {
                    self.on_frame(now, &frame);
                    changed = true;
                }
                Ok(Packet::CommChange) | Err(nb::Error::WouldBlock) => {}
                Err(nb::Error::Other(error)) => {
                    self.on_bad_candidate(now, error);
                    changed = true;
                }
            }
        }
        changed
    }

    // Not inlined into its callers: 132 bytes less on the F103 (scripts/size-report.sh).
    #[inline(never)]
    pub(super) fn complete(&mut self, now: Instant, flight: InFlight, reply: Reply) {
        let axis = flight.request.axis;
        let state = &mut self.axes[axis];
        state.counters.replies = state.counters.replies.wrapping_add(1);
        if !self.config.axes.contains(axis) {
            // Its axis left the bus while it was on the wire (`leave`): the line is free, and
            // that is all. Online, a status or a position would put the axis back into the
            // schedule (a position read, a resend).
            return;
        }
        if let Some(code) = reply.rejection() {
            state.counters.rejections = state.counters.rejections.wrapping_add(1);
            state.last_error = Some(LinkError::Rejected(code));
        }
        if matches!(flight.request.command, Command::CancelMotion) {
            // Any answer to a `d` pays an owed stop: the axis has heard it (its status says
            // the rest, and a controller that refuses `d` must not lose its polls for ever).
            self.owed = self.owed.without(axis);
        }
        if flight.origin != Origin::Rejoin {
            // Online means answering at the bus rate; a rejoin talks at the power-up rate.
            self.set_link(now, axis, Link::Online);
        }
        if let Some(report) = reply.report() {
            self.update_report(now, axis, *report);
            if flight.origin == Origin::Job {
                // A job's direct command answered with the axis' status, as a poll would have
                // (complete edition §3-1-2): the next poll counts from it.
                self.schedule.reported(now, axis);
            }
        }
        let reads_pnow =
            matches!(flight.request.command, Command::ReadMemory { address } if address == PNOW);
        if let (true, Some(position)) = (reads_pnow, reply.position()) {
            // Whoever asked (polling, a job), PNOW is PNOW.
            let state = &mut self.axes[axis];
            let previous = state.position;
            state.position = Some(position);
            state.position_at = Some(now);
            let transaction = self
                .schedule
                .transaction((self.config.baud, self.config.rtim));
            self.schedule
                .approach(axis)
                .position_read(now, position, previous, transaction);
        }
        if flight.stands_in {
            // Its origin's frame did not go: the job, establishment step or rejoin step sends
            // it next (the stop's answer moved nothing on but the status).
            return;
        }
        // A move whose job a stop cancelled on the wire, taken: no job moves on to say it
        // started. A `t` its own axis refuses still starts the others' buffered moves (§4-4-17).
        let refused_t = matches!(flight.request.command, Command::ExecuteBuffered)
            && reply.rejection().is_some();
        if flight.origin == Origin::Cancelled || refused_t {
            self.may_have_moved(&flight.request);
        }
        if flight.origin == Origin::Job && reply.rejection().is_none() {
            let at = self.axes[axis].position;
            // A point's position is not in its Q3: the job may know it. A `t` starts the moves
            // its axes buffered.
            let (point, started) = match self.active[axis].as_ref().map(|a| a.job.kind) {
                Some(JobKind::MoveToPoint(_, target)) => (target, AxisSet::EMPTY),
                Some(JobKind::StartBuffered(axes))
                    if matches!(flight.request.command, Command::ExecuteBuffered) =>
                {
                    (None, axes.with(axis))
                }
                _ => (None, AxisSet::EMPTY),
            };
            self.schedule
                .approach(axis)
                .command_accepted(now, &flight.request.command, at, point);
            for a in started.iter() {
                self.schedule.approach(a).started(now);
            }
        }
        match flight.origin {
            Origin::Poll | Origin::Probe | Origin::Position | Origin::Cancelled => {}
            Origin::Stop(id) => {
                let result = match (reply.rejection(), reply.report()) {
                    (Some(code), _) => Err(JobError::Rejected(code)),
                    (None, Some(report)) => Ok(JobOutput::Status(*report)),
                    (None, None) => Ok(JobOutput::Done),
                };
                if result.is_ok() {
                    self.schedule.approach(axis).cancelled();
                }
                self.emit(Event::JobDone { id, axis, result });
            }
            Origin::Job => self.job_reply(now, axis, &reply),
            Origin::Establish => self.establish_reply(axis, &flight.request, &reply),
            Origin::Rejoin => self.rejoin_reply(axis, &flight.request, &reply),
        }
    }

    /// `request` may have set axes moving and no answer said so: an `m` or a `t` whose answer
    /// was lost (never resent, §5 (2), (3)), any move whose attempt was lost (a stop may cancel
    /// its job before the resend goes), a move whose job a stop cancelled while it was on the
    /// wire, a `t` its own axis refused (the others still start). Such a move can end before any
    /// status shows it (a short one, over before the axis' next poll), and the position read when
    /// its job failed was taken mid-move: the
    /// axes count as moving until a status says otherwise, so that the first one that shows
    /// them standing has their position read until it rests. A `t` may have started any axis
    /// that has a move buffered.
    pub(super) fn may_have_moved(&mut self, request: &Request) {
        if !request.command.moves() {
            return;
        }
        let axes = match request.command {
            Command::ExecuteBuffered => self.config.axes,
            _ => AxisSet::EMPTY.with(request.axis),
        };
        // Not an offline axis: no status would clear its mark (which held rejoin tries off for
        // good), and going online reads its position anyway.
        for a in axes.iter().filter(|&a| self.axes[a].link != Link::Offline) {
            self.schedule.approach(a).may_have_started();
        }
    }

    pub(super) fn set_link(&mut self, now: Instant, axis: Axis, link: Link) {
        let state = &mut self.axes[axis];
        if state.link == link {
            return;
        }
        state.link = link;
        match link {
            Link::Online => {
                // Read its position once, so that it is known before the first move.
                self.schedule.position_due(axis);
                self.emit(Event::Online(axis));
            }
            Link::Offline => {
                self.schedule.went_offline(now, axis);
                self.schedule.approach(axis).clear();
                self.emit(Event::Offline(axis));
                // A job that waits on an axis that no longer answers cannot finish, and one
                // waiting its turn must not run minutes later when the axis is back.
                self.fail_job(axis, JobError::Timeout);
                self.cancel_waiting(axis, JobError::Offline);
            }
            Link::Unknown => {}
        }
    }

    pub(super) fn update_report(&mut self, now: Instant, axis: Axis, report: StatusReport) {
        // A move commanded since the last status counts as moving, so that one that began and
        // ended between two status reports (a short one, or one to a target already in its
        // position band) is seen to stop too.
        let commanded = self.schedule.approach(axis).unseen();
        let state = &mut self.axes[axis];
        let changed = state.report != Some(report);
        let was_moving = state.moving() || commanded;
        state.report = Some(report);
        state.report_at = Some(now);
        let moving = state.moving();
        self.schedule.approach(axis).status_seen();
        // Just stopped: its position is worth reading. (A mover's are read for its estimate
        // when its acceleration is over, and now and then: the schedule.)
        let stopped = was_moving && !moving;
        if stopped && !self.job_reads_position(axis) {
            self.schedule.position_due(axis);
        }
        if stopped {
            let arrived = report.outputs.pfin();
            self.schedule.approach(axis).stopped(arrived);
        }
        if changed {
            self.emit(Event::Status { axis, report });
        }
        self.check_await(now, axis, &report);
        self.check_cross_axis_waits(now, axis);
    }
}
