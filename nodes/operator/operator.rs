//! The operator node's behaviour: the order list worked through the cell,
//! operator communication (the cell's `output` and `input`), alarms and
//! acknowledgement, recipe delivery, and the answers to the operator API.
//! Every change is written to the [`Store`] before it is confirmed.

use crate::pps::{self, RecipeSet};
use crate::store::{Store, StoreError};
use falc_common::api::{
    ApiReply, ApiRequest, ApiResult, CellStatus, EntryKind, ListState, Order, OrderState,
    StationView,
};
use falc_common::bus::station::Station;
use falc_common::bus::Responder;
use falc_common::ids::{ObjectName, StationName};
use falc_common::mms::domain::content_hash;
use falc_common::mms::error::ServiceError;
use falc_common::mms::pdu::{JobEvent, Request, Response, Severity, Unconfirmed};
use falc_common::mms::vmd::VmdStatus;
use falc_common::node::say;
use falc_common::topology::Topology;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

/// How long a Start or Stop of the cell's program invocation may take.
const CELL_LIMIT: Duration = Duration::from_secs(10);

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
    store: Store,
    topology: Topology,
    cell: StationName,
    recipes_dir: PathBuf,
    recipes: RecipeSet,
    /// Content hash of each domain delivered to the cell in this association.
    delivered: BTreeMap<ObjectName, u64>,
    associated: bool,
    problem: Option<String>,
    list: ListState,
    alarm: Option<String>,
    running: Option<Order>,
    question: Option<Question>,
    shutdown_pending: bool,
    statuses: BTreeMap<StationName, VmdStatus>,
    /// The stations on the bus now.
    present: std::collections::BTreeSet<StationName>,
    /// Lines the cell showed since the last question (shown with it).
    shown: Vec<String>,
}

fn text_of(e: &ServiceError) -> String {
    e.description.clone()
}

impl Operator {
    /// The node around its station runtime, store and checked recipes.
    pub fn new(
        station: Station,
        store: Store,
        topology: Topology,
        cell: StationName,
        recipes_dir: PathBuf,
        recipes: RecipeSet,
    ) -> Self {
        Self {
            station,
            store,
            topology,
            cell,
            recipes_dir,
            recipes,
            delivered: BTreeMap::new(),
            associated: false,
            problem: None,
            list: ListState::Idle,
            alarm: None,
            running: None,
            question: None,
            shutdown_pending: false,
            statuses: BTreeMap::new(),
            present: Default::default(),
            shown: Vec::new(),
        }
    }

    /// Whether the node should stop (shut down requested and the list done).
    pub fn should_stop(&self) -> bool {
        self.shutdown_pending && self.running.is_none()
    }

    fn me(&self) -> String {
        self.station.bus().me().station.to_string()
    }

    /// Journals; a failure to write is logged and said (the node goes on:
    /// the order state itself is in the same file and was written first).
    pub fn journal(&mut self, kind: EntryKind, order: Option<i64>, who: &str, text: &str) {
        match self.store.journal(kind, order, who, text) {
            Ok(e) => say(&format!(
                "JOURNAL {} {} {who}: {}",
                e.id,
                kind.as_str(),
                text.replace('\n', " / ")
            )),
            Err(e) => {
                tracing::error!("{e}");
                say(&format!("EVENT store-error {e}"));
            }
        }
    }

    fn running_id(&self) -> Option<i64> {
        self.running.as_ref().map(|o| o.id)
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
        match pps::load(&self.recipes_dir, &self.topology, &self.cell) {
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
        if let Some(order) = self.running.take() {
            self.end(order, OrderState::Failed, &format!("alarm: {text}"));
            self.raise(text);
        } else {
            let me = self.me();
            self.journal(EntryKind::Alarm, None, &me, &text);
        }
    }

    fn raise(&mut self, text: String) {
        self.list = ListState::Alarm;
        let me = self.me();
        let order = self.running_id();
        self.journal(EntryKind::Alarm, order, &me, &text);
        self.alarm = Some(text);
    }

    fn end(&mut self, order: Order, state: OrderState, result: &str) {
        if let Err(e) = self.store.end_order(order.id, state, result) {
            tracing::error!("{e}");
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
    async fn start_next(&mut self) -> Result<Option<Order>, String> {
        let Some(order) = self.store.next_queued().map_err(|e| e.to_string())? else {
            return Ok(None);
        };
        let name = ObjectName::new(&order.recipe).map_err(|e| e.to_string())?;
        let bus = self.station.bus().clone();
        let req = Request::Start {
            name,
            argument: format!("order {}", order.id),
        };
        match bus.request(&self.cell, &req, CELL_LIMIT).await {
            Ok(_) => {
                self.store
                    .set_running(order.id)
                    .map_err(|e| e.to_string())?;
                let order = Order {
                    state: OrderState::Running,
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
            Err(e) => Err(format!(
                "order {} ({}) not started: {}",
                order.id,
                order.recipe,
                text_of(&e)
            )),
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
            Err(text) => self.raise(text),
        }
    }

    /// A publication of a station.
    pub async fn publication(&mut self, u: Unconfirmed) {
        match u {
            Unconfirmed::Status { station, status } => {
                self.statuses.insert(station, status);
            }
            Unconfirmed::Report {
                station,
                severity,
                text,
            } if station == self.cell => {
                let kind = if severity == Severity::Alarm {
                    EntryKind::Alarm
                } else {
                    EntryKind::Report
                };
                let order = self.running_id();
                self.journal(kind, order, station.as_str(), &text);
            }
            Unconfirmed::Report { .. } => {}
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
                        let (result, alarm) = match failure {
                            JobEvent::Alarm(text) => (
                                format!("alarm: {text}"),
                                format!("order {} ({}): {text}", order.id, order.recipe),
                            ),
                            other => {
                                let word = match other {
                                    JobEvent::BadProduct => "bad_product",
                                    JobEvent::FailedSafe => "failed_safe",
                                    _ => "failed_danger",
                                };
                                let alarm = format!(
                                    "order {} ({}) ended with {word}",
                                    order.id, order.recipe
                                );
                                (word.to_string(), alarm)
                            }
                        };
                        self.running = None;
                        self.question = None;
                        self.end(order, OrderState::Failed, &result);
                        self.raise(alarm);
                    }
                }
            }
            Unconfirmed::Job { .. } => {}
        }
    }

    /// A station came onto or left the bus.
    pub fn presence(&mut self, p: falc_common::bus::Presence) {
        if p.present {
            self.present.insert(p.station);
        } else {
            self.present.remove(&p.station);
        }
    }

    /// A request from the cell: operator communication.
    pub async fn upward(&mut self, request: Request, responder: Responder) {
        let cell = self.cell.to_string();
        let order = self.running_id();
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

    fn status(&self) -> Result<CellStatus, StoreError> {
        Ok(CellStatus {
            list: self.list,
            cell_associated: self.associated,
            problem: self.problem.clone(),
            alarm: self.alarm.clone(),
            running: self.running.clone(),
            queued: self.store.queued()?,
            journal_head: self.store.journal_head()?,
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
        let db = |e: StoreError| e.to_string();
        match request {
            ApiRequest::Status => Ok(ApiReply::Status(self.status().map_err(db)?)),
            ApiRequest::OrderList => Ok(ApiReply::Orders(self.store.orders().map_err(db)?)),
            ApiRequest::Messages { after } => Ok(ApiReply::Entries(
                self.store.entries(after, None, true, PAGE).map_err(db)?,
            )),
            ApiRequest::Journal { order, after } => Ok(ApiReply::Entries(
                self.store.entries(after, order, false, PAGE).map_err(db)?,
            )),
            ApiRequest::OrderAdd { recipe } => {
                let name = ObjectName::new(&recipe).map_err(|e| e.to_string())?;
                if !self.recipes.cell_recipes().contains(&&name) {
                    // A recipe saved since the last start is known once the
                    // store checks clean with it (delivered at the start).
                    let fresh = pps::load(&self.recipes_dir, &self.topology, &self.cell);
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
                let order = self
                    .store
                    .add_order(&recipe.to_lowercase(), who)
                    .map_err(db)?;
                self.journal(
                    EntryKind::Action,
                    Some(order.id),
                    who,
                    &format!("added order {} ({})", order.id, order.recipe),
                );
                Ok(ApiReply::Order(order))
            }
            ApiRequest::OrderRemove { id } => match self.store.remove_order(id).map_err(db)? {
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
            ApiRequest::Ack => {
                let Some(alarm) = self.alarm.take() else {
                    return Ok(ApiReply::Done("no alarm to acknowledge".into()));
                };
                self.list = ListState::Idle;
                self.journal(
                    EntryKind::Action,
                    None,
                    who,
                    &format!("acknowledged: {alarm}"),
                );
                Ok(ApiReply::Done(format!("acknowledged: {alarm}")))
            }
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
            ApiRequest::RecipeList => Ok(ApiReply::Recipes(pps::list(
                &self.recipes_dir,
                &self.topology,
                &self.cell,
            )?)),
            ApiRequest::RecipeGet { file } => {
                Ok(ApiReply::Recipe(pps::get(&self.recipes_dir, &file)?))
            }
            ApiRequest::RecipePut { file, text, base } => {
                let saved = pps::put(
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
                    Err(pps::PutError::Findings(f)) => Err(format!(
                        "recipe {file} NOT saved: the recipe set does not check clean with it:\n{}",
                        f.join("\n")
                    )),
                    Err(pps::PutError::Refused(why)) => {
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

    async fn start(&mut self, who: &str) -> ApiResult {
        if let Some(alarm) = &self.alarm {
            return Err(format!(
                "an alarm waits for acknowledgement (falc ack): {alarm}"
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
