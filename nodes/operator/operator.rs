//! The operator node's behaviour: the order list worked through the cell,
//! operator communication (the cell's `output` and `input`), alarms and
//! acknowledgement, recipe delivery, and the answers to the operator API.
//! Every change is written to the [`Database`] before it is confirmed.

use crate::alarms::{AlarmList, Raised};
use crate::database::{Database, DatabaseError};
use crate::recipe_store::{self, RecipeSet};
use falc_bus::station::Station;
use falc_bus::Responder;
use falc_model::alarm::AlarmClass;
use falc_model::console::{
    ApiReply, ApiRequest, ApiResult, CellStatus, EntryKind, ListState, Order, OrderState,
    StationView,
};
use falc_model::ids::{ObjectName, StationName};
use falc_model::mms::domain::content_hash;
use falc_model::mms::error::ServiceError;
use falc_model::mms::pdu::{JobEvent, Request, Response, Severity, Unconfirmed};
use falc_model::mms::vmd::VmdStatus;
use falc_model::topology::Topology;
use falc_node::say;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

/// How long a Start or Stop of the cell's program invocation may take.
const CELL_LIMIT: Duration = Duration::from_secs(10);

/// A station's message this soon after an order ended still belongs to it.
const TRAIL: Duration = Duration::from_secs(2);

/// At most this many journal entries per API answer.
const PAGE: usize = 500;

/// A question the cell asked, waiting for `answer`.
struct Question {
    prompt: String,
    responder: Responder,
}

/// What the operator node knows and does.
pub struct Operator {
    pub station: Station,
    db: Database,
    topology: Topology,
    cell: StationName,
    recipes_dir: PathBuf,
    recipes: RecipeSet,
    /// Content hash of each domain delivered to the cell in this association.
    delivered: BTreeMap<ObjectName, u64>,
    associated: bool,
    problem: Option<String>,
    /// Whether the list goes on (`Running`) or waits (`Idle`); shown as
    /// `Alarm` while an alarm holds it back ([`Self::list_state`]).
    list: ListState,
    /// Every station's alarms and the operator's own.
    alarms: AlarmList,
    /// The alarm a failed database write raised: the database is taken as
    /// failing until it is acknowledged (the next write then tells).
    db_alarm: Option<i64>,
    running: Option<Order>,
    question: Option<Question>,
    shutdown_pending: bool,
    statuses: BTreeMap<StationName, VmdStatus>,
    /// The stations on the bus now.
    present: std::collections::BTreeSet<StationName>,
    /// Lines the cell showed since the last question (shown with it).
    shown: Vec<String>,
    /// The running order must be stopped at the cell (a write failed).
    halt_pending: bool,
    /// Order ends that could not be written: written before the next start
    /// (until then the order stays `running` in the file, which a restart
    /// turns into `interrupted`: never queued again).
    unwritten_ends: Vec<(i64, OrderState, String)>,
    /// The order that ended last, and when (messages that trail it
    /// closely belong to it).
    last_ended: Option<(i64, std::time::Instant)>,
}

fn text_of(e: &ServiceError) -> String {
    e.description.clone()
}

impl Operator {
    /// The node around its station runtime, database and checked recipes.
    pub fn new(
        station: Station,
        db: Database,
        topology: Topology,
        cell: StationName,
        recipes_dir: PathBuf,
        recipes: RecipeSet,
    ) -> Self {
        let alarms = match AlarmList::load(&db) {
            Ok(l) => l,
            Err(e) => {
                tracing::error!("{e}; the alarm list starts empty");
                AlarmList::default()
            }
        };
        Self {
            station,
            db,
            topology,
            cell,
            recipes_dir,
            recipes,
            delivered: BTreeMap::new(),
            associated: false,
            problem: None,
            list: ListState::Idle,
            alarms,
            db_alarm: None,
            running: None,
            question: None,
            shutdown_pending: false,
            statuses: BTreeMap::new(),
            present: Default::default(),
            shown: Vec::new(),
            halt_pending: false,
            unwritten_ends: Vec::new(),
            last_ended: None,
        }
    }

    /// Whether the node should stop (shut down requested and the list done).
    pub fn should_stop(&self) -> bool {
        self.shutdown_pending && self.running.is_none()
    }

    fn me(&self) -> String {
        self.station.bus().me().station.to_string()
    }

    /// Journals; a failure to write stops the list ([`Self::db_failed`]).
    pub fn journal(&mut self, kind: EntryKind, order: Option<i64>, who: &str, text: &str) {
        match self.db.journal(kind, order, who, text) {
            Ok(e) => say(&format!(
                "JOURNAL {} {} {who}: {}",
                e.id,
                kind.as_str(),
                text.replace('\n', " / ")
            )),
            Err(e) => self.db_failed(&e),
        }
    }

    /// A write to the order list or journal failed: the cell must not run
    /// on with the journal behind. The list stops with an alarm saying why
    /// and the running order is halted at the cell ([`Self::enforce`]).
    pub fn db_failed(&mut self, e: &DatabaseError) {
        tracing::error!("{e}");
        say(&format!("EVENT store-error {e}"));
        if self.db_alarm.is_some() {
            return;
        }
        let text = format!(
            "the order list and journal cannot be written ({e}): the list is stopped{}; \
             free the disk, then falc ack and falc start",
            if self.running.is_some() {
                " and the running order halted"
            } else {
                ""
            }
        );
        self.halt_pending = self.running.is_some();
        // Neither journalled nor, most likely, stored: the database is what
        // cannot be written (the list keeps it in memory meanwhile).
        let order = self.running_id();
        let me = self.me();
        let (raised, _) = self
            .alarms
            .raise(&mut self.db, &me, AlarmClass::Device, &text, order);
        self.db_alarm = Some(self.raised(raised, AlarmClass::Device));
    }

    /// Says a new alarm, and stops the list if its class needs an
    /// acknowledgement (a running order ends, the next one waits); its
    /// number.
    fn raised(&mut self, raised: Raised, class: AlarmClass) -> i64 {
        if class.needs_ack() {
            self.list = ListState::Idle;
        }
        match raised {
            Raised::New(a) => {
                say(&format!(
                    "EVENT alarm id={} class={} station={} {}",
                    a.id, a.class, a.station, a.text
                ));
                a.id
            }
            Raised::Repeated(id) => id,
        }
    }

    /// The list as consoles see it: `Alarm` while an alarm holds it back.
    fn list_state(&self) -> ListState {
        if self.alarms.blocking().is_some() {
            ListState::Alarm
        } else {
            self.list
        }
    }

    /// Puts an alarm of `station` in the list (the same one again while
    /// unacknowledged is not repeated); one that needs acknowledgement
    /// stops the list ([`Self::raised`]) and is shown as its state
    /// ([`Self::list_state`]).
    fn raise_alarm(&mut self, station: &str, class: AlarmClass, text: &str, order: Option<i64>) {
        let (raised, error) = self.alarms.raise(&mut self.db, station, class, text, order);
        self.raised(raised, class);
        if let Some(e) = error {
            self.db_failed(&e);
        }
    }

    /// Clears the alarms of `station` whose condition is gone, from its
    /// latest status and presence.
    fn settle_alarms(&mut self, station: &StationName) {
        let status = self.statuses.get(station);
        let present = self.present.contains(station);
        let (cleared, error) = self
            .alarms
            .settle(&mut self.db, station.as_str(), status, present);
        for a in cleared {
            say(&format!("EVENT alarm-cleared id={}", a.id));
            self.journal(
                EntryKind::Report,
                a.order,
                station.as_str(),
                &format!("alarm #{} cleared: {}", a.id, a.text),
            );
        }
        if let Some(e) = error {
            self.db_failed(&e);
        }
    }

    /// Carries out what a failed write asked for: the running order is
    /// stopped at the cell (its end is written once the database works again).
    /// Called by the driver after every event.
    pub async fn enforce(&mut self) {
        if !std::mem::take(&mut self.halt_pending) {
            return;
        }
        let Some(order) = self.running.take() else {
            return;
        };
        if let Some(q) = self.question.take() {
            q.responder
                .respond(Err(ServiceError::state_conflict(
                    "the order was halted: the journal cannot be written",
                )))
                .await;
        }
        let stopped = match ObjectName::new(&order.recipe) {
            Ok(name) => self
                .station
                .bus()
                .request(&self.cell, &Request::Stop { name }, CELL_LIMIT)
                .await
                .map(|_| ())
                .map_err(|e| text_of(&e)),
            Err(e) => Err(e.to_string()),
        };
        match &stopped {
            Ok(()) => say(&format!("EVENT order-halted id={}", order.id)),
            Err(why) => say(&format!(
                "EVENT order-halted id={} (the cell did not confirm: {why})",
                order.id
            )),
        }
        self.end(
            order,
            OrderState::Failed,
            "halted: the order list and journal could not be written",
        );
    }

    /// Writes the order ends a failed database write held back; the error (the
    /// fault raised again) while it still cannot.
    fn write_held_ends(&mut self) -> Result<(), String> {
        while let Some((id, state, result)) = self.unwritten_ends.first().cloned() {
            if let Err(e) = self.db.end_order(id, state, &result) {
                self.db_failed(&e);
                return Err(e.to_string());
            }
            self.unwritten_ends.remove(0);
            let me = self.me();
            self.journal(
                EntryKind::Order,
                Some(id),
                &me,
                &format!("order {id} {state}: {result} (written late)"),
            );
        }
        Ok(())
    }

    fn running_id(&self) -> Option<i64> {
        self.running.as_ref().map(|o| o.id)
    }

    /// The order a message of the cell or a station belongs to: the running
    /// one, else the one that ended within [`TRAIL`] (a cause a station
    /// reports just after its order failed).
    fn order_of_message(&self) -> Option<i64> {
        self.running_id().or(self
            .last_ended
            .filter(|(_, at)| at.elapsed() < TRAIL)
            .map(|(id, _)| id))
    }

    /// Associates the cell if it is not, and delivers what changed. Quiet
    /// when nothing changed; the last refusal is kept as `problem`.
    pub async fn connect(&mut self) -> Result<(), String> {
        if !self.associated {
            match self.station.associate_subordinates().await {
                Ok(_) => {
                    self.associated = true;
                    self.problem = None;
                    self.delivered.clear();
                    say(&format!("EVENT associated station={}", self.cell));
                    let me = self.me();
                    // The cell is back: the lost connection has cleared.
                    let (_, error) = self.alarms.clear_where(&mut self.db, |a| {
                        a.station == me && a.class == AlarmClass::Communication
                    });
                    if let Some(e) = error {
                        self.db_failed(&e);
                    }
                    self.journal(
                        EntryKind::System,
                        None,
                        &me,
                        &format!("associated with {}", self.cell),
                    );
                }
                Err(e) => {
                    let text = text_of(&e);
                    if self.problem.as_deref() != Some(text.as_str()) {
                        say(&format!("EVENT not-associated {text}"));
                    }
                    self.problem = Some(text.clone());
                    return Err(text);
                }
            }
        }
        self.deliver().await
    }

    /// Initiates the associated cell again: a cell that lost a workstation
    /// associates it again on a repeated Initiate of its commander (the 1992
    /// recursive scheme), or refuses with the cause ("no connection with
    /// station TRANSPORT"). Only while no order runs.
    async fn reassociate(&mut self) -> Result<(), String> {
        let bus = self.station.bus().clone();
        let req = Request::Initiate {
            calling: bus.me().clone(),
        };
        match bus.request(&self.cell, &req, CELL_LIMIT).await {
            Ok(_) => {
                self.problem = None;
                Ok(())
            }
            Err(e) => {
                let text = text_of(&e);
                self.problem = Some(text.clone());
                Err(text)
            }
        }
    }

    /// Sends every recipe whose content the cell does not have yet; says
    /// `EVENT cell-ready` when the cell holds them all after a change.
    async fn deliver(&mut self) -> Result<(), String> {
        let todo: Vec<_> = self
            .recipes
            .deliveries
            .iter()
            .filter(|d| self.delivered.get(&d.domain) != Some(&content_hash(&d.content)))
            .cloned()
            .collect();
        let sent_any = !todo.is_empty();
        for d in todo {
            let bus = self.station.bus().clone();
            let sent = if d.is_cell {
                bus.deliver(&self.cell, &d.domain, &d.content).await
            } else {
                bus.deliver_domain(&self.cell, &d.domain, &d.content).await
            };
            if let Err(e) = sent {
                self.delivered.remove(&d.domain);
                let text = text_of(&e);
                let me = self.me();
                self.journal(EntryKind::System, None, &me, &text);
                return Err(text);
            }
            self.delivered
                .insert(d.domain.clone(), content_hash(&d.content));
            say(&format!("EVENT delivered recipe={}", d.domain));
        }
        if sent_any {
            say(&format!(
                "EVENT cell-ready recipes={}",
                self.recipes.deliveries.len()
            ));
        }
        Ok(())
    }

    /// Reads and checks the recipe directory again; the new set replaces
    /// the old only when it is clean.
    fn reload(&mut self) -> Result<(), String> {
        match recipe_store::load(&self.recipes_dir, &self.topology, &self.cell) {
            Ok(set) => {
                self.recipes = set;
                Ok(())
            }
            Err(problems) => Err(format!(
                "recipes refused, nothing delivered:\n{}",
                problems.join("\n")
            )),
        }
    }

    /// The cell was lost (abort indication).
    pub fn cell_lost(&mut self, reason: &str) {
        self.associated = false;
        self.delivered.clear();
        let text = format!("no connection with station {}", self.cell);
        self.problem = Some(text.clone());
        say(&format!("EVENT cell-lost {reason}"));
        self.question = None;
        let order = self.running.take();
        let id = order.as_ref().map(|o| o.id);
        if let Some(order) = order {
            self.end(order, OrderState::Failed, &format!("alarm: {text}"));
        }
        let me = self.me();
        self.raise(&me, id, AlarmClass::Communication, text);
    }

    /// Raises an alarm of `station` that this node journals (a station's
    /// own reports are journalled as they come), under `order` (the order
    /// that failed, which no longer runs by now).
    fn raise(&mut self, station: &str, order: Option<i64>, class: AlarmClass, text: String) {
        self.raise_alarm(station, class, &text, order);
        self.journal(EntryKind::Alarm, order, station, &text);
    }

    fn end(&mut self, order: Order, state: OrderState, result: &str) {
        self.last_ended = Some((order.id, std::time::Instant::now()));
        if let Err(e) = self.db.end_order(order.id, state, result) {
            self.unwritten_ends
                .push((order.id, state, result.to_string()));
            self.db_failed(&e);
        }
        let me = self.me();
        self.journal(
            EntryKind::Order,
            Some(order.id),
            &me,
            &format!("order {} ({}) {state}: {result}", order.id, order.recipe),
        );
        say(&format!("EVENT order-ended id={} state={state}", order.id));
    }

    /// Starts the next queued order. `Ok(None)` when the list is empty.
    /// The order is durably `running` before the cell is asked to start
    /// it, and goes back to the queue only if the cell refused.
    async fn start_next(&mut self) -> Result<Option<Order>, String> {
        self.write_held_ends()?;
        let Some(order) = self.db.next_queued().map_err(|e| e.to_string())? else {
            return Ok(None);
        };
        let name = ObjectName::new(&order.recipe).map_err(|e| e.to_string())?;
        let started_ms = match self.db.set_running(order.id) {
            Ok(ms) => ms,
            Err(e) => {
                self.db_failed(&e);
                return Err(format!(
                    "order {} ({}) not started: {e}",
                    order.id, order.recipe
                ));
            }
        };
        let bus = self.station.bus().clone();
        let req = Request::Start {
            name,
            argument: format!("order {}", order.id),
        };
        match bus.request(&self.cell, &req, CELL_LIMIT).await {
            Ok(_) => {
                let order = Order {
                    state: OrderState::Running,
                    started_ms: Some(started_ms),
                    ..order
                };
                let me = self.me();
                self.journal(
                    EntryKind::Order,
                    Some(order.id),
                    &me,
                    &format!("order {} ({}) started", order.id, order.recipe),
                );
                say(&format!("EVENT order-started id={}", order.id));
                self.shown.clear();
                self.running = Some(order.clone());
                Ok(Some(order))
            }
            Err(e) => {
                let why = format!(
                    "order {} ({}) not started: {}",
                    order.id,
                    order.recipe,
                    text_of(&e)
                );
                if let Err(e) = self.db.requeue(order.id) {
                    // Stays `running` in the file: interrupted at a restart,
                    // never run twice; failed once the database works again.
                    self.unwritten_ends
                        .push((order.id, OrderState::Failed, why.clone()));
                    self.db_failed(&e);
                }
                Err(why)
            }
        }
    }

    /// After an order ended: the next one, or the list is done.
    async fn continue_list(&mut self) {
        if self.list != ListState::Running {
            return;
        }
        match self.start_next().await {
            Ok(Some(_)) => {}
            Ok(None) => {
                self.list = ListState::Idle;
                let me = self.me();
                self.journal(EntryKind::System, None, &me, "the order list is done");
                say("EVENT list-done");
            }
            Err(text) => {
                let me = self.me();
                self.raise(&me, None, AlarmClass::Process, text);
            }
        }
    }

    /// A publication of a station.
    pub async fn publication(&mut self, u: Unconfirmed) {
        match u {
            Unconfirmed::Status { station, status } => {
                self.statuses.insert(station.clone(), status);
                self.settle_alarms(&station);
            }
            Unconfirmed::Report {
                station,
                severity,
                text,
            } => {
                // Every station's reports, each under its own name (its
                // message pane), with the order they belong to.
                let order = self.order_of_message();
                match severity {
                    Severity::Alarm(class) => {
                        self.raise_alarm(station.as_str(), class, &text, order);
                        self.journal(EntryKind::Alarm, order, station.as_str(), &text);
                    }
                    Severity::Info | Severity::Warning => {
                        self.journal(EntryKind::Report, order, station.as_str(), &text);
                    }
                }
            }
            Unconfirmed::Job {
                station,
                program,
                event,
            } if station == self.cell => {
                let Some(order) = self.running.clone() else {
                    return;
                };
                if ObjectName::new(&order.recipe).ok().as_ref() != Some(&program) {
                    return;
                }
                match event {
                    JobEvent::Paused | JobEvent::Resumed => {
                        let order = self.running_id();
                        self.journal(
                            EntryKind::Report,
                            order,
                            station.as_str(),
                            &format!("{program} {event:?}").to_lowercase(),
                        );
                    }
                    JobEvent::Done => {
                        self.running = None;
                        self.question = None;
                        self.end(order, OrderState::Done, "done");
                        self.continue_list().await;
                    }
                    failure => {
                        self.running = None;
                        self.question = None;
                        let id = order.id;
                        match failure {
                            JobEvent::Alarm(cause) => {
                                self.end(order, OrderState::Failed, &format!("alarm: {cause}"));
                                // The cell reported the same alarm (journalled
                                // as it came): one alarm, whichever is first.
                                let cell = self.cell.to_string();
                                self.raise_alarm(&cell, cause.class, &cause.text, Some(id));
                            }
                            other => {
                                let (word, class) = match other {
                                    JobEvent::BadProduct => ("bad_product", AlarmClass::Process),
                                    JobEvent::FailedSafe => ("failed_safe", AlarmClass::Process),
                                    _ => ("failed_danger", AlarmClass::Safety),
                                };
                                let text =
                                    format!("order {} ({}) ended with {word}", id, order.recipe);
                                self.end(order, OrderState::Failed, word);
                                let me = self.me();
                                self.raise(&me, Some(id), class, text);
                            }
                        }
                    }
                }
            }
            Unconfirmed::Job { .. } => {}
        }
    }

    /// A station came onto or left the bus.
    pub fn presence(&mut self, p: falc_bus::Presence) {
        if p.present {
            self.present.insert(p.station.clone());
        } else {
            self.present.remove(&p.station);
        }
        self.settle_alarms(&p.station);
    }

    /// A request from the cell: operator communication.
    pub async fn upward(&mut self, request: Request, responder: Responder) {
        let cell = self.cell.to_string();
        let order = self.order_of_message();
        match request {
            Request::Output { lines } => {
                for l in &lines {
                    self.journal(EntryKind::Message, order, &cell, l);
                }
                self.shown.extend(lines);
                responder.respond(Ok(Response::Done)).await;
            }
            Request::Input { prompt, .. } => {
                let mut text = self.shown.join("\n");
                if !text.is_empty() {
                    text.push('\n');
                }
                text.push_str(&prompt);
                self.shown.clear();
                self.journal(EntryKind::Question, order, &cell, &prompt);
                say(&format!("EVENT question {prompt}"));
                if let Some(old) = self.question.take() {
                    old.responder
                        .respond(Err(ServiceError::state_conflict(
                            "a newer question replaced this one",
                        )))
                        .await;
                }
                self.question = Some(Question {
                    prompt: text,
                    responder,
                });
            }
            other => {
                responder
                    .respond(Err(ServiceError::undefined(format!(
                        "the operator serves only input and output to its cell, not {}",
                        other.service()
                    ))))
                    .await;
            }
        }
    }

    fn status(&self) -> Result<CellStatus, DatabaseError> {
        Ok(CellStatus {
            list: self.list_state(),
            cell_associated: self.associated,
            problem: self.problem.clone(),
            alarm: self.alarms.blocking().map(|a| a.line()),
            alarms: self.alarms.listed().to_vec(),
            running: self.running.clone(),
            queued: self.db.queued()?,
            journal_head: self.db.journal_head()?,
            question: self.question.as_ref().map(|q| q.prompt.clone()),
            shutdown_pending: self.shutdown_pending,
            stations: self
                .topology
                .stations()
                .iter()
                .filter(|s| s.commander.is_some())
                .map(|s| StationView {
                    name: s.name.clone(),
                    status: self.statuses.get(&s.name).cloned(),
                    connected: self.present.contains(&s.name),
                })
                .collect(),
        })
    }

    /// Answers one operator API request from console user `user`.
    pub async fn api(&mut self, user: &StationName, request: ApiRequest) -> ApiResult {
        let who = user.as_str();
        // The router already refused what the user's role does not allow;
        // checked again here so a mis-generated ACL cannot widen a role.
        let call = request.call();
        match self.topology.console(user) {
            Some(c) if c.role >= call.role() => {}
            Some(c) => {
                return Err(format!(
                    "{user} is {:?}, `{call}` needs {:?}",
                    c.role,
                    call.role()
                ))
            }
            None => return Err(format!("{user} is not a console user of this cell")),
        }
        let db = |e: DatabaseError| e.to_string();
        match request {
            ApiRequest::Status => Ok(ApiReply::Status(self.status().map_err(db)?)),
            ApiRequest::OrderList => Ok(ApiReply::Orders(self.db.orders().map_err(db)?)),
            ApiRequest::Messages { after } => Ok(ApiReply::Entries(
                self.db.entries(after, None, true, PAGE).map_err(db)?,
            )),
            ApiRequest::Journal { order, after } => Ok(ApiReply::Entries(
                self.db.entries(after, order, false, PAGE).map_err(db)?,
            )),
            ApiRequest::OrderAdd { recipe } => {
                let name = ObjectName::new(&recipe).map_err(|e| e.to_string())?;
                if !self.recipes.cell_recipes().contains(&&name) {
                    // A recipe saved since the last start is known once the
                    // recipe store checks clean with it (delivered at the start).
                    let fresh = recipe_store::load(&self.recipes_dir, &self.topology, &self.cell);
                    let known: Vec<String> = match &fresh {
                        Ok(set) => set.cell_recipes().iter().map(|n| n.to_string()).collect(),
                        Err(_) => Vec::new(),
                    };
                    if !known.iter().any(|n| n == name.as_str()) {
                        let list: Vec<String> = self
                            .recipes
                            .cell_recipes()
                            .iter()
                            .map(|n| n.as_str().to_lowercase())
                            .collect();
                        return Err(format!(
                            "there is no cell recipe {recipe}; the cell knows {}",
                            list.join(", ")
                        ));
                    }
                }
                let order = match self.db.add_order(&recipe.to_lowercase(), who) {
                    Ok(o) => o,
                    Err(e) => {
                        self.db_failed(&e);
                        return Err(e.to_string());
                    }
                };
                self.journal(
                    EntryKind::Action,
                    Some(order.id),
                    who,
                    &format!("added order {} ({})", order.id, order.recipe),
                );
                Ok(ApiReply::Order(order))
            }
            ApiRequest::OrderRemove { id } => match self.db.remove_order(id).map_err(db)? {
                Ok(order) => {
                    self.journal(
                        EntryKind::Action,
                        Some(id),
                        who,
                        &format!("removed order {id} ({})", order.recipe),
                    );
                    Ok(ApiReply::Done(format!("order {id} removed")))
                }
                Err(why) => Err(why),
            },
            ApiRequest::Start => self.start(who).await,
            ApiRequest::Stop => self.stop(who).await,
            ApiRequest::Ack { id } => self.ack(who, id),
            ApiRequest::Answer { text } => {
                let Some(q) = self.question.take() else {
                    return Err("no question is waiting for an answer".into());
                };
                let order = self.running_id();
                self.journal(EntryKind::Answer, order, who, &text);
                q.responder
                    .respond(Ok(Response::Answer(text.clone())))
                    .await;
                Ok(ApiReply::Done(format!("answered {text}")))
            }
            ApiRequest::RecipeList => Ok(ApiReply::Recipes(recipe_store::list(
                &self.recipes_dir,
                &self.topology,
                &self.cell,
            )?)),
            ApiRequest::RecipeGet { file } => Ok(ApiReply::Recipe(recipe_store::get(
                &self.recipes_dir,
                &file,
            )?)),
            ApiRequest::RecipePut { file, text, base } => {
                let saved = recipe_store::put(
                    &self.recipes_dir,
                    &self.topology,
                    &self.cell,
                    &file,
                    &text,
                    base,
                );
                match saved {
                    Ok(()) => {
                        let what = if base.is_none() { "created" } else { "changed" };
                        self.journal(
                            EntryKind::Action,
                            None,
                            who,
                            &format!("recipe {file} {what} (checked; the cell gets it at the next start)"),
                        );
                        Ok(ApiReply::Done(format!(
                            "recipe {file} saved: it checks clean; the cell gets it at the next start"
                        )))
                    }
                    Err(recipe_store::PutError::Findings(f)) => Err(format!(
                        "recipe {file} NOT saved: the recipe set does not check clean with it:\n{}",
                        f.join("\n")
                    )),
                    Err(recipe_store::PutError::Refused(why)) => {
                        Err(format!("recipe {file} NOT saved: {why}"))
                    }
                }
            }
            ApiRequest::Shutdown => {
                self.journal(EntryKind::Action, None, who, "shut down requested");
                self.shutdown_pending = true;
                if self.running.is_some() {
                    Ok(ApiReply::Done(
                        "the cell shuts down when the order list is done".into(),
                    ))
                } else {
                    Ok(ApiReply::Done("shutting down".into()))
                }
            }
        }
    }

    /// Acknowledges alarm `id`, or all; journalled with the user.
    fn ack(&mut self, who: &str, id: Option<i64>) -> ApiResult {
        let (acked, error) = self.alarms.ack(&mut self.db, id, who)?;
        if acked.is_empty() {
            return Ok(ApiReply::Done("no alarm to acknowledge".into()));
        }
        if let Some(s) = self.db_alarm.filter(|s| acked.iter().any(|a| a.id == *s)) {
            // Acknowledged: the next write tells whether the database works
            // again (it raises a new alarm if not).
            self.db_alarm = None;
            let _ = self.alarms.clear_where(&mut self.db, |a| a.id == s);
        }
        if let Some(e) = error {
            self.db_failed(&e);
        }
        for a in &acked {
            self.journal(
                EntryKind::Action,
                a.order,
                who,
                &format!("acknowledged alarm {}", a.line()),
            );
        }
        let lines: Vec<String> = acked.iter().map(|a| a.line()).collect();
        Ok(ApiReply::Done(format!(
            "acknowledged: {}",
            lines.join("; ")
        )))
    }

    async fn start(&mut self, who: &str) -> ApiResult {
        if let Some(a) = self.alarms.blocking() {
            return Err(format!(
                "alarm {} waits for acknowledgement (falc ack {}, or falc ack for all)",
                a.line(),
                a.id
            ));
        }
        if self.shutdown_pending {
            return Err("the cell is shutting down".into());
        }
        if self.running.is_some() {
            self.list = ListState::Running;
            return Ok(ApiReply::Done("the list is running".into()));
        }
        if let Err(text) = self.reload() {
            let me = self.me();
            self.journal(EntryKind::System, None, &me, &text);
            return Err(text);
        }
        self.connect().await?;
        self.reassociate().await?;
        match self.start_next().await {
            Ok(Some(order)) => {
                self.list = ListState::Running;
                self.journal(EntryKind::Action, None, who, "started the list");
                Ok(ApiReply::Done(format!(
                    "order {} ({}) started",
                    order.id, order.recipe
                )))
            }
            Ok(None) => Err("the order list holds no queued order".into()),
            Err(text) => {
                self.journal(
                    EntryKind::Action,
                    None,
                    who,
                    &format!("start refused: {text}"),
                );
                Err(text)
            }
        }
    }

    async fn stop(&mut self, who: &str) -> ApiResult {
        self.list = ListState::Idle;
        let Some(order) = self.running.take() else {
            self.journal(EntryKind::Action, None, who, "stopped the list");
            return Ok(ApiReply::Done("the list is stopped".into()));
        };
        let bus = self.station.bus().clone();
        let result = match ObjectName::new(&order.recipe) {
            Ok(name) => bus
                .request(&self.cell, &Request::Stop { name }, CELL_LIMIT)
                .await
                .map(|_| ())
                .map_err(|e| text_of(&e)),
            Err(e) => Err(e.to_string()),
        };
        if let Some(q) = self.question.take() {
            q.responder
                .respond(Err(ServiceError::state_conflict("the order was stopped")))
                .await;
        }
        self.journal(
            EntryKind::Action,
            Some(order.id),
            who,
            &format!("stopped order {}", order.id),
        );
        self.end(
            order.clone(),
            OrderState::Stopped,
            &format!("stopped by {who}"),
        );
        match result {
            Ok(()) => Ok(ApiReply::Done(format!("order {} stopped", order.id))),
            Err(text) => Ok(ApiReply::Done(format!(
                "order {} marked stopped; the cell did not confirm the stop: {text}",
                order.id
            ))),
        }
    }
}
