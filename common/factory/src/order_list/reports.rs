//! What the stations publish and their presence on the bus: statuses,
//! reports journalled and raised as alarms, job events (an order's end),
//! and a station lost or back.

use super::*;

impl<R: Records, S: RecipeSource> OrderList<R, S> {
    /// A station came onto (`present`) or left the bus. A workstation lost
    /// while no order runs (in any mode, a manual operation too) is a
    /// communication alarm of its own; while an order runs the cell raises
    /// it. Back on the bus, every alarm saying it cannot be reached clears.
    pub fn handle_presence(&mut self, now: Duration, station: StationName, present: bool) {
        self.tick(now);
        if present {
            let back = self.present.insert(station.clone());
            if back {
                self.heard_back(&station);
            }
            let (cleared, error) = self.alarms.settle_reached(&mut self.db, station.as_str());
            self.cleared(station.as_str(), cleared, error);
            if back && self.is_workstation(&station) {
                self.jobs.push_back(Job::Rejoin(station.clone()));
            }
            // The cell is back on the bus: associated again at once (and
            // asked how its order ended), not at the next retry.
            if back && station == self.cell && !self.associated && self.jobs.is_empty() {
                self.jobs.push_back(Job::Connect);
            }
        } else {
            self.present.remove(&station);
            if station == self.cell || self.is_workstation(&station) {
                self.whole = false;
            }
            if self.is_workstation(&station) && self.running.is_none() {
                let text = format!("no connection with station {station}");
                self.raise(&station, None, AlarmClass::Communication, text);
            }
        }
        self.settle_alarms(&station);
        self.pump(now);
    }

    /// A publication of a station, without beginning the next job.
    pub(super) fn publication(&mut self, now: Duration, u: Unconfirmed) {
        match u {
            Unconfirmed::Status { station, status } => {
                if station == self.cell && self.recorded_mode != Some(status.mode) {
                    match self.db.record_mode(status.mode) {
                        Ok(()) => self.recorded_mode = Some(status.mode),
                        Err(e) => self.db_failed(&e),
                    }
                }
                let mut started = None;
                if station != self.cell {
                    if let Some(p) = &status.program {
                        let known = self.open_jobs.get(&station).map(|(name, ..)| name);
                        if known != Some(&p.name) {
                            let job =
                                (p.name.clone(), self.db.now_ms(), self.order_of_message(now));
                            self.open_jobs.insert(station.clone(), job);
                            started = Some(format!("job {} started", p.name));
                        }
                    }
                }
                self.statuses.insert(station.clone(), status);
                self.settle_alarms(&station);
                if let Some(text) = started {
                    self.station_says(now, station, text);
                }
            }
            Unconfirmed::Report { .. } if self.can_hold() && self.replaying.is_none() => {
                self.early.push(Early::Publication(u));
            }
            Unconfirmed::Report {
                station,
                severity,
                text,
            } => self.station_report(now, station, severity, text),
            Unconfirmed::Job {
                station,
                program,
                event,
            } if station == self.cell => {
                if let Some(Busy::Starting { order, .. }) = &self.busy {
                    if ObjectName::new(&order.recipe).ok().as_ref() == Some(&program)
                        && self.can_hold()
                    {
                        self.early.push(Early::Publication(Unconfirmed::Job {
                            station,
                            program,
                            event,
                        }));
                        return;
                    }
                }
                let Some(order) = self.running.clone() else {
                    return;
                };
                if ObjectName::new(&order.recipe).ok().as_ref() != Some(&program) {
                    return;
                }
                self.job_event(now, order, &station, &program, event);
            }
            Unconfirmed::Job {
                station,
                program,
                event,
            } => self.workstation_job(now, station, program, event),
        }
    }

    /// A station's report: every station's, each under its own name (its
    /// message pane), with the order it belongs to; an alarm raised.
    pub(super) fn station_report(
        &mut self,
        now: Duration,
        station: StationName,
        severity: Severity,
        text: String,
    ) {
        let order = self.order_of_message(now);
        match severity {
            Severity::Alarm(class) => {
                self.raise_alarm(&station, class, &text, order);
                self.journal(EntryKind::Alarm, order, station.as_str(), &text);
            }
            Severity::Info | Severity::Warning => {
                self.journal(EntryKind::Report, order, station.as_str(), &text);
            }
        }
    }

    /// A workstation's job event: an end is kept in the records with the
    /// order it is part of (pauses are not) and journalled under the
    /// station, as its start was.
    pub(super) fn workstation_job(
        &mut self,
        now: Duration,
        station: StationName,
        program: ObjectName,
        event: JobEvent,
    ) {
        let outcome = match &event {
            JobEvent::Paused | JobEvent::Resumed => return,
            JobEvent::Started => return self.workstation_started(now, station, program),
            JobEvent::Done => "done".to_string(),
            JobEvent::BadProduct => "bad product".to_string(),
            JobEvent::FailedSafe => "failed safe".to_string(),
            JobEvent::FailedDanger => "failed with danger".to_string(),
            JobEvent::Alarm(cause) => format!("alarm: {cause}"),
        };
        let open = self
            .open_jobs
            .remove(&station)
            .filter(|(name, ..)| *name == program);
        let order = open
            .as_ref()
            .and_then(|(_, _, order)| *order)
            .or(self.order_of_message(now));
        let job = falc_model::product::JobRecord {
            station: station.to_string(),
            program: program.to_string(),
            started_ms: open.map(|(_, at, _)| at),
            ended_ms: self.replaying.unwrap_or_else(|| self.db.now_ms()),
            outcome,
        };
        let text = format!("job {program} ended: {}", job.outcome);
        if let Err(e) = self.db.record_job(order, &job) {
            self.db_failed(&e);
        }
        self.station_says(now, station, text);
    }

    /// A workstation's run began (its numbered job event, live or read
    /// back after a cut): its job is open from the station's time. If its
    /// status said so first, the line is not written twice; a start read
    /// back sets the time to the station's own.
    fn workstation_started(&mut self, now: Duration, station: StationName, program: ObjectName) {
        let at = self.replaying.unwrap_or_else(|| self.db.now_ms());
        match self.open_jobs.get_mut(&station) {
            Some((name, since, _)) if *name == program => {
                // The station's own time of its start is the truth; the
                // status's was when the operator heard of it.
                if self.replaying.is_some() {
                    *since = at;
                }
            }
            _ => {
                let job = (program.clone(), at, self.order_of_message(now));
                self.open_jobs.insert(station.clone(), job);
                self.station_says(now, station, format!("job {program} started"));
            }
        }
    }

    /// A line of what `station` did, journalled as its own report (its
    /// pane), with the order it belongs to.
    fn station_says(&mut self, now: Duration, station: StationName, text: String) {
        let severity = Severity::Info;
        let report = Unconfirmed::Report {
            station,
            severity,
            text,
        };
        self.publication(now, report);
    }

    /// A job event of the running order's program invocation.
    pub(super) fn job_event(
        &mut self,
        now: Duration,
        order: Order,
        station: &StationName,
        program: &ObjectName,
        event: JobEvent,
    ) {
        match event {
            JobEvent::Paused | JobEvent::Resumed => {
                self.journal(
                    EntryKind::Report,
                    Some(order.id),
                    station.as_str(),
                    &format!("{program} {event:?}").to_lowercase(),
                );
            }
            // The cell's own run's start is its Start's confirm.
            JobEvent::Started => {}
            JobEvent::Done => {
                self.running = None;
                self.forget_question();
                self.end(now, order, OrderState::Done, "done");
                self.jobs.push_back(Job::Next);
            }
            failure => {
                self.running = None;
                self.forget_question();
                let id = order.id;
                match failure {
                    JobEvent::Alarm(cause) => {
                        self.end(now, order, OrderState::Failed, &format!("alarm: {cause}"));
                        // The cell reported the same alarm (journalled as it
                        // came): one alarm, whichever is first.
                        let cell = self.cell.clone();
                        self.raise_alarm(&cell, cause.class, &cause.text, Some(id));
                    }
                    other => {
                        let (word, class) = match other {
                            JobEvent::BadProduct => ("bad_product", AlarmClass::Process),
                            JobEvent::FailedSafe => ("failed_safe", AlarmClass::Process),
                            _ => ("failed_danger", AlarmClass::Safety),
                        };
                        let text = format!("order {} ({}) ended with {word}", id, order.recipe);
                        self.end(now, order, OrderState::Failed, word);
                        let me = self.me.clone();
                        self.raise(&me, Some(id), class, text.clone());
                        // An order's end is an event, not a condition that
                        // holds: raised cleared, it leaves the list once
                        // acknowledged (found by falc-sim: each one stayed
                        // listed for good, the list grew with every order).
                        let (_, error) = self.alarms.clear_where(&mut self.db, |a| {
                            a.station == me && a.order == Some(id) && a.text == text
                        });
                        if let Some(e) = error {
                            self.db_failed(&e);
                        }
                    }
                }
            }
        }
    }
}
