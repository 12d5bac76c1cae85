//! The cell lane: one call to the cell at a time, and what each outcome
//! goes on with. Jobs (`start`, `stop`, the next order, a halt, a rejoin)
//! begin when the call before ended; a connection associates the cell,
//! delivers what changed and Initiates it again only when an association
//! may not stand; an order's Start, its end and a stop; the cell's answers
//! and a lost association (the running order's end asked for once the cell
//! is back).

use super::*;

impl<R: Records, S: RecipeSource> OrderList<R, S> {
    pub(super) fn begin(&mut self, now: Duration, job: Job) {
        match job {
            Job::Connect => self.connect(None, false),
            Job::Start(by) => self.begin_start(by),
            Job::Next => {
                if self.list == ListState::Running {
                    self.start_next(None);
                }
            }
            Job::Stop(by) => self.begin_stop(now, by),
            Job::Pass { by, request, done } => {
                self.call(CellCall::Pass(request), Busy::Passing { by, done });
            }
            Job::Restart { by, order, from } => self.begin_restart(by, order, from),
            Job::Rejoin(station) => {
                // Not associated: the next connection associates it all.
                if self.associated && self.running.is_none() {
                    self.call(CellCall::Initiate, Busy::Rejoining(station));
                }
            }
            Job::Halt => {
                let Some(order) = self.running.take() else {
                    return;
                };
                self.refuse_question("the order was halted: the journal cannot be written");
                match ObjectName::new(&order.recipe) {
                    Ok(name) => self.call(CellCall::Stop { name }, Busy::Halting { order }),
                    Err(e) => self.halted(now, order, Err(e.to_string())),
                }
            }
        }
    }

    /// The recipes whose content the cell does not have yet, with their
    /// content hash.
    pub(super) fn undelivered(&self) -> impl Iterator<Item = (&Delivery, u64)> {
        self.recipes
            .deliveries
            .iter()
            .zip(self.hashes.iter().copied())
            .filter(|(d, h)| self.delivered.get(&d.domain) != Some(h))
    }

    /// Associates the cell if it is not, and delivers what changed, one
    /// call at a time; then goes on with `after`. Quiet when nothing
    /// changed; says `EVENT cell-ready` when the cell holds every recipe
    /// after a change (`sent`). Then goes on with an operator's `start`.
    pub(super) fn connect(&mut self, start: Option<Caller>, sent: bool) {
        if !self.associated {
            self.call(CellCall::Associate, Busy::Associating { start });
            return;
        }
        if self.away.is_some() {
            if let Some(order) = &self.running {
                match ObjectName::new(&order.recipe) {
                    Ok(name) => return self.call(CellCall::Ask { name }, Busy::Asking { start }),
                    Err(e) => tracing::error!("order {}'s recipe: {e}", order.id),
                }
            }
            self.away = None;
        }
        // A recipe in use is not replaced under the running order: what
        // changed is delivered once it ended.
        if self.running.is_some() {
            if let Some(by) = start {
                self.list = ListState::Running;
                self.reply(by.ticket, Ok(ApiReply::Done("the list is running".into())));
            }
            return;
        }
        let next = self.undelivered().next().map(|(d, h)| (d.clone(), h));
        if let Some((d, hash)) = next {
            if !self.whole {
                // A workstation left the bus since the cell associated
                // it (and came back while an order ran, when it is not
                // initiated): its recipes go through the cell to it, so
                // the cell associates it again first.
                self.call(CellCall::Initiate, Busy::Initiating(start));
                return;
            }
            let busy = Busy::Delivering {
                start,
                domain: d.domain.clone(),
                hash,
            };
            self.call(CellCall::Deliver(d), busy);
            return;
        }
        if sent {
            let n = self.recipes.deliveries.len();
            self.say(format!("EVENT cell-ready recipes={n}"));
        }
        if let Some(by) = start {
            if self.association_stands() {
                self.problem = None;
                self.start_next(Some(by));
            } else {
                self.call(CellCall::Initiate, Busy::Initiating(Some(by)));
            }
        }
    }

    /// Whether the cell's associations stand: it associated its
    /// workstations, none left the bus since, and the cell's status does
    /// not say it lost one. Else a `start` Initiates the cell again first
    /// (the 1992 recursive scheme associates what was lost).
    pub(super) fn association_stands(&self) -> bool {
        self.associated
            && self.whole
            && self
                .statuses
                .get(&self.cell)
                .map_or(true, |s| s.physical == PhysicalStatus::Operational)
    }

    /// A connection failed: the last refusal is kept as `problem`.
    pub(super) fn connect_failed(&mut self, start: Option<Caller>, text: String) {
        if let Some(by) = start {
            self.reply(by.ticket, Err(text));
        }
    }

    pub(super) fn associated_now(&mut self) {
        self.associated = true;
        self.whole = true;
        self.problem = None;
        self.delivered.clear();
        self.say(format!("EVENT associated station={}", self.cell));
        let me = self.me.clone();
        // The cell is back: the lost connection has cleared.
        let (_, error) = self.alarms.clear_where(&mut self.db, |a| {
            a.station == me && a.class == AlarmClass::Communication
        });
        if let Some(e) = error {
            self.db_failed(&e);
        }
        let text = format!("associated with {}", self.cell);
        self.journal_mine(EntryKind::System, None, &text);
    }

    pub(super) fn begin_start(&mut self, by: Caller) {
        let ticket = by.ticket;
        if let Some(a) = self.alarms.blocking() {
            let text = format!(
                "alarm {} waits for acknowledgement (falc ack {}, or falc ack for all)",
                a.line(),
                a.id
            );
            return self.reply(ticket, Err(text));
        }
        if self.shutdown_pending {
            return self.reply(ticket, Err("the cell is shutting down".into()));
        }
        if !self.cell_mode().runs_orders() {
            let text = "the cell is in maintenance mode: no order runs (falc mode auto)";
            return self.reply(ticket, Err(text.into()));
        }
        if let Some(order) = &self.running {
            if self.away.is_some() {
                let text = format!(
                    "order {} ({}) ran on {} when the connection was lost, and how it ended \
                     is not known yet: {} is asked once it is reachable again (falc status)",
                    order.id, order.recipe, self.cell, self.cell
                );
                return self.reply(ticket, Err(text));
            }
            self.list = ListState::Running;
            return self.reply(ticket, Ok(ApiReply::Done("the list is running".into())));
        }
        // The recipe store again: what was saved since is delivered now.
        match self.source.load() {
            Ok(set) => {
                self.hashes = hashes_of(&set);
                self.recipes = set;
                self.version_set();
            }
            Err(problems) => {
                let text = format!(
                    "recipes refused, nothing delivered:\n{}",
                    problems.join("\n")
                );
                self.journal_mine(EntryKind::System, None, &text);
                return self.reply(ticket, Err(text));
            }
        }
        self.connect(Some(by), false);
    }

    /// The cell's mode, as its status says.
    pub(super) fn cell_mode(&self) -> CellMode {
        self.statuses
            .get(&self.cell)
            .map(|s| s.mode)
            .unwrap_or_default()
    }

    /// Starts the next queued order: durably `running` before the cell is
    /// asked to start it; back in the queue only if the cell refused.
    pub(super) fn start_next(&mut self, by: Option<Caller>) {
        let prepared = self.write_held_ends().and_then(|()| {
            let cell = self.topology.cell().as_str();
            let Some(order) = self.db.next_queued(cell).map_err(|e| e.to_string())? else {
                return Ok(None);
            };
            let name = ObjectName::new(&order.recipe).map_err(|e| e.to_string())?;
            let used = self.used_by(&order.recipe);
            match self.db.set_running(order.id, cell, &used) {
                Ok(ms) => Ok(Some((
                    Order {
                        cell: Some(cell.to_string()),
                        ..order
                    },
                    name,
                    ms,
                ))),
                Err(e) => {
                    let why = format!("order {} ({}) not started: {e}", order.id, order.recipe);
                    self.db_failed(&e);
                    Err(why)
                }
            }
        });
        match prepared {
            Ok(Some((order, name, started_ms))) => {
                let argument = format!("order {}", order.id);
                let busy = Busy::Starting {
                    order,
                    started_ms,
                    by,
                    previous: None,
                };
                self.call(CellCall::Start { name, argument }, busy);
            }
            Ok(None) => self.start_ended(by, Ok(None)),
            Err(text) => self.start_ended(by, Err(text)),
        }
    }

    /// The outcome of a start: answered to the operator who asked, or
    /// the list goes on.
    pub(super) fn start_ended(
        &mut self,
        by: Option<Caller>,
        outcome: Result<Option<Order>, String>,
    ) {
        match (by, outcome) {
            (Some(Caller { ticket, who }), Ok(Some(order))) => {
                self.list = ListState::Running;
                self.journal(EntryKind::Action, None, &who, "started the list");
                let text = format!("order {} ({}) started", order.id, order.recipe);
                self.reply(ticket, Ok(ApiReply::Done(text)));
            }
            (Some(Caller { ticket, .. }), Ok(None)) => {
                self.reply(ticket, Err("the order list holds no queued order".into()));
            }
            (Some(Caller { ticket, who }), Err(text)) => {
                self.journal(
                    EntryKind::Action,
                    None,
                    &who,
                    &format!("start refused: {text}"),
                );
                self.reply(ticket, Err(text));
            }
            (None, Ok(Some(_))) => {}
            (None, Ok(None)) => {
                self.list = ListState::Idle;
                self.journal_mine(EntryKind::System, None, "the order list is done");
                self.say("EVENT list-done".into());
            }
            (None, Err(text)) => {
                let me = self.me.clone();
                self.raise(&me, None, AlarmClass::Process, text);
            }
        }
    }

    pub(super) fn begin_stop(&mut self, now: Duration, by: Caller) {
        self.list = ListState::Idle;
        let Some(order) = self.running.take() else {
            self.journal(EntryKind::Action, None, &by.who, "stopped the list");
            return self.reply(by.ticket, Ok(ApiReply::Done("the list is stopped".into())));
        };
        match ObjectName::new(&order.recipe) {
            Ok(name) => self.call(CellCall::Stop { name }, Busy::Stopping { order, by }),
            Err(e) => self.stopped(now, order, by, Err(e.to_string())),
        }
    }

    pub(super) fn stopped(
        &mut self,
        now: Duration,
        order: Order,
        Caller { ticket, who }: Caller,
        result: Result<(), String>,
    ) {
        self.refuse_question("the order was stopped");
        self.journal(
            EntryKind::Action,
            Some(order.id),
            &who,
            &format!("stopped order {}", order.id),
        );
        let id = order.id;
        self.end(
            now,
            order,
            OrderState::Stopped,
            &format!("stopped by {who}"),
        );
        let text = match result {
            Ok(()) => format!("order {id} stopped"),
            Err(text) => {
                format!("order {id} marked stopped; the cell did not confirm the stop: {text}")
            }
        };
        self.reply(ticket, Ok(ApiReply::Done(text)));
    }

    pub(super) fn halted(&mut self, now: Duration, order: Order, result: Result<(), String>) {
        match &result {
            Ok(()) => self.say(format!("EVENT order-halted id={}", order.id)),
            Err(why) => self.say(format!(
                "EVENT order-halted id={} (the cell did not confirm: {why})",
                order.id
            )),
        }
        self.end(
            now,
            order,
            OrderState::Failed,
            "halted: the order list and journal could not be written",
        );
    }

    /// The answer to the call to the cell that is out.
    pub fn handle_cell_answer(&mut self, now: Duration, result: Result<Response, ServiceError>) {
        self.tick(now);
        let Some(busy) = self.busy.take() else {
            tracing::warn!("a reply from the cell that nothing waits for: {result:?}");
            return;
        };
        if let Busy::Asking { start } = busy {
            self.asked(now, start, result);
            return self.pump(now);
        }
        let unanswered = result.as_ref().is_err_and(ServiceError::unanswered);
        let result = result.map(|_| ()).map_err(|e| e.description);
        match busy {
            Busy::Associating { start } => match result {
                Ok(()) => {
                    self.associated_now();
                    self.connect(start, false);
                }
                Err(text) => {
                    if self.problem.as_deref() != Some(text.as_str()) {
                        self.say(format!("EVENT not-associated {text}"));
                    }
                    self.problem = Some(text.clone());
                    self.connect_failed(start, text);
                }
            },
            Busy::Delivering {
                start,
                domain,
                hash,
            } => match result {
                Ok(()) => {
                    self.say(format!("EVENT delivered recipe={domain}"));
                    self.delivered.insert(domain, hash);
                    self.connect(start, true);
                }
                Err(text) => {
                    self.delivered.remove(&domain);
                    self.journal_mine(EntryKind::System, None, &text);
                    self.connect_failed(start, text);
                }
            },
            Busy::Rejoining(station) => match result {
                Ok(()) => {
                    self.whole = true;
                    self.say(format!("EVENT rejoined station={station}"));
                }
                Err(text) => {
                    tracing::warn!(
                        "{station} is back, but the cell could not associate it: {text}"
                    );
                    self.say(format!("EVENT not-rejoined station={station} {text}"));
                }
            },
            Busy::Initiating(by) => match result {
                Ok(()) => {
                    self.whole = true;
                    self.problem = None;
                    // What waited for it: a start, the deliveries first.
                    match by {
                        Some(by) if self.undelivered().next().is_none() => {
                            self.start_next(Some(by))
                        }
                        by => self.connect(by, false),
                    }
                }
                Err(text) => {
                    self.problem = Some(text.clone());
                    self.connect_failed(by, text);
                }
            },
            Busy::Starting {
                order,
                started_ms,
                by,
                previous,
            } => {
                let outcome = match result {
                    Ok(()) => {
                        let order = Order {
                            state: OrderState::Running,
                            started_ms: Some(started_ms),
                            ..order
                        };
                        // Running before anything is written: a failed
                        // write halts it.
                        self.running = Some(order.clone());
                        self.questions.new_order();
                        self.journal_mine(
                            EntryKind::Order,
                            Some(order.id),
                            &format!("order {} ({}) started", order.id, order.recipe),
                        );
                        self.say(format!("EVENT order-started id={}", order.id));
                        Ok(Some(order))
                    }
                    // The Start may have reached the cell: it runs the
                    // order on by itself, so the order is not queued
                    // again before the cell says it never started.
                    Err(text) if unanswered && previous.is_none() => {
                        let order = Order {
                            state: OrderState::Running,
                            started_ms: Some(started_ms),
                            ..order
                        };
                        self.running = Some(order.clone());
                        self.away = Some(Away::StartUnconfirmed);
                        self.associated = false;
                        self.problem = Some(text.clone());
                        let line = format!(
                            "order {} ({}): its start was not confirmed ({text}); the cell is \
                             asked whether it runs",
                            order.id, order.recipe
                        );
                        self.journal_mine(EntryKind::Order, Some(order.id), &line);
                        Err(line)
                    }
                    Err(text) => {
                        let why =
                            format!("order {} ({}) not started: {text}", order.id, order.recipe);
                        let undone = match &previous {
                            Some(p) => self.db.end_order(
                                p.id,
                                p.state,
                                p.result.as_deref().unwrap_or_default(),
                            ),
                            None => self.db.requeue(order.id),
                        };
                        self.undone(order.id, undone, &why);
                        Err(why)
                    }
                };
                self.start_ended(by, outcome);
                // In the order it came; the next job begins only after.
                for e in std::mem::take(&mut self.early) {
                    match e {
                        Early::Publication(u) => self.publication(now, u),
                        Early::Message(kind, text) => self.journal_cell_message(now, kind, &text),
                    }
                }
            }
            Busy::Stopping { order, by } => self.stopped(now, order, by, result),
            Busy::Passing { by, done } => {
                let text = match &result {
                    Ok(()) => done.clone(),
                    Err(e) => format!("{done} refused: {e}"),
                };
                self.journal(EntryKind::Action, self.running_id(), &by.who, &text);
                self.reply(by.ticket, result.map(|()| ApiReply::Done(done)));
            }
            Busy::Halting { order } => self.halted(now, order, result),
            // Answered above (`asked`), with the whole answer.
            Busy::Asking { .. } => {}
        }
        self.pump(now);
    }

    // ---- the cell and the stations ----

    /// The cell was lost (abort indication). A cell runs its order on to
    /// its end without its commander (`StationKind::runs_on_alone`): the
    /// order stays `running` here, and once the cell is associated again
    /// it is asked how the run ended ([`CellCall::Ask`]). Nothing is
    /// assumed meanwhile, so nothing is lost and nothing runs twice.
    pub fn handle_abort(&mut self, now: Duration, reason: &str) {
        self.tick(now);
        self.associated = false;
        self.delivered.clear();
        let text = format!("no connection with station {}", self.cell);
        self.problem = Some(text.clone());
        self.say(format!("EVENT cell-lost {reason}"));
        self.forget_question();
        let id = self.running_id();
        if let Some(order) = &self.running {
            // (A start not confirmed stays so.)
            self.away.get_or_insert(Away::Running);
            let line = format!(
                "order {} ({}): the connection with {} was lost while it ran; the cell runs it \
                 on, and is asked how it ended once it is back",
                order.id, order.recipe, self.cell
            );
            self.journal_mine(EntryKind::Order, id, &line);
        }
        let me = self.me.clone();
        self.raise(&me, id, AlarmClass::Communication, text);
        self.pump(now);
    }

    /// The cell's answer to [`CellCall::Ask`]; then the connection goes on
    /// (`start`: the operator's start it was made for).
    pub(super) fn asked(
        &mut self,
        now: Duration,
        start: Option<Caller>,
        result: Result<Response, ServiceError>,
    ) {
        match result {
            Ok(Response::PiAttributes(a)) => self.learned(now, a.state, a.last_end),
            // The cell was lost again meanwhile: asked at the next
            // association.
            Ok(_) | Err(_) if !self.associated => {}
            Ok(other) => {
                let why = format!("the cell answered {other:?}");
                self.run_unknown(now, &why);
            }
            Err(e) => {
                // The cell does not know the program invocation: it was
                // restarted.
                if matches!(e.class, ErrorClass::Definition(_)) {
                    self.run_unknown(now, &e.description);
                } else {
                    // The link broke again: asked at the next association.
                    self.associated = false;
                    self.problem = Some(e.description);
                }
            }
        }
        self.connect(start, false);
    }

    /// What the cell said of the run of the order that was away.
    pub(super) fn learned(&mut self, now: Duration, state: PiState, end: Option<JobEvent>) {
        let unconfirmed = self.away.take() == Some(Away::StartUnconfirmed);
        let Some(order) = self.running.clone() else {
            return;
        };
        let cell = self.cell.clone();
        match (state, end) {
            (PiState::Idle, None) if unconfirmed => {
                // Never started: back in the queue, as a refused start.
                self.running = None;
                let line = format!(
                    "order {} ({}) never began at {cell}: queued again",
                    order.id, order.recipe
                );
                let requeued = self.db.requeue(order.id);
                self.undone(order.id, requeued, &line);
                self.journal_mine(EntryKind::Order, Some(order.id), &line);
            }
            (PiState::Starting | PiState::Running | PiState::Resuming, _) => {
                let line = format!(
                    "order {} ({}) still runs at {cell}: the list follows it again",
                    order.id, order.recipe
                );
                self.journal_mine(EntryKind::Order, Some(order.id), &line);
                self.say(format!("EVENT order-followed id={}", order.id));
            }
            (_, Some(event)) => {
                let line = format!(
                    "order {} ({}) ended at {cell} while the connection was lost: {event:?}",
                    order.id, order.recipe
                );
                self.journal_mine(EntryKind::Order, Some(order.id), &line);
                let program = ObjectName::new(&order.recipe);
                match program {
                    Ok(program) => self.job_event(now, order, &cell, &program, event),
                    Err(e) => self.run_unknown(now, &e.to_string()),
                }
            }
            (state, None) => self.run_unknown(now, &format!("its program invocation is {state}")),
        }
    }

    /// The cell no longer knows how the running order's run went (it was
    /// restarted while the connection was lost): the order ends
    /// `interrupted` (never run again by itself: `falc restart N`).
    pub(super) fn run_unknown(&mut self, now: Duration, why: &str) {
        self.away = None;
        let Some(order) = self.running.take() else {
            return;
        };
        self.forget_question();
        let id = order.id;
        let text = format!(
            "order {id} ({}): {} kept no end of its run ({why}); not restarted (falc restart {id})",
            order.recipe, self.cell
        );
        self.end(now, order, OrderState::Interrupted, &text);
        let me = self.me.clone();
        self.raise(&me, Some(id), AlarmClass::Process, text);
    }
}
