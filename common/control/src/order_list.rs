//! The operator's order list, sans-I/O (the quinn-proto style): the order
//! list worked through the cell, operator communication (the cell's
//! `output` and `input`), alarms and their acknowledgement, recipe delivery
//! and the answers to the operator API.
//!
//! Events come in with the time they happen (`handle_*`); what the node
//! must do comes out of [`OrderList::poll_output`]: one request to the cell
//! at a time ([`CellCall`], answered with [`OrderList::handle_cell_reply`]),
//! answers to consoles and to the cell's indications, and lines to say.
//! [`OrderList::poll_timeout`] is when to try the cell again. Nothing here
//! waits: a console's `status` is answered while a start is under way;
//! `start`, `stop`, the next order and a halt are jobs done one after the
//! other.
//!
//! Every change is written to the [`Records`] before it is confirmed. A
//! write that fails stops the list with a device alarm and halts the
//! running order at the cell; order ends that could not be written are
//! written before the next start.

use crate::alarm_list::{AlarmList, Raised};
use crate::recipe_source::{Delivery, PutError, RecipeSet, RecipeSource};
use crate::records::{EntryQuery, Records};
use falc_model::alarm::{Alarm, AlarmClass};
use falc_model::console::RecipeFile;
use falc_model::console::{
    ApiReply, ApiRequest, ApiResult, CellStatus, EntryKind, ListState, Order, OrderState,
    Placement, StationView, MAX_OUTPUT_CHARS, MAX_OUTPUT_LINES, MAX_QUEUED_ORDERS,
    QUESTION_WINDOW_LINES,
};
use falc_model::ids::{CellId, ObjectName, StationName};
use falc_model::mms::domain::content_hash;
use falc_model::mms::error::{ErrorClass, ServiceError};
use falc_model::mms::pdu::{JobEvent, Peer, Request, Response, Severity, Unconfirmed};
use falc_model::mms::program::PiState;
use falc_model::mms::vmd::{PhysicalStatus, VmdStatus};
use falc_model::mode::{CellMode, ModeSetting};
use falc_model::product::{RecipeVersion, UsedRecipe};
use falc_model::topology::Topology;
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::Duration;

/// A station's message this soon after an order ended still belongs to it.
const TRAIL: Duration = Duration::from_secs(2);

/// At most this many messages and events wait for an order's start to be
/// confirmed; more are journalled as they come (nothing is lost).
const MAX_EARLY: usize = 1000;

/// At most this many journal entries per API answer.
const PAGE: usize = 500;

/// How often to try the cell again while it is not associated, or a
/// recipe could not be delivered.
pub const RETRY: Duration = Duration::from_secs(1);

/// A console request or an indication of the cell waiting for its answer
/// (the node keeps what answers it under this number).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Ticket(pub u64);

/// A request to the cell. One is out at a time; its outcome comes back
/// through [`OrderList::handle_cell_reply`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CellCall {
    /// Associate the cell (the root's Initiate).
    Associate,
    /// Initiate the associated cell again: a cell that lost a workstation
    /// associates it again (the 1992 recursive scheme), or refuses with the
    /// cause.
    Initiate,
    /// Deliver one recipe (a domain download, with a program invocation
    /// for a cell recipe).
    Deliver(Delivery),
    /// Start the program invocation `name` for an order.
    Start {
        /// The cell recipe.
        name: ObjectName,
        /// `order N`.
        argument: String,
    },
    /// Stop the program invocation `name`.
    Stop {
        /// The cell recipe.
        name: ObjectName,
    },
    /// A request passed to the cell as it is: a mode, a step, a manual
    /// operation for a workstation, a Resume.
    Pass(Request),
    /// Ask how the run of program invocation `name` stands (the order that
    /// ran while the cell was cut off, or when this node started): its
    /// answer comes back through [`OrderList::handle_cell_answer`].
    Ask {
        /// The cell recipe.
        name: ObjectName,
    },
}

/// How long a call to the cell may take (a delivery: each of its steps).
pub const CELL_LIMIT: Duration = Duration::from_secs(10);

impl CellCall {
    /// The request this call is on the bus, `calling` being the operator's
    /// own peer: an Associate and an Initiate are both Initiates; a
    /// delivery is a sequence of requests
    /// (`falc_model::mms::domain::download_steps`), handed back as it is.
    pub fn request(self, calling: &Peer) -> Result<Request, Box<Delivery>> {
        Ok(match self {
            CellCall::Associate | CellCall::Initiate => Request::Initiate {
                calling: calling.clone(),
            },
            CellCall::Deliver(d) => return Err(Box::new(d)),
            CellCall::Start { name, argument } => Request::Start { name, argument },
            CellCall::Stop { name } => Request::Stop { name },
            CellCall::Pass(request) => request,
            CellCall::Ask { name } => Request::GetProgramInvocationAttributes { name },
        })
    }
}

/// What the node must do.
#[derive(Debug)]
pub enum Output {
    /// Send this request to the cell.
    Cell(CellCall),
    /// Answer a console's request.
    Reply {
        /// Which.
        ticket: Ticket,
        /// The answer (boxed: a status is large, the other outputs small).
        result: Box<ApiResult>,
    },
    /// Answer an indication of the cell.
    Respond {
        /// Which.
        ticket: Ticket,
        /// The answer.
        result: Result<Response, ServiceError>,
    },
    /// Drop an indication of the cell unanswered (its order ended).
    Forget(Ticket),
    /// A line for the node's standard output (`EVENT …`, `JOURNAL …`).
    Say(String),
    /// What `status` answers changed: tell the consoles that watch
    /// (a publication, so they need not ask again and again).
    Changed,
}

/// A question the cell asked, waiting for `answer`.
#[derive(Debug)]
struct Question {
    prompt: String,
    ticket: Ticket,
}

/// The console request a job answers when it ends, and its user.
#[derive(Debug)]
struct Caller {
    ticket: Ticket,
    who: String,
}

/// Work that needs the cell, done one after the other.
#[derive(Debug)]
enum Job {
    /// Associate if not, and deliver what changed (the retry).
    Connect,
    /// An operator's `start`.
    Start(Caller),
    /// The next order after one ended.
    Next,
    /// An operator's `stop`.
    Stop(Caller),
    /// Stop the running order at the cell: a write failed.
    Halt,
    /// An operator's request passed to the cell (mode, step, manual):
    /// journalled with the user as `done` once the cell confirmed it.
    Pass {
        by: Caller,
        request: Request,
        done: String,
    },
    /// An operator's `restart`.
    Restart {
        by: Caller,
        order: i64,
        from: Option<u16>,
    },
    /// A workstation came back on the bus while the cell is associated:
    /// the cell is initiated again, which associates the workstation and
    /// gives it the cell's mode and its recipes, in every mode.
    Rejoin(StationName),
}

/// The cell call out, and what its outcome goes on with. `start` is the
/// operator's start a connection is made for (None: the retry); `by` is
/// whose start an order's is (None: the list going on).
#[derive(Debug)]
enum Busy {
    Associating {
        start: Option<Caller>,
    },
    Delivering {
        start: Option<Caller>,
        domain: ObjectName,
        hash: u64,
    },
    Initiating(Caller),
    Starting {
        order: Order,
        started_ms: i64,
        by: Option<Caller>,
        /// A restarted order as it was: what a refusal puts back (never
        /// the queue: it ran before).
        previous: Option<Order>,
    },
    Passing {
        by: Caller,
        done: String,
    },
    Stopping {
        order: Order,
        by: Caller,
    },
    Halting {
        order: Order,
    },
    Rejoining(StationName),
    /// Asking how the running order's run stands at the cell after a cut
    /// ([`OrderList::away`]).
    Asking {
        start: Option<Caller>,
    },
}

/// Why the running order's run is not followed now: it went on at the
/// cell while this node could not hear it. Once the cell is associated
/// again it is asked how the run stands ([`CellCall::Ask`]) before
/// anything else.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Away {
    /// The cell was cut off while it ran, or this node started while it
    /// ran.
    Running,
    /// Its Start was sent but never confirmed: the cell may never have
    /// begun it (then it is queued again).
    StartUnconfirmed,
}

/// What waits for an order's Start to be confirmed
/// ([`OrderList::can_hold`]).
#[derive(Debug)]
enum Early {
    /// The cell's job event of that order, or a station's report.
    Publication(Unconfirmed),
    /// The cell's output line or question (answered at once, journalled
    /// once the start is).
    Message(EntryKind, String),
}

/// The operator's order list.
pub struct OrderList<R: Records, S: RecipeSource> {
    me: StationName,
    cell: StationName,
    topology: Topology,
    db: R,
    source: S,
    recipes: RecipeSet,
    /// The content hash of each of `recipes`, in the same order.
    hashes: Vec<u64>,
    /// The cell's mode as last kept in the records (for the figures).
    recorded_mode: Option<CellMode>,
    /// Each workstation's job its status shows running: the program,
    /// since when (ms since the Unix epoch), the order it is part of.
    open_jobs: BTreeMap<StationName, (ObjectName, i64, Option<i64>)>,
    /// The version of each of `recipes` (by domain), as the records keep it.
    versions: BTreeMap<ObjectName, RecipeVersion>,
    /// Content hash of each domain delivered to the cell in this association.
    delivered: BTreeMap<ObjectName, u64>,
    associated: bool,
    /// The cell associated every workstation since the last Associate or
    /// Initiate and none has left the bus since: a `start` needs no
    /// Initiate ([`Self::association_stands`]).
    whole: bool,
    problem: Option<String>,
    /// How many orders may wait in the list ([`MAX_QUEUED_ORDERS`] unless
    /// [`Self::with_max_queued`] says otherwise).
    max_queued: usize,
    /// Whether the list goes on (`Running`) or waits (`Idle`); shown as
    /// `Alarm` while an alarm holds it back ([`Self::list_state`]).
    list: ListState,
    /// Every station's alarms and the operator's own.
    alarms: AlarmList,
    /// The alarm a failed write raised: the records are taken as failing
    /// until it is acknowledged (the next write then tells).
    db_alarm: Option<i64>,
    running: Option<Order>,
    /// Set while the running order's run is not followed ([`Away`]).
    away: Option<Away>,
    question: Option<Question>,
    shutdown_pending: bool,
    statuses: BTreeMap<StationName, VmdStatus>,
    /// The stations on the bus now.
    present: BTreeSet<StationName>,
    /// Lines the cell showed since the last question (shown with it).
    shown: Vec<String>,
    /// Order ends that could not be written: written before the next start
    /// (until then the order stays `running` in the records, which a
    /// restart turns into `interrupted`: never queued again).
    unwritten_ends: Vec<(i64, OrderState, String)>,
    /// The order that ended last, and when (messages that trail it
    /// closely belong to it).
    last_ended: Option<(i64, Duration)>,
    /// The cell call out.
    busy: Option<Busy>,
    /// Jobs waiting for the cell call out to end.
    jobs: VecDeque<Job>,
    /// What came while the Start of an order was still unconfirmed, in
    /// the order it came: handled once the start is, so that nothing of an
    /// order is journalled before its start.
    early: Vec<Early>,
    /// When to try the cell again.
    next_try: Duration,
    out: VecDeque<Output>,
    /// The status as last told by [`Output::Changed`].
    told: Option<CellStatus>,
}

/// How an order was placed, for its journal line (`, priority 5, for
/// falc2`), empty for the default.
fn placed(order: &Order) -> String {
    let mut v = Vec::new();
    if order.priority != 0 {
        v.push(format!("priority {}", order.priority));
    }
    if let Some(due) = order.due_ms {
        v.push(format!("due {}", falc_model::console::utc_text(due)));
    }
    if let Some(cell) = &order.wanted {
        v.push(format!("for {cell}"));
    }
    v.iter().map(|p| format!(", {p}")).collect()
}

/// The content hash of each recipe of `set`, in order.
fn hashes_of(set: &RecipeSet) -> Vec<u64> {
    set.deliveries
        .iter()
        .map(|d| content_hash(&d.content))
        .collect()
}

impl<R: Records, S: RecipeSource> OrderList<R, S> {
    /// The order list of operator `me` over `cell`, with its records and
    /// checked recipes. Its first connection attempt is due at once.
    pub fn new(
        me: StationName,
        cell: StationName,
        topology: Topology,
        db: R,
        source: S,
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
            me,
            cell,
            topology,
            db,
            source,
            hashes: hashes_of(&recipes),
            versions: BTreeMap::new(),
            recorded_mode: None,
            open_jobs: BTreeMap::new(),
            recipes,
            delivered: BTreeMap::new(),
            associated: false,
            whole: false,
            problem: None,
            max_queued: MAX_QUEUED_ORDERS,
            list: ListState::Idle,
            alarms,
            db_alarm: None,
            running: None,
            away: None,
            question: None,
            shutdown_pending: false,
            statuses: BTreeMap::new(),
            present: BTreeSet::new(),
            shown: Vec::new(),
            unwritten_ends: Vec::new(),
            last_ended: None,
            busy: None,
            jobs: VecDeque::new(),
            early: Vec::new(),
            next_try: Duration::ZERO,
            out: VecDeque::new(),
            told: None,
        }
        .versioned()
    }

    /// Keeps each recipe of the set as a version ([`Self::version_set`]).
    fn versioned(mut self) -> Self {
        self.version_set();
        self
    }

    /// Keeps the text of each recipe of the set as its file's newest
    /// version where it is not yet (a text changed in the store by hand
    /// since the last save is a version of its own, by this node), and
    /// journals each new one.
    fn version_set(&mut self) {
        let mut versions = BTreeMap::new();
        for d in &self.recipes.deliveries.clone() {
            let text = String::from_utf8_lossy(&d.content);
            let me = self.me.to_string();
            match self
                .db
                .add_version(&d.file, &text, &me, "found in the recipe store")
            {
                Ok((v, new)) => {
                    if new {
                        let line = format!(
                            "recipe {} version {} ({}) found in the recipe store",
                            v.file,
                            v.version,
                            v.hash.short()
                        );
                        self.journal_mine(EntryKind::System, None, &line);
                    }
                    versions.insert(d.domain.clone(), v);
                }
                Err(e) => return self.db_failed(&e),
            }
        }
        self.versions = versions;
    }

    /// The recipe versions an order of cell recipe `recipe` runs: the
    /// cell recipe, then each workstation recipe it starts.
    fn used_by(&self, recipe: &str) -> Vec<UsedRecipe> {
        let used = |domain: &str| {
            let d = self.recipes.get(domain)?;
            let v = self.versions.get(&d.domain)?;
            Some(UsedRecipe {
                domain: d.domain.to_string(),
                file: d.file.clone(),
                version: v.version,
                hash: v.hash.clone(),
                starts: d.starts.clone(),
            })
        };
        let Ok(name) = ObjectName::new(recipe) else {
            return Vec::new();
        };
        let Some(cell) = used(name.as_str()) else {
            return Vec::new();
        };
        let below = cell.starts.iter().filter_map(|s| used(s));
        std::iter::once(cell.clone()).chain(below).collect()
    }

    /// Takes over `order`, which was running on this cell when this node
    /// stopped (the records still say `running`): the cell may have run it
    /// on, so it is asked how the run stands once it is associated.
    pub fn adopting(mut self, order: Order) -> Self {
        self.running = Some(order);
        self.away = Some(Away::Running);
        self
    }

    /// At most `max` orders wait in the list; one more is refused.
    pub fn with_max_queued(mut self, max: usize) -> Self {
        self.max_queued = max;
        self
    }

    /// The next thing the node must do. When nothing else is left, an
    /// [`Output::Changed`] if the status differs from the one last told.
    pub fn poll_output(&mut self) -> Option<Output> {
        if let Some(out) = self.out.pop_front() {
            return Some(out);
        }
        let now = self.status().ok()?;
        if self.told.as_ref() == Some(&now) {
            return None;
        }
        self.told = Some(now);
        Some(Output::Changed)
    }

    /// When to call [`Self::handle_timeout`]: the next attempt to
    /// associate the cell or deliver to it, while it is needed.
    pub fn poll_timeout(&self) -> Option<Duration> {
        let idle = self.busy.is_none() && self.jobs.is_empty();
        let deliver = self.running.is_none() && self.undelivered().next().is_some();
        (idle && (!self.associated || deliver)).then_some(self.next_try)
    }

    /// The time of [`Self::poll_timeout`] has come: try the cell again.
    pub fn handle_timeout(&mut self, now: Duration) {
        if self.poll_timeout().is_some_and(|t| t <= now) {
            self.next_try = now + RETRY;
            self.jobs.push_back(Job::Connect);
            self.pump(now);
        }
    }

    /// Whether the node should stop (shut down requested, no order runs,
    /// no call to the cell is out).
    pub fn should_stop(&self) -> bool {
        self.shutdown_pending && self.running.is_none() && self.busy.is_none()
    }

    /// The records, for tests to look at and to make fail.
    #[cfg(test)]
    pub(crate) fn records(&mut self) -> &mut R {
        &mut self.db
    }

    fn say(&mut self, line: String) {
        self.out.push_back(Output::Say(line));
    }

    fn reply(&mut self, ticket: Ticket, result: ApiResult) {
        self.out.push_back(Output::Reply {
            ticket,
            result: Box::new(result),
        });
    }

    fn call(&mut self, call: CellCall, busy: Busy) {
        self.out.push_back(Output::Cell(call));
        self.busy = Some(busy);
    }

    /// Journals; a failure to write stops the list ([`Self::db_failed`]).
    pub fn journal(&mut self, kind: EntryKind, order: Option<i64>, who: &str, text: &str) {
        match self.db.journal(kind, order, who, text) {
            Ok(e) => self.say(format!(
                "JOURNAL {} {} {who}: {}",
                e.id,
                kind.as_str(),
                text.replace('\n', " / ")
            )),
            Err(e) => self.db_failed(&e),
        }
    }

    fn journal_mine(&mut self, kind: EntryKind, order: Option<i64>, text: &str) {
        let me = self.me.to_string();
        self.journal(kind, order, &me, text);
    }

    /// A write to the order list or journal failed: the cell must not run
    /// on with the journal behind. The list stops with an alarm saying why
    /// and the running order is halted at the cell ([`Job::Halt`]).
    fn db_failed(&mut self, e: &R::Error) {
        tracing::error!("{e}");
        self.say(format!("EVENT store-error {e}"));
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
        if self.running.is_some() {
            // Before anything else.
            self.jobs.push_front(Job::Halt);
        }
        // Neither journalled nor, most likely, stored: the records are what
        // cannot be written (the list keeps it in memory meanwhile).
        let order = self.running_id();
        let me = self.me.to_string();
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
                self.say(format!(
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

    /// Raises an alarm of `station` that this node journals (a station's
    /// own reports are journalled as they come), under `order` (the order
    /// that failed, which no longer runs by now).
    fn raise(&mut self, station: &str, order: Option<i64>, class: AlarmClass, text: String) {
        self.raise_alarm(station, class, &text, order);
        self.journal(EntryKind::Alarm, order, station, &text);
    }

    /// Clears the alarms of `station` whose condition is gone, from its
    /// latest status and presence.
    fn settle_alarms(&mut self, station: &StationName) {
        let status = self.statuses.get(station);
        let present = self.present.contains(station);
        let (cleared, error) = self
            .alarms
            .settle(&mut self.db, station.as_str(), status, present);
        self.cleared(station.as_str(), cleared, error);
    }

    /// Whether `station` is one of the cell's workstations (not the
    /// operator, not the cell).
    fn is_workstation(&self, station: &StationName) -> bool {
        *station != self.me && *station != self.cell && self.topology.station(station).is_some()
    }

    /// Says and journals the alarms cleared because of `station`.
    fn cleared(&mut self, station: &str, cleared: Vec<Alarm>, error: Option<R::Error>) {
        for a in cleared {
            self.say(format!("EVENT alarm-cleared id={}", a.id));
            self.journal(
                EntryKind::Report,
                a.order,
                station,
                &format!("alarm #{} cleared: {}", a.id, a.text),
            );
        }
        if let Some(e) = error {
            self.db_failed(&e);
        }
    }

    /// Whether what comes now waits ([`Early`]): the cell is being asked to
    /// start an order, and fewer than [`MAX_EARLY`] things wait already.
    fn can_hold(&self) -> bool {
        matches!(self.busy, Some(Busy::Starting { .. })) && self.early.len() < MAX_EARLY
    }

    /// Journals a message of the cell; while an order is starting, once
    /// its start is journalled.
    fn journal_cell_message(&mut self, now: Duration, kind: EntryKind, text: &str) {
        if self.can_hold() {
            self.early.push(Early::Message(kind, text.to_string()));
        } else {
            let cell = self.cell.to_string();
            let order = self.order_of_message(now);
            self.journal(kind, order, &cell, text);
        }
    }

    fn running_id(&self) -> Option<i64> {
        self.running.as_ref().map(|o| o.id)
    }

    /// The order a message of the cell or a station belongs to: the running
    /// one, else the one that ended within [`TRAIL`] (a cause a station
    /// reports just after its order failed).
    fn order_of_message(&self, now: Duration) -> Option<i64> {
        self.running_id().or(self
            .last_ended
            .filter(|(_, at)| now.saturating_sub(*at) < TRAIL)
            .map(|(id, _)| id))
    }

    fn end(&mut self, now: Duration, order: Order, state: OrderState, result: &str) {
        self.last_ended = Some((order.id, now));
        if let Err(e) = self.db.end_order(order.id, state, result) {
            self.unwritten_ends
                .push((order.id, state, result.to_string()));
            self.db_failed(&e);
        }
        self.journal_mine(
            EntryKind::Order,
            Some(order.id),
            &format!("order {} ({}) {state}: {result}", order.id, order.recipe),
        );
        self.say(format!("EVENT order-ended id={} state={state}", order.id));
    }

    /// Order `id`, which never ran after all, put back as it was
    /// (`result`). If that write failed it stays `running` in the records:
    /// interrupted at a restart, never run twice; failed (`why`) once the
    /// records can be written again.
    fn undone(&mut self, id: i64, result: Result<(), R::Error>, why: &str) {
        if let Err(e) = result {
            self.unwritten_ends
                .push((id, OrderState::Failed, why.to_string()));
            self.db_failed(&e);
        }
    }

    /// Answers the waiting question with `why` (its order no longer runs).
    fn refuse_question(&mut self, why: &str) {
        if let Some(q) = self.question.take() {
            self.out.push_back(Output::Respond {
                ticket: q.ticket,
                result: Err(ServiceError::state_conflict(why)),
            });
        }
    }

    /// Drops the waiting question unanswered.
    fn forget_question(&mut self) {
        if let Some(q) = self.question.take() {
            self.out.push_back(Output::Forget(q.ticket));
        }
    }

    // ---- jobs: one call to the cell at a time ----

    /// Begins the waiting jobs while no call to the cell is out.
    fn pump(&mut self, now: Duration) {
        while self.busy.is_none() {
            let Some(job) = self.jobs.pop_front() else {
                return;
            };
            self.begin(now, job);
        }
    }

    fn begin(&mut self, now: Duration, job: Job) {
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
    fn undelivered(&self) -> impl Iterator<Item = (&Delivery, u64)> {
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
    fn connect(&mut self, start: Option<Caller>, sent: bool) {
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
                self.call(CellCall::Initiate, Busy::Initiating(by));
            }
        }
    }

    /// Whether the cell's associations stand: it associated its
    /// workstations, none left the bus since, and the cell's status does
    /// not say it lost one. Else a `start` Initiates the cell again first
    /// (the 1992 recursive scheme associates what was lost).
    fn association_stands(&self) -> bool {
        self.associated
            && self.whole
            && self
                .statuses
                .get(&self.cell)
                .map_or(true, |s| s.physical == PhysicalStatus::Operational)
    }

    /// A connection failed: the last refusal is kept as `problem`.
    fn connect_failed(&mut self, start: Option<Caller>, text: String) {
        if let Some(by) = start {
            self.reply(by.ticket, Err(text));
        }
    }

    fn associated_now(&mut self) {
        self.associated = true;
        self.whole = true;
        self.problem = None;
        self.delivered.clear();
        self.say(format!("EVENT associated station={}", self.cell));
        let me = self.me.to_string();
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

    fn begin_start(&mut self, by: Caller) {
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
    fn cell_mode(&self) -> CellMode {
        self.statuses
            .get(&self.cell)
            .map(|s| s.mode)
            .unwrap_or_default()
    }

    /// Why order `id` cannot be restarted now (from `from`), or the order,
    /// the request that restarts it at the cell and the journal line.
    fn restart_plan(
        &self,
        id: i64,
        from: Option<u16>,
    ) -> Result<(Order, CellCall, String), String> {
        if let Some(a) = self.alarms.blocking() {
            return Err(format!(
                "alarm {} waits for acknowledgement (falc ack {})",
                a.line(),
                a.id
            ));
        }
        if let Some(r) = &self.running {
            return Err(format!("order {} runs: falc stop first", r.id));
        }
        if self.shutdown_pending {
            return Err("the cell is shutting down".into());
        }
        if !self.cell_mode().runs_orders() {
            return Err("the cell is in maintenance mode: no order runs (falc mode auto)".into());
        }
        if !self.associated || self.undelivered().next().is_some() {
            return Err(format!(
                "the cell does not hold the recipes yet ({}): try again in a moment",
                self.problem.as_deref().unwrap_or("connecting")
            ));
        }
        let orders = self.db.orders().map_err(|e| e.to_string())?;
        let order = orders
            .into_iter()
            .find(|o| o.id == id)
            .ok_or_else(|| format!("there is no order {id}"))?;
        match order.state {
            OrderState::Failed | OrderState::Stopped | OrderState::Interrupted => {}
            OrderState::Queued => return Err(format!("order {id} is queued: falc start runs it")),
            OrderState::Running => return Err(format!("order {id} runs")),
            OrderState::Done => {
                return Err(format!(
                    "order {id} is done: add a new order to run {} again",
                    order.recipe
                ))
            }
        }
        let name = ObjectName::new(&order.recipe).map_err(|e| e.to_string())?;
        let Some(delivery) = self.recipes.deliveries.iter().find(|d| d.domain == name) else {
            return Err(format!(
                "order {id}'s recipe {} is no longer in the recipe store",
                order.recipe
            ));
        };
        if let Some(f) = from {
            let text = String::from_utf8_lossy(&delivery.content);
            let recipe = falc_recipe::syntax::parse(&text, &order.recipe);
            let mut states: Vec<u16> = recipe.rows.iter().map(|r| r.state.0).collect();
            states.sort_unstable();
            states.dedup();
            if !states.contains(&f) {
                return Err(format!(
                    "{} has no state {f}: its states are {}",
                    order.recipe,
                    states
                        .iter()
                        .map(u16::to_string)
                        .collect::<Vec<_>>()
                        .join(", ")
                ));
            }
        }
        Ok(match from {
            None if order.state == OrderState::Stopped => {
                let what = format!("resumed order {id} where it stopped");
                (order, CellCall::Pass(Request::Resume { name }), what)
            }
            _ => {
                let f = from.unwrap_or(1);
                let argument = match from {
                    Some(f) => format!("order {id} from {f}"),
                    None => format!("order {id}"),
                };
                let what = format!("restarted order {id} from state {f}");
                (order, CellCall::Start { name, argument }, what)
            }
        })
    }

    fn begin_restart(&mut self, by: Caller, id: i64, from: Option<u16>) {
        let (order, call, what) = match self.restart_plan(id, from) {
            Ok(plan) => plan,
            Err(text) => {
                let line = format!("restart of order {id} refused: {text}");
                self.journal(EntryKind::Action, Some(id), &by.who, &line);
                return self.reply(by.ticket, Err(text));
            }
        };
        let used = self.used_by(&order.recipe);
        let cell = self.topology.cell().as_str();
        let started_ms = match self.db.set_running(id, cell, &used) {
            Ok(ms) => ms,
            Err(e) => {
                let text = format!("order {id} not restarted: {e}");
                self.db_failed(&e);
                return self.reply(by.ticket, Err(text));
            }
        };
        self.journal(EntryKind::Action, Some(id), &by.who, &what);
        let busy = Busy::Starting {
            order: order.clone(),
            started_ms,
            by: Some(by),
            previous: Some(order),
        };
        self.call(call, busy);
    }

    /// The request passing `mode` to the cell, or why not.
    fn mode_request(&self, mode: CellMode, stations: Vec<StationName>) -> Result<Request, String> {
        if mode != CellMode::Step && !stations.is_empty() {
            return Err("workstations step only in step mode".into());
        }
        for (i, s) in stations.iter().enumerate() {
            if self.topology.commander_of(s) != Some(&self.cell) {
                return Err(format!("{s} is not a workstation of {}", self.cell));
            }
            if stations[..i].contains(s) {
                return Err(format!("{s} is named more than once"));
            }
        }
        let current = self.cell_mode();
        if let Some(r) = &self.running {
            if !current.may_change_running(mode) {
                return Err(format!(
                    "order {} runs: the mode changes from {current} to {mode} only when no \
                     order runs (falc stop first)",
                    r.id
                ));
            }
        }
        let mut stepping = Vec::new();
        if mode == CellMode::Step {
            stepping.push(self.cell.clone());
            stepping.extend(stations);
        }
        Ok(Request::Mode(ModeSetting { mode, stepping }))
    }

    /// `orders` as they stand: an end the database could not take yet (a
    /// full disk) shows, not the state written before it.
    fn with_unwritten_ends(&self, mut orders: Vec<Order>) -> Vec<Order> {
        for (id, state, result) in &self.unwritten_ends {
            if let Some(o) = orders.iter_mut().find(|o| o.id == *id) {
                o.state = *state;
                o.result = Some(format!(
                    "{result} (not yet written: the journal cannot be written)"
                ));
            }
        }
        orders
    }

    /// Writes the order ends a failed write held back; the error (the
    /// fault raised again) while it still cannot.
    fn write_held_ends(&mut self) -> Result<(), String> {
        while let Some((id, state, result)) = self.unwritten_ends.first().cloned() {
            if let Err(e) = self.db.end_order(id, state, &result) {
                let text = e.to_string();
                self.db_failed(&e);
                return Err(text);
            }
            self.unwritten_ends.remove(0);
            self.journal_mine(
                EntryKind::Order,
                Some(id),
                &format!("order {id} {state}: {result} (written late)"),
            );
        }
        Ok(())
    }

    /// Starts the next queued order: durably `running` before the cell is
    /// asked to start it; back in the queue only if the cell refused.
    fn start_next(&mut self, by: Option<Caller>) {
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
    fn start_ended(&mut self, by: Option<Caller>, outcome: Result<Option<Order>, String>) {
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
                let me = self.me.to_string();
                self.raise(&me, None, AlarmClass::Process, text);
            }
        }
    }

    fn begin_stop(&mut self, now: Duration, by: Caller) {
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

    fn stopped(
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

    fn halted(&mut self, now: Duration, order: Order, result: Result<(), String>) {
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

    /// The outcome of the call to the cell that is out, when only success
    /// or failure matters ([`Self::handle_cell_answer`] with the answer).
    pub fn handle_cell_reply(&mut self, now: Duration, result: Result<(), ServiceError>) {
        self.handle_cell_answer(now, result.map(|()| Response::Done));
    }

    /// The answer to the call to the cell that is out.
    pub fn handle_cell_answer(&mut self, now: Duration, result: Result<Response, ServiceError>) {
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
                    self.start_next(Some(by));
                }
                Err(text) => {
                    self.problem = Some(text.clone());
                    self.reply(by.ticket, Err(text));
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
                        self.shown.clear();
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
        let me = self.me.to_string();
        self.raise(&me, id, AlarmClass::Communication, text);
        self.pump(now);
    }

    /// The cell's answer to [`CellCall::Ask`]; then the connection goes on
    /// (`start`: the operator's start it was made for).
    fn asked(
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
    fn learned(&mut self, now: Duration, state: PiState, end: Option<JobEvent>) {
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
    fn run_unknown(&mut self, now: Duration, why: &str) {
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
        let me = self.me.to_string();
        self.raise(&me, Some(id), AlarmClass::Process, text);
    }

    /// A station came onto (`present`) or left the bus. A workstation lost
    /// while no order runs (in any mode, a manual operation too) is a
    /// communication alarm of its own; while an order runs the cell raises
    /// it. Back on the bus, every alarm saying it cannot be reached clears.
    pub fn handle_presence(&mut self, now: Duration, station: StationName, present: bool) {
        if present {
            let back = self.present.insert(station.clone());
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
                self.raise(station.as_str(), None, AlarmClass::Communication, text);
            }
        }
        self.settle_alarms(&station);
        self.pump(now);
    }

    /// A publication of a station.
    pub fn handle_publication(&mut self, now: Duration, u: Unconfirmed) {
        self.publication(now, u);
        self.pump(now);
    }

    /// A publication of a station, without beginning the next job.
    fn publication(&mut self, now: Duration, u: Unconfirmed) {
        match u {
            Unconfirmed::Status { station, status } => {
                if station == self.cell && self.recorded_mode != Some(status.mode) {
                    match self.db.record_mode(status.mode) {
                        Ok(()) => self.recorded_mode = Some(status.mode),
                        Err(e) => self.db_failed(&e),
                    }
                }
                if station != self.cell {
                    if let Some(p) = &status.program {
                        let known = self.open_jobs.get(&station).map(|(name, ..)| name);
                        if known != Some(&p.name) {
                            let job =
                                (p.name.clone(), self.db.now_ms(), self.order_of_message(now));
                            self.open_jobs.insert(station.clone(), job);
                        }
                    }
                }
                self.statuses.insert(station.clone(), status);
                self.settle_alarms(&station);
            }
            Unconfirmed::Report { .. } if self.can_hold() => {
                self.early.push(Early::Publication(u));
            }
            Unconfirmed::Report {
                station,
                severity,
                text,
            } => {
                // Every station's reports, each under its own name (its
                // message pane), with the order they belong to.
                let order = self.order_of_message(now);
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

    /// A workstation's job event: an end is kept in the records with the
    /// order it is part of (pauses are not).
    fn workstation_job(
        &mut self,
        now: Duration,
        station: StationName,
        program: ObjectName,
        event: JobEvent,
    ) {
        let outcome = match &event {
            JobEvent::Paused | JobEvent::Resumed => return,
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
            ended_ms: self.db.now_ms(),
            outcome,
        };
        if let Err(e) = self.db.record_job(order, &job) {
            self.db_failed(&e);
        }
    }

    /// A job event of the running order's program invocation.
    fn job_event(
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
                        let cell = self.cell.to_string();
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
                        let me = self.me.to_string();
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

    /// A request of the cell: operator communication. Answered through
    /// [`Output::Respond`] under `ticket` (an `input` once answered).
    pub fn handle_cell_request(&mut self, now: Duration, ticket: Ticket, request: Request) {
        if let Some(e) = too_long_for_the_operator(&request) {
            self.out.push_back(Output::Respond {
                ticket,
                result: Err(e),
            });
            self.pump(now);
            return;
        }
        match request {
            Request::Output { lines } => {
                for l in &lines {
                    self.journal_cell_message(now, EntryKind::Message, l);
                }
                self.shown.extend(lines);
                // The window that goes with the next question; the journal
                // has every line.
                let over = self.shown.len().saturating_sub(QUESTION_WINDOW_LINES);
                self.shown.drain(..over);
                self.out.push_back(Output::Respond {
                    ticket,
                    result: Ok(Response::Done),
                });
            }
            Request::Input { prompt, .. } => {
                let mut text = self.shown.join("\n");
                if !text.is_empty() {
                    text.push('\n');
                }
                text.push_str(&prompt);
                self.shown.clear();
                self.journal_cell_message(now, EntryKind::Question, &prompt);
                self.say(format!("EVENT question {prompt}"));
                self.refuse_question("a newer question replaced this one");
                self.question = Some(Question {
                    prompt: text,
                    ticket,
                });
            }
            other => {
                let e = ServiceError::undefined(format!(
                    "the operator serves only input and output to its cell, not {}",
                    other.service()
                ));
                self.out.push_back(Output::Respond {
                    ticket,
                    result: Err(e),
                });
            }
        }
        self.pump(now);
    }

    // ---- the operator API ----

    /// The cell this list runs on.
    pub fn cell(&self) -> &CellId {
        self.topology.cell()
    }

    /// Whether the cell has a cell recipe of this name (as delivered, or
    /// saved since).
    pub fn knows_recipe(&self, recipe: &str) -> bool {
        let Ok(name) = ObjectName::new(recipe) else {
            return false;
        };
        self.recipes.cell_recipes().contains(&&name)
            || self
                .source
                .load()
                .is_ok_and(|set| set.cell_recipes().contains(&&name))
    }

    /// Whether alarm `id` is listed here.
    pub fn has_alarm(&self, id: i64) -> bool {
        self.alarms.listed().iter().any(|a| a.id == id)
    }

    /// Whether order `id` ran (or runs) on this cell.
    pub fn ran(&self, id: i64) -> bool {
        self.db.orders().is_ok_and(|orders| {
            orders
                .iter()
                .any(|o| o.id == id && o.cell.as_deref() == Some(self.cell().as_str()))
        })
    }

    /// Whether the cell's question waits for an answer.
    pub fn question_waiting(&self) -> bool {
        self.question.is_some()
    }

    /// The cell at a glance, as `status` answers it.
    pub fn status(&self) -> Result<CellStatus, R::Error> {
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
            mode: self.cell_mode(),
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

    /// The same for a request a console made for this cell of a plant
    /// (`falc --cell C`): the journal and the messages it reads are this
    /// cell's (with those written before entries had a cell).
    pub fn handle_cell_api(
        &mut self,
        now: Duration,
        ticket: Ticket,
        user: &StationName,
        request: ApiRequest,
    ) {
        let cell = self.cell().to_string();
        self.api_call(now, ticket, user, request, Some(&cell));
    }

    /// One operator API request from console user `user`, answered through
    /// [`Output::Reply`] under `ticket`: at once, or (`start`, `stop`) when
    /// the cell confirmed.
    pub fn handle_api(
        &mut self,
        now: Duration,
        ticket: Ticket,
        user: &StationName,
        request: ApiRequest,
    ) {
        self.api_call(now, ticket, user, request, None);
    }

    fn api_call(
        &mut self,
        now: Duration,
        ticket: Ticket,
        user: &StationName,
        request: ApiRequest,
        entries_of: Option<&str>,
    ) {
        if let Some(result) = self.api(ticket, user, request, entries_of) {
            self.reply(ticket, result);
        }
        self.pump(now);
    }

    /// Saves `text` as recipe `file` (checked with the whole set; only
    /// over `base`) and keeps it as the file's newest version; `what` the
    /// store did (`changed`, `created`, `rolled back to version 3`).
    fn save_recipe(
        &mut self,
        who: &str,
        file: &RecipeFile,
        text: &str,
        base: Option<u64>,
        what: &str,
        message: &str,
    ) -> ApiResult {
        match self.source.put(file, text, base) {
            Ok(()) => {}
            Err(PutError::Findings(f)) => {
                return Err(format!(
                    "recipe {file} NOT saved: the recipe set does not check clean with it:\n{}",
                    f.join("\n")
                ))
            }
            Err(PutError::Refused(why)) => return Err(format!("recipe {file} NOT saved: {why}")),
        }
        // Saved: a version that cannot be written stops the list (the
        // next start keeps the text as a version found in the store).
        let version = match self.db.add_version(file, text, who, message) {
            Ok((v, _)) => v,
            Err(e) => {
                let text = format!("recipe {file} saved, but its version not kept: {e}");
                self.db_failed(&e);
                return Err(text);
            }
        };
        let said = if message.is_empty() {
            String::new()
        } else {
            format!(": {message}")
        };
        self.journal(
            EntryKind::Action,
            None,
            who,
            &format!(
                "recipe {file} {what}: version {} ({}){said} (checked; the cell gets it at the next start)",
                version.version,
                version.hash.short()
            ),
        );
        Ok(ApiReply::Done(format!(
            "recipe {file} saved as version {} ({}): it checks clean; the cell gets it at the next start",
            version.version,
            version.hash.short()
        )))
    }

    /// Saves version `version` of `file` again as its newest version,
    /// checked like any save.
    fn roll_back(
        &mut self,
        who: &str,
        file: &RecipeFile,
        version: u32,
        message: &str,
    ) -> ApiResult {
        let (old, text) = match self.db.version(file, version) {
            Ok(Some(v)) => v,
            Ok(None) => {
                return Err(format!(
                    "recipe {file} has no version {version} (falc recipe history {file})"
                ))
            }
            Err(e) => return Err(e.to_string()),
        };
        let now = self.source.get(file).ok();
        if now.as_ref().is_some_and(|n| n.text == text) {
            return Err(format!(
                "recipe {file} is the text of version {version} already: nothing to roll back"
            ));
        }
        let what = format!(
            "rolled back to version {} ({})",
            old.version,
            old.hash.short()
        );
        self.save_recipe(who, file, &text, now.map(|n| n.hash), &what, message)
    }

    /// The answer now, or None when a job answers it later; the journal
    /// and messages it reads are cell `entries_of`'s (None: all).
    fn api(
        &mut self,
        ticket: Ticket,
        user: &StationName,
        request: ApiRequest,
        entries_of: Option<&str>,
    ) -> Option<ApiResult> {
        let who = user.as_str();
        let caller = || Caller {
            ticket,
            who: who.to_string(),
        };
        // The router already refused what the user's role does not allow;
        // checked again here so a mis-generated ACL cannot widen a role.
        let call = request.call();
        match self.topology.console(user) {
            Some(c) if c.role >= call.role() => {}
            Some(c) => {
                return Some(Err(format!(
                    "{user} is {:?}, `{call}` needs {:?}",
                    c.role,
                    call.role()
                )))
            }
            None => return Some(Err(format!("{user} is not a console user of this cell"))),
        }
        let db = |e: R::Error| e.to_string();
        Some(match request {
            ApiRequest::Status => self.status().map(ApiReply::Status).map_err(db),
            ApiRequest::OrderList => self
                .db
                .orders()
                .map(|orders| ApiReply::Orders(self.with_unwritten_ends(orders)))
                .map_err(db),
            ApiRequest::Messages { after } => self
                .db
                .entries(&EntryQuery {
                    messages_only: true,
                    cell: entries_of,
                    ..EntryQuery::page(after, PAGE)
                })
                .map(ApiReply::Entries)
                .map_err(db),
            ApiRequest::Journal { order, after, last } => self
                .db
                .entries(&EntryQuery {
                    order,
                    cell: entries_of,
                    newest: last.is_some(),
                    ..EntryQuery::page(after, last.map_or(PAGE, |n| usize::from(n).min(PAGE)))
                })
                .map(ApiReply::Entries)
                .map_err(db),
            ApiRequest::OrderAdd {
                recipe,
                placement,
                count,
            } => self.add_order(who, &recipe, &placement, count),
            ApiRequest::OrderRemove { id } => match self.db.remove_order(id) {
                Err(e) => Err(e.to_string()),
                Ok(Ok(order)) => {
                    self.journal(
                        EntryKind::Action,
                        Some(id),
                        who,
                        &format!("removed order {id} ({})", order.recipe),
                    );
                    Ok(ApiReply::Done(format!("order {id} removed")))
                }
                Ok(Err(why)) => Err(why),
            },
            ApiRequest::Start | ApiRequest::Stop => {
                let by = caller();
                let stop = matches!(request, ApiRequest::Stop);
                self.jobs
                    .push_back(if stop { Job::Stop(by) } else { Job::Start(by) });
                return None;
            }
            ApiRequest::Ack { id } => self.ack(who, id),
            ApiRequest::Answer { text } => {
                let Some(q) = self.question.take() else {
                    return Some(Err("no question is waiting for an answer".into()));
                };
                let order = self.running_id();
                self.journal(EntryKind::Answer, order, who, &text);
                self.out.push_back(Output::Respond {
                    ticket: q.ticket,
                    result: Ok(Response::Answer(text.clone())),
                });
                Ok(ApiReply::Done(format!("answered {text}")))
            }
            ApiRequest::RecipeList => self.source.list().map(ApiReply::Recipes),
            ApiRequest::RecipeGet { file } => self.source.get(&file).map(ApiReply::Recipe),
            ApiRequest::RecipePut {
                file,
                text,
                base,
                message,
            } => {
                let what = if base.is_none() { "created" } else { "changed" };
                self.save_recipe(who, &file, &text, base, what, &message)
            }
            ApiRequest::RecipeHistory { file } => match self.db.versions(&file) {
                Ok(v) if v.is_empty() => Err(format!(
                    "recipe {file} has no saved version (falc store list shows the recipes)"
                )),
                Ok(v) => Ok(ApiReply::Versions(v)),
                Err(e) => Err(e.to_string()),
            },
            ApiRequest::RecipeVersion { file, version } => match self.db.version(&file, version) {
                Ok(Some((version, text))) => Ok(ApiReply::RecipeAt { version, text }),
                Ok(None) => Err(format!(
                    "recipe {file} has no version {version} (falc recipe history {file})"
                )),
                Err(e) => Err(e.to_string()),
            },
            ApiRequest::RecipeRollback {
                file,
                version,
                message,
            } => self.roll_back(who, &file, version, &message),
            ApiRequest::Figures(query) => {
                let now = self.db.now_ms();
                let until = query.until_ms.unwrap_or(now);
                match self.db.figure_inputs(query.since_ms, until) {
                    Ok(inputs) => {
                        let mut f = crate::figures::compute(
                            &inputs,
                            self.topology.calendar(),
                            &[self.topology.cell().as_str()],
                            &query,
                            now,
                        );
                        crate::figures::keep_newest_runs(&mut f);
                        Ok(ApiReply::Figures(Box::new(f)))
                    }
                    Err(e) => Err(e.to_string()),
                }
            }
            ApiRequest::OrderShow { id } => match self.db.order_record(id) {
                Ok(Some(mut record)) => {
                    if let Some(o) = self.with_unwritten_ends(vec![record.order.clone()]).pop() {
                        record.order = o;
                    }
                    Ok(ApiReply::OrderRecord(Box::new(record)))
                }
                Ok(None) => Err(format!("there is no order {id}")),
                Err(e) => Err(e.to_string()),
            },
            ApiRequest::Mode { mode, stations } => {
                let request = match self.mode_request(mode, stations) {
                    Ok(r) => r,
                    Err(e) => return Some(Err(e)),
                };
                if mode == CellMode::Maintenance {
                    self.list = ListState::Idle;
                }
                let done = match &request {
                    Request::Mode(m) => format!("mode {m}"),
                    _ => format!("mode {mode}"),
                };
                self.jobs.push_back(Job::Pass {
                    by: caller(),
                    request,
                    done,
                });
                return None;
            }
            ApiRequest::Step { station, to } => {
                let on = station.clone().unwrap_or_else(|| self.cell.clone());
                let done = match to {
                    Some(t) => format!("step on {on} up to state {t}"),
                    None => format!("step on {on}"),
                };
                let by = Caller {
                    ticket,
                    who: who.to_string(),
                };
                let request = Request::Step { station, to };
                self.jobs.push_back(Job::Pass { by, request, done });
                return None;
            }
            ApiRequest::Manual { station, action } => {
                if let Err(e) = falc_recipe::check::check_manual(&action) {
                    return Some(Err(format!("manual on {station}: {e}")));
                }
                let done = format!("manual on {station}: {action}");
                let request = Request::Manual {
                    station,
                    action,
                    by: who.to_string(),
                };
                self.jobs.push_back(Job::Pass {
                    by: caller(),
                    request,
                    done,
                });
                return None;
            }
            ApiRequest::Restart { order, from } => {
                self.jobs.push_back(Job::Restart {
                    by: caller(),
                    order,
                    from,
                });
                return None;
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
        })
    }

    /// Adds `count` orders of `recipe`, placed as `placement` says; each
    /// journalled with the user. The list's limit counts them all: none
    /// is added when they do not all fit.
    fn add_order(
        &mut self,
        who: &str,
        recipe: &str,
        placement: &Placement,
        count: u16,
    ) -> ApiResult {
        let name = ObjectName::new(recipe).map_err(|e| e.to_string())?;
        if let Some(cell) = placement
            .cell
            .as_ref()
            .filter(|c| *c != self.topology.cell())
        {
            return Err(format!(
                "there is no cell {cell}; the order list runs on cell {}",
                self.topology.cell()
            ));
        }
        if !self.recipes.cell_recipes().contains(&&name) {
            // A recipe saved since the last start is known once the recipe
            // store checks clean with it (delivered at the start).
            let known = match self.source.load() {
                Ok(set) => set.cell_recipes().contains(&&name),
                Err(_) => false,
            };
            if !known {
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
        match self.db.queued() {
            Ok(queued) if queued + usize::from(count) > self.max_queued => {
                let more = if count > 1 {
                    format!("; {count} more do not fit")
                } else {
                    String::new()
                };
                return Err(format!(
                    "the order list holds {queued} queued orders, its limit \
                     (falc-operator --max-queued-orders {}){more}; remove some, or start the list",
                    self.max_queued
                ));
            }
            Ok(_) => {}
            Err(e) => {
                let text = e.to_string();
                self.db_failed(&e);
                return Err(text);
            }
        }
        let mut added = Vec::new();
        for _ in 0..count {
            let order = match self.db.add_order(&recipe.to_lowercase(), who, placement) {
                Ok(o) => o,
                Err(e) => {
                    let text = e.to_string();
                    self.db_failed(&e);
                    return Err(text);
                }
            };
            self.journal(
                EntryKind::Action,
                Some(order.id),
                who,
                &format!(
                    "added order {} ({}{})",
                    order.id,
                    order.recipe,
                    placed(&order)
                ),
            );
            added.push(order);
        }
        match added.pop() {
            Some(only) if added.is_empty() => Ok(ApiReply::Order(only)),
            Some(last) => {
                added.push(last);
                Ok(ApiReply::Orders(added))
            }
            None => Err("no order added".into()),
        }
    }

    /// Acknowledges alarm `id`, or all; journalled with the user.
    fn ack(&mut self, who: &str, id: Option<i64>) -> ApiResult {
        let (acked, error) = self.alarms.ack(&mut self.db, id, who)?;
        if acked.is_empty() {
            if let Some(e) = error {
                // Not one could be written: none is acknowledged.
                let text = e.to_string();
                self.db_failed(&e);
                return Err(format!("not acknowledged: {text}"));
            }
            return Ok(ApiReply::Done("no alarm to acknowledge".into()));
        }
        if let Some(s) = self.db_alarm.filter(|s| acked.iter().any(|a| a.id == *s)) {
            // Acknowledged: the order ends held back are written now, not
            // at the next start (there may be none: the list was done), and
            // that write tells whether the records work again (it raises a
            // new alarm if not).
            self.db_alarm = None;
            let _ = self.alarms.clear_where(&mut self.db, |a| a.id == s);
            let _ = self.write_held_ends();
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
}

/// The refusal of an operator communication that carries more than an
/// operator can read ([`MAX_OUTPUT_LINES`] lines of [`MAX_OUTPUT_CHARS`]
/// characters), before any of it is journalled or shown.
fn too_long_for_the_operator(request: &Request) -> Option<ServiceError> {
    let too_long = |text: &str| text.chars().count() > MAX_OUTPUT_CHARS;
    let why = match request {
        Request::Output { lines } if lines.len() > MAX_OUTPUT_LINES => format!(
            "an output of {} lines; the operator takes at most {MAX_OUTPUT_LINES} at once",
            lines.len()
        ),
        Request::Output { lines } => match lines.iter().find(|l| too_long(l)) {
            Some(l) => format!(
                "an output line `{}`; the operator takes lines of at most {MAX_OUTPUT_CHARS} characters",
                falc_model::ids::excerpt(l)
            ),
            None => return None,
        },
        Request::Input { prompt, .. } if too_long(prompt) => format!(
            "a question `{}`; the operator takes questions of at most {MAX_OUTPUT_CHARS} characters",
            falc_model::ids::excerpt(prompt)
        ),
        _ => return None,
    };
    Some(ServiceError::undefined(why))
}

#[cfg(test)]
mod tests {
    //! The order list on a virtual clock, with records in memory and a
    //! recipe source in memory; the test plays the cell (answering each
    //! [`CellCall`]) and the consoles.

    use super::*;
    use crate::recipe_source::fake::{set, Source};
    use crate::records::memory::Memory;
    use falc_model::alarm::Cause;

    /// The cell as shipped (console users `console`, an operator, and
    /// `observer`).
    const TOPOLOGY: &str = include_str!("../../../launch/cell.toml");

    fn name(s: &str) -> ObjectName {
        ObjectName::new(s).expect("a valid name")
    }

    fn st(s: &str) -> StationName {
        StationName::new(s).expect("a valid station")
    }

    struct Rig {
        list: OrderList<Memory, Source>,
        now: Duration,
        tickets: u64,
    }

    impl Rig {
        fn new() -> Self {
            let topology = Topology::parse(TOPOLOGY, "test").expect("topology");
            let list = OrderList::new(
                st("operator"),
                st("cell"),
                topology,
                Memory::default(),
                Source::default(),
                set(),
            );
            Self {
                list,
                now: Duration::ZERO,
                tickets: 0,
            }
        }

        fn outputs(&mut self) -> Vec<Output> {
            std::iter::from_fn(|| self.list.poll_output()).collect()
        }

        fn ticket(&mut self) -> Ticket {
            self.tickets += 1;
            Ticket(self.tickets)
        }

        /// Sends a console request; its ticket and what came out.
        fn api(&mut self, user: &str, req: ApiRequest) -> (Ticket, Vec<Output>) {
            let t = self.ticket();
            self.list.handle_api(self.now, t, &st(user), req);
            (t, self.outputs())
        }

        /// A console request answered at once.
        fn ask(&mut self, user: &str, req: ApiRequest) -> ApiResult {
            let (t, out) = self.api(user, req);
            reply(&out, t).unwrap_or_else(|| panic!("no answer at once: {out:?}"))
        }

        fn status(&mut self) -> CellStatus {
            match self.ask("console", ApiRequest::Status) {
                Ok(ApiReply::Status(s)) => s,
                other => panic!("{other:?}"),
            }
        }

        /// The cell answers the call that is out (an error is a refusal).
        fn answer(&mut self, result: Result<(), &str>) -> Vec<Output> {
            let result = result.map_err(ServiceError::state_conflict);
            self.list.handle_cell_reply(self.now, result);
            self.outputs()
        }

        /// No answer comes to the call that is out.
        fn no_reply(&mut self) -> Vec<Output> {
            let e = ServiceError::unreachable("no reply from cell");
            self.list.handle_cell_reply(self.now, Err(e));
            self.outputs()
        }

        /// The cell answers the [`CellCall::Ask`] that is out, and every
        /// call that follows (deliveries) with success.
        fn tell(&mut self, answer: Result<Response, ServiceError>) -> Vec<Output> {
            self.list.handle_cell_answer(self.now, answer);
            let mut all = self.outputs();
            let mut more = call(&all).is_some();
            while more {
                let out = self.answer(Ok(()));
                more = call(&out).is_some();
                all.extend(out);
            }
            all
        }

        /// The cell asks the operator `prompt`; the question's ticket.
        fn question(&mut self, prompt: &str) -> Ticket {
            let q = self.ticket();
            let input = Request::Input {
                prompt: prompt.into(),
                timeout_s: None,
            };
            self.list.handle_cell_request(self.now, q, input);
            self.outputs();
            q
        }

        fn publish(&mut self, u: Unconfirmed) -> Vec<Output> {
            self.list.handle_publication(self.now, u);
            self.outputs()
        }

        fn job(&mut self, event: JobEvent) -> Vec<Output> {
            self.publish(Unconfirmed::Job {
                station: st("cell"),
                program: name("dikdroog"),
                event,
            })
        }

        fn add(&mut self, n: usize) {
            for _ in 0..n {
                let r = self.ask("console", ApiRequest::order_add("dikdroog"));
                assert!(matches!(r, Ok(ApiReply::Order(_))), "{r:?}");
            }
        }

        /// `start` through association, delivery, an Initiate if one is due, and the
        /// cell's Start; the start's answer.
        fn start(&mut self) -> ApiResult {
            let (t, mut out) = self.api("console", ApiRequest::Start);
            loop {
                if let Some(r) = reply(&out, t) {
                    return r;
                }
                assert!(
                    call(&out).is_some(),
                    "neither an answer nor a call: {out:?}"
                );
                out = self.answer(Ok(()));
            }
        }

        /// `start` through association and delivery up to the cell's
        /// Start, which is left out; the start's ticket.
        fn start_until_the_cells_start(&mut self) -> Ticket {
            let (t, mut out) = self.api("console", ApiRequest::Start);
            while !matches!(call(&out), Some(CellCall::Start { .. })) {
                out = self.answer(Ok(()));
            }
            t
        }

        fn order(&mut self, id: i64) -> Order {
            let orders = self.list.records().orders.clone();
            orders
                .into_iter()
                .find(|o| o.id == id)
                .unwrap_or_else(|| panic!("no order {id}"))
        }
    }

    fn reply(out: &[Output], ticket: Ticket) -> Option<ApiResult> {
        out.iter().find_map(|o| match o {
            Output::Reply { ticket: t, result } if *t == ticket => Some(*result.clone()),
            _ => None,
        })
    }

    fn call(out: &[Output]) -> Option<CellCall> {
        out.iter().find_map(|o| match o {
            Output::Cell(c) => Some(c.clone()),
            _ => None,
        })
    }

    fn said(out: &[Output], what: &str) -> bool {
        out.iter()
            .any(|o| matches!(o, Output::Say(l) if l.contains(what)))
    }

    #[test]
    fn a_start_associates_delivers_and_starts_and_status_is_answered_meanwhile() {
        let mut r = Rig::new();
        r.add(1);
        let (start, out) = r.api("console", ApiRequest::Start);
        assert_eq!(call(&out), Some(CellCall::Associate));
        // The loop does not wait for the cell: status is answered now.
        assert!(!r.status().cell_associated);
        let out = r.answer(Ok(()));
        assert!(said(&out, "EVENT associated station=cell"));
        let Some(CellCall::Deliver(d)) = call(&out) else {
            panic!("{out:?}")
        };
        assert_eq!(
            d.domain,
            name("WELDING$DROOG_DIK"),
            "workstation recipes first"
        );
        let out = r.answer(Ok(()));
        assert!(matches!(call(&out), Some(CellCall::Deliver(d)) if d.is_cell));
        let out = r.answer(Ok(()));
        assert!(said(&out, "EVENT cell-ready recipes=2"));
        // Just associated: no Initiate again.
        assert_eq!(
            call(&out),
            Some(CellCall::Start {
                name: name("dikdroog"),
                argument: "order 1".into()
            })
        );
        assert_eq!(
            r.order(1).state,
            OrderState::Running,
            "durably running before the cell is asked"
        );
        assert!(
            reply(&out, start).is_none(),
            "answered only when the cell confirmed"
        );
        let out = r.answer(Ok(()));
        assert_eq!(
            reply(&out, start),
            Some(Ok(ApiReply::Done("order 1 (dikdroog) started".into())))
        );
        assert_eq!(r.status().list, ListState::Running);
        let out = r.job(JobEvent::Done);
        assert!(said(&out, "EVENT order-ended id=1 state=done"));
        assert!(said(&out, "EVENT list-done"));
        assert_eq!(r.order(1).state, OrderState::Done);
        assert_eq!(r.status().list, ListState::Idle);
        // A second start: nothing to deliver again, the association
        // stands: the order starts.
        r.add(1);
        let (_, out) = r.api("console", ApiRequest::Start);
        assert!(
            matches!(call(&out), Some(CellCall::Start { .. })),
            "{out:?}"
        );
        r.answer(Ok(()));
        r.job(JobEvent::Done);
        // A workstation left the bus and came back while an order ran (no
        // rejoin then): the next start Initiates the cell first.
        r.add(1);
        let (_, out) = r.api("console", ApiRequest::Start);
        assert!(matches!(call(&out), Some(CellCall::Start { .. })));
        r.answer(Ok(()));
        let now = r.now;
        r.list.handle_presence(now, st("welding"), false);
        r.list.handle_presence(now, st("welding"), true);
        r.outputs();
        r.job(JobEvent::Done);
        r.add(1);
        let (start, out) = r.api("console", ApiRequest::Start);
        assert_eq!(call(&out), Some(CellCall::Initiate));
        let out = r.answer(Err("welding: not associated"));
        assert!(matches!(reply(&out, start), Some(Err(_))), "{out:?}");
        // Refused: the next start tries again; once it went through, the
        // association stands.
        let (_, out) = r.api("console", ApiRequest::Start);
        assert_eq!(call(&out), Some(CellCall::Initiate));
        let out = r.answer(Ok(()));
        assert!(matches!(call(&out), Some(CellCall::Start { .. })));
    }

    #[test]
    fn each_run_records_the_versions_it_ran_and_a_save_or_rollback_is_a_new_version() {
        let mut r = Rig::new();
        // At start-up the store's texts are kept as versions 1.
        let welding = RecipeFile::new(st("welding"), "droog_dik").expect("file");
        let cell = RecipeFile::new(st("cell"), "dikdroog").expect("file");
        let kept = r.list.records().versions.clone();
        assert_eq!(kept.len(), 2);
        assert!(kept
            .iter()
            .all(|(v, _)| v.version == 1 && v.author == "operator"));
        r.add(1);
        assert!(r.start().is_ok());
        r.job(JobEvent::Done);
        // The engineer saves a new welding text, with a message.
        let base = r.list.source.get(&welding).expect("get").hash;
        let put = ApiRequest::RecipePut {
            file: welding.clone(),
            text: "thicker".into(),
            base: Some(base),
            message: "more current".into(),
        };
        let said = r.ask("engineer", put).expect("saved");
        assert!(
            matches!(&said, ApiReply::Done(t) if t.contains("version 2")),
            "{said:?}"
        );
        let history = r.ask(
            "console",
            ApiRequest::RecipeHistory {
                file: welding.clone(),
            },
        );
        let Ok(ApiReply::Versions(v)) = history else {
            panic!("{history:?}")
        };
        assert_eq!(
            v.iter()
                .map(|v| (v.version, v.author.as_str(), v.message.as_str()))
                .collect::<Vec<_>>(),
            vec![
                (1, "operator", "found in the recipe store"),
                (2, "engineer", "more current")
            ]
        );
        // A save with a finding is no version.
        let bad = ApiRequest::RecipePut {
            file: welding.clone(),
            text: "defect".into(),
            base: Some(r.list.source.get(&welding).expect("get").hash),
            message: String::new(),
        };
        assert!(r.ask("engineer", bad).is_err());
        r.add(1);
        assert!(r.start().is_ok());
        r.job(JobEvent::Done);
        // Roll back to 1: version 3 with version 1's text.
        let back = ApiRequest::RecipeRollback {
            file: welding.clone(),
            version: 1,
            message: "scrap rate".into(),
        };
        assert!(r.ask("engineer", back.clone()).is_ok());
        let again = r.ask("engineer", back);
        assert!(
            matches!(&again, Err(e) if e.contains("nothing to roll back")),
            "{again:?}"
        );
        r.add(1);
        assert!(r.start().is_ok());
        r.job(JobEvent::Done);
        let used = |r: &mut Rig, id: i64| -> Vec<(String, u32)> {
            let Ok(ApiReply::OrderRecord(rec)) = r.ask("console", ApiRequest::OrderShow { id })
            else {
                panic!("no record of order {id}")
            };
            assert_eq!(rec.runs.len(), 1);
            rec.runs[0]
                .recipes
                .iter()
                .map(|u| (u.file.to_string(), u.version))
                .collect()
        };
        let c = cell.to_string();
        let w = welding.to_string();
        assert_eq!(used(&mut r, 1), vec![(c.clone(), 1), (w.clone(), 1)]);
        assert_eq!(used(&mut r, 2), vec![(c.clone(), 1), (w.clone(), 2)]);
        assert_eq!(used(&mut r, 3), vec![(c, 1), (w.clone(), 3)]);
        let hashes: Vec<_> = r
            .list
            .records()
            .runs
            .iter()
            .map(|(_, run)| run.recipes[1].hash.clone())
            .collect();
        assert_eq!(hashes[0], hashes[2], "the rollback's text is the first's");
        assert_ne!(hashes[0], hashes[1]);
        let text = r.ask(
            "console",
            ApiRequest::RecipeVersion {
                file: welding,
                version: 2,
            },
        );
        assert!(matches!(text, Ok(ApiReply::RecipeAt { text, .. }) if text == "thicker"));
        let none = r.ask("console", ApiRequest::OrderShow { id: 99 });
        assert!(matches!(none, Err(e) if e.contains("no order 99")));
    }

    #[test]
    fn the_list_goes_on_and_a_start_the_cell_refuses_puts_the_order_back() {
        let mut r = Rig::new();
        r.add(2);
        assert!(r.start().is_ok());
        let out = r.job(JobEvent::Done);
        assert!(
            matches!(call(&out), Some(CellCall::Start { argument, .. }) if argument == "order 2")
        );
        let out = r.answer(Err("vmd-state/program invocation busy"));
        assert!(said(&out, "EVENT alarm"), "{out:?}");
        assert_eq!(
            r.order(2).state,
            OrderState::Queued,
            "never lost, never run"
        );
        let s = r.status();
        assert_eq!(s.list, ListState::Alarm);
        assert!(s
            .alarm
            .is_some_and(|a| a.contains("order 2 (dikdroog) not started")));
        // The way back: ack, start, done.
        assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
        assert!(r.start().is_ok());
        r.job(JobEvent::Done);
        assert_eq!(r.order(2).state, OrderState::Done);
    }

    #[test]
    fn while_the_cell_is_away_it_is_tried_again_every_second() {
        let mut r = Rig::new();
        assert_eq!(r.list.poll_timeout(), Some(Duration::ZERO));
        r.list.handle_timeout(r.now);
        assert_eq!(call(&r.outputs()), Some(CellCall::Associate));
        assert_eq!(r.list.poll_timeout(), None, "nothing while a call is out");
        let out = r.answer(Err("no reply from cell"));
        assert!(said(&out, "EVENT not-associated no reply from cell"));
        assert_eq!(r.status().problem.as_deref(), Some("no reply from cell"));
        assert_eq!(r.list.poll_timeout(), Some(RETRY));
        r.now = Duration::from_millis(500);
        r.list.handle_timeout(r.now);
        assert!(call(&r.outputs()).is_none(), "not yet");
        r.now = RETRY;
        r.list.handle_timeout(r.now);
        assert_eq!(call(&r.outputs()), Some(CellCall::Associate));
        let out = r.answer(Err("no reply from cell"));
        assert!(
            !said(&out, "not-associated"),
            "the same refusal is said once"
        );
        r.now = RETRY * 2;
        r.list.handle_timeout(r.now);
        r.outputs();
        // Associated; a delivery the cell refuses is tried again too.
        let out = r.answer(Ok(()));
        assert!(matches!(call(&out), Some(CellCall::Deliver(_))));
        r.answer(Err("disk full at the cell"));
        assert!(r
            .list
            .records()
            .texts()
            .iter()
            .any(|t| t == "disk full at the cell"));
        assert_eq!(r.list.poll_timeout(), Some(RETRY * 3));
        r.now = RETRY * 3;
        r.list.handle_timeout(r.now);
        assert!(matches!(call(&r.outputs()), Some(CellCall::Deliver(_))));
        r.answer(Ok(()));
        let out = r.answer(Ok(()));
        assert!(said(&out, "EVENT cell-ready"));
        assert_eq!(r.list.poll_timeout(), None, "all delivered");
    }

    #[test]
    fn a_change_of_status_is_told_once_and_a_look_is_no_change() {
        let changed = |out: &[Output]| out.iter().filter(|o| matches!(o, Output::Changed)).count();
        let mut r = Rig::new();
        let _ = r.outputs();
        // A station's status: told once, with the rest of what came out.
        let status = VmdStatus {
            logical: falc_model::mms::vmd::LogicalStatus::NoStateChangesAllowed,
            ..VmdStatus::default()
        };
        let publish = |r: &mut Rig| {
            r.publish(Unconfirmed::Status {
                station: st("welding"),
                status: status.clone(),
            })
        };
        assert_eq!(changed(&publish(&mut r)), 1);
        // The same status again, and a console's look: no change.
        assert_eq!(changed(&publish(&mut r)), 0);
        let (_, out) = r.api("console", ApiRequest::Status);
        assert_eq!(changed(&out), 0, "{out:?}");
        // A station gone and an order added: each a change.
        r.list.handle_presence(r.now, st("welding"), false);
        let _ = r.outputs();
        r.list.handle_presence(r.now, st("welding"), true);
        assert_eq!(changed(&r.outputs()), 1);
        let (_, out) = r.api("console", ApiRequest::order_add("dikdroog"));
        assert_eq!(changed(&out), 1, "{out:?}");
    }

    #[test]
    fn a_failed_write_halts_the_running_order_and_no_order_runs_twice() {
        let mut r = Rig::new();
        r.add(2);
        assert!(r.start().is_ok());
        let q = r.question("weld (ja/nee)?");
        r.list.records().failing = true;
        let out = r.publish(Unconfirmed::Report {
            station: st("welding"),
            severity: Severity::Info,
            text: "seam 1 done".into(),
        });
        assert!(said(&out, "EVENT store-error disk full"));
        let out: Vec<&Output> = out
            .iter()
            .filter(|o| !matches!(o, Output::Changed))
            .collect();
        assert!(
            matches!(&out[..], [.., Output::Respond { ticket, result: Err(_) }, Output::Cell(CellCall::Stop { .. })] if *ticket == q),
            "the question refused, the order stopped at the cell: {out:?}"
        );
        let out = r.answer(Ok(()));
        assert!(said(&out, "EVENT order-halted id=1"));
        assert_eq!(
            r.order(1).state,
            OrderState::Running,
            "its end could not be written"
        );
        let s = r.status();
        assert_eq!((s.list, s.running), (ListState::Alarm, None));
        let refused = r.ask("console", ApiRequest::Start);
        assert!(refused.is_err_and(|e| e.contains("cannot be written")));
        // The disk is freed: ack, start; the held end is written first.
        r.list.records().failing = false;
        assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
        assert_eq!(
            r.start(),
            Ok(ApiReply::Done("order 2 (dikdroog) started".into()))
        );
        assert_eq!(r.order(1).state, OrderState::Failed);
        assert!(r
            .list
            .records()
            .texts()
            .iter()
            .any(|t| t.contains("(written late)")));
        let texts = r.list.records().texts();
        for id in [1, 2] {
            let line = format!("order {id} (dikdroog) started");
            let n = texts.iter().filter(|t| **t == line).count();
            assert_eq!(n, 1, "order {id} started once");
        }
    }

    #[test]
    fn an_order_ended_with_danger_leaves_the_alarm_list_once_acknowledged() {
        let mut r = Rig::new();
        r.add(2);
        assert!(r.start().is_ok());
        r.job(JobEvent::FailedDanger);
        let s = r.status();
        assert_eq!(s.list, ListState::Alarm);
        let alarm = s
            .alarms
            .iter()
            .find(|a| a.text.contains("ended with failed_danger"))
            .cloned()
            .unwrap_or_else(|| panic!("{:?}", s.alarms));
        assert!(alarm.blocks_start(), "a safety alarm waits for its ack");
        assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
        let s = r.status();
        assert!(
            !s.alarms.iter().any(|a| a.id == alarm.id),
            "acknowledged, nothing left to clear: {:?}",
            s.alarms
        );
        assert!(r.start().is_ok(), "the way back: ack, start");
        r.job(JobEvent::Done);
        assert_eq!(r.order(2).state, OrderState::Done);
    }

    #[test]
    fn an_ack_the_full_disk_refuses_is_not_taken_and_the_way_back_runs_the_next_order() {
        let mut r = Rig::new();
        r.add(2);
        assert!(r.start().is_ok());
        r.job(JobEvent::FailedDanger);
        r.list.records().failing = true;
        let refused = r.ask("console", ApiRequest::Ack { id: None });
        assert!(
            refused
                .as_ref()
                .is_err_and(|e| e.contains("not acknowledged")),
            "{refused:?}"
        );
        let s = r.status();
        assert!(
            s.alarms
                .iter()
                .any(|a| a.text.contains("failed_danger") && a.acked.is_none()),
            "not acknowledged in the list either: {:?}",
            s.alarms
        );
        assert!(r.ask("console", ApiRequest::Start).is_err());
        // Room again: ack (both alarms), start, the next order done.
        r.list.records().failing = false;
        assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
        assert!(r.status().alarms.is_empty(), "{:?}", r.status().alarms);
        assert!(r.start().is_ok());
        r.job(JobEvent::Done);
        assert_eq!(r.order(2).state, OrderState::Done);
    }

    #[test]
    fn the_last_orders_held_end_is_written_at_the_ack_without_a_start() {
        // Found by falc-sim: the list's last order halted by a full disk
        // stayed `running` in the records, since only a start wrote it.
        let mut r = Rig::new();
        r.add(1);
        assert!(r.start().is_ok());
        r.list.records().failing = true;
        r.publish(Unconfirmed::Report {
            station: st("welding"),
            severity: Severity::Info,
            text: "seam 1 done".into(),
        });
        let out = r.answer(Ok(()));
        assert!(said(&out, "EVENT order-halted id=1"));
        assert_eq!(r.order(1).state, OrderState::Running);
        // Still full: the ack is taken, the end stays held, a new alarm.
        assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
        assert_eq!(r.order(1).state, OrderState::Running);
        assert_eq!(r.status().list, ListState::Alarm);
        // Room again: the ack writes it.
        r.list.records().failing = false;
        assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
        assert_eq!(r.order(1).state, OrderState::Failed);
        let late = r.list.records().texts();
        assert_eq!(
            late.iter().filter(|t| t.contains("(written late)")).count(),
            1,
            "{late:?}"
        );
        assert_eq!(r.status().list, ListState::Idle);
    }

    /// The cell answers the [`CellCall::Ask`] that is out with attributes
    /// (`state`, `last_end`).
    fn attributes(state: PiState, last_end: Option<JobEvent>) -> Result<Response, ServiceError> {
        Ok(Response::PiAttributes(falc_model::mms::pdu::PiAttributes {
            state,
            domains: vec![name("dikdroog")],
            reusable: true,
            deletable: true,
            last_end,
        }))
    }

    /// A cut: order 1 runs with a question waiting, the cell is lost.
    fn cut_mid_order(r: &mut Rig) {
        r.add(2);
        assert!(r.start().is_ok());
        let q = r.question("ok?");
        r.list.handle_abort(r.now, "lease expired");
        let out = r.outputs();
        assert!(out
            .iter()
            .any(|o| matches!(o, Output::Forget(t) if *t == q)));
        assert!(!said(&out, "EVENT order-ended"), "{out:?}");
        assert_eq!(r.order(1).state, OrderState::Running);
        let s = r.status();
        assert_eq!(s.list, ListState::Alarm);
        assert_eq!(
            s.problem.as_deref(),
            Some("no connection with station cell")
        );
        // While the cell is away, the retry associates it, and then asks
        // how the order's run stands before anything else.
        r.now += RETRY;
        r.list.handle_timeout(r.now);
        assert_eq!(call(&r.outputs()), Some(CellCall::Associate));
        let out = r.answer(Ok(()));
        assert_eq!(
            call(&out),
            Some(CellCall::Ask {
                name: name("dikdroog")
            })
        );
        assert!(
            r.status().alarms.iter().all(|a| a.cleared_ms.is_some()),
            "the cell is back"
        );
    }

    #[test]
    fn a_cut_off_cell_s_order_ends_as_the_cell_says_once_it_is_back() {
        let mut r = Rig::new();
        cut_mid_order(&mut r);
        let out = r.tell(attributes(PiState::Idle, Some(JobEvent::Done)));
        assert!(said(&out, "EVENT order-ended id=1 state=done"), "{out:?}");
        assert_eq!(r.order(1).state, OrderState::Done);
        assert_eq!(
            r.order(2).state,
            OrderState::Queued,
            "the list waits for ack"
        );
        assert!(r.list.records().journal.iter().any(|e| e
            .text
            .contains("ended at cell while the connection was lost")));
        // The way back: ack, start; the next order runs once.
        assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
        assert!(r.start().is_ok());
        r.job(JobEvent::Done);
        assert_eq!(r.order(2).state, OrderState::Done);
        let starts = r
            .list
            .records()
            .journal
            .iter()
            .filter(|e| e.text.ends_with(") started"))
            .count();
        assert_eq!(starts, 2, "each order started once");
    }

    #[test]
    fn a_cell_back_on_the_bus_is_associated_at_once() {
        let mut r = Rig::new();
        r.add(1);
        assert!(r.start().is_ok());
        r.list.handle_presence(r.now, st("cell"), true);
        r.outputs();
        r.list.handle_abort(r.now, "lease expired");
        r.list.handle_presence(r.now, st("cell"), false);
        r.outputs();
        r.list.handle_presence(r.now, st("cell"), true);
        assert_eq!(call(&r.outputs()), Some(CellCall::Associate));
    }

    #[test]
    fn a_cut_off_cell_whose_order_still_runs_is_followed_again() {
        let mut r = Rig::new();
        cut_mid_order(&mut r);
        let out = r.tell(attributes(PiState::Running, None));
        assert!(said(&out, "EVENT order-followed id=1"), "{out:?}");
        assert_eq!(r.order(1).state, OrderState::Running);
        // A recipe in use is not delivered again under the running order.
        r.now += RETRY;
        r.list.handle_timeout(r.now);
        assert_eq!(call(&r.outputs()), None);
        r.job(JobEvent::Alarm(falc_model::alarm::Cause::process(
            "robot estop",
        )));
        assert_eq!(r.order(1).state, OrderState::Failed);
        assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
        assert!(r.start().is_ok());
        r.job(JobEvent::Done);
        assert_eq!(r.order(2).state, OrderState::Done);
    }

    #[test]
    fn a_cell_that_restarted_while_cut_off_kept_no_end_and_the_order_is_interrupted() {
        let mut r = Rig::new();
        cut_mid_order(&mut r);
        let unknown = ServiceError::undefined("program invocation dikdroog is not defined");
        let out = r.tell(Err(unknown));
        assert!(
            said(&out, "EVENT order-ended id=1 state=interrupted"),
            "{out:?}"
        );
        // Recipes go to the restarted cell again, then the way back.
        assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
        assert!(r.start().is_ok());
        r.job(JobEvent::Done);
        assert_eq!(r.order(2).state, OrderState::Done);
        assert_eq!(r.order(1).state, OrderState::Interrupted);
    }

    #[test]
    fn a_start_that_was_never_confirmed_is_queued_again_only_if_the_cell_never_began_it() {
        for began in [false, true] {
            let mut r = Rig::new();
            r.add(1);
            let t = r.start_until_the_cells_start();
            let out = r.no_reply();
            assert!(reply(&out, t).is_some_and(|a| a.is_err()), "{out:?}");
            assert_eq!(
                r.order(1).state,
                OrderState::Running,
                "not queued again yet"
            );
            r.now += RETRY;
            r.list.handle_timeout(r.now);
            assert_eq!(call(&r.outputs()), Some(CellCall::Associate));
            assert!(matches!(
                call(&r.answer(Ok(()))),
                Some(CellCall::Ask { .. })
            ));
            let answer = if began {
                attributes(PiState::Idle, Some(JobEvent::Done))
            } else {
                attributes(PiState::Idle, None)
            };
            r.tell(answer);
            let expected = if began {
                OrderState::Done
            } else {
                OrderState::Queued
            };
            assert_eq!(r.order(1).state, expected, "began: {began}");
        }
    }

    #[test]
    fn an_order_running_when_the_operator_stopped_is_adopted_and_asked_for() {
        let mut r = Rig::new();
        r.add(1);
        assert!(r.start().is_ok());
        let order = r.order(1);
        let records = std::mem::take(r.list.records());
        let topology = Topology::parse(TOPOLOGY, "test").expect("topology");
        let mut list = OrderList::new(
            st("operator"),
            st("cell"),
            topology,
            records,
            Source::default(),
            set(),
        )
        .adopting(order);
        list.handle_timeout(Duration::ZERO);
        let out: Vec<Output> = std::iter::from_fn(|| list.poll_output()).collect();
        assert_eq!(call(&out), Some(CellCall::Associate));
        list.handle_cell_reply(Duration::ZERO, Ok(()));
        let out: Vec<Output> = std::iter::from_fn(|| list.poll_output()).collect();
        assert!(matches!(call(&out), Some(CellCall::Ask { .. })), "{out:?}");
        list.handle_cell_answer(
            Duration::ZERO,
            attributes(PiState::Idle, Some(JobEvent::Done)),
        );
        let out: Vec<Output> = std::iter::from_fn(|| list.poll_output()).collect();
        assert!(said(&out, "EVENT order-ended id=1 state=done"), "{out:?}");
    }

    #[test]
    fn a_job_event_before_the_start_is_confirmed_is_kept_for_it() {
        let mut r = Rig::new();
        r.add(1);
        let t = r.start_until_the_cells_start();
        let early = r.job(JobEvent::Alarm(Cause::new(
            AlarmClass::Process,
            "alarm in state 2",
        )));
        assert!(early.is_empty(), "{early:?}");
        let out = r.answer(Ok(()));
        assert!(reply(&out, t).is_some_and(|r| r.is_ok()));
        assert!(said(&out, "EVENT order-ended id=1 state=failed"));
        assert_eq!(r.order(1).state, OrderState::Failed);
    }

    #[test]
    fn messages_before_the_start_is_confirmed_are_journalled_after_it() {
        let mut r = Rig::new();
        r.add(1);
        let t = r.start_until_the_cells_start();
        // The cell runs the recipe before its Start confirm arrives: its
        // first output, a step-mode report and a question come first.
        let o = r.ticket();
        let lines = vec!["lassen begint".to_string()];
        r.list
            .handle_cell_request(r.now, o, Request::Output { lines });
        let answered = r.outputs();
        assert!(
            answered
                .iter()
                .any(|x| matches!(x, Output::Respond { ticket, result: Ok(_) } if *ticket == o)),
            "the output is answered at once: {answered:?}"
        );
        r.publish(Unconfirmed::Report {
            station: st("cell"),
            severity: Severity::Info,
            text: "state 1 waits".into(),
        });
        let q = r.question("verder?");
        let out = r.answer(Ok(()));
        assert!(reply(&out, t).is_some_and(|r| r.is_ok()));
        let journal = r
            .list
            .records()
            .entries(&EntryQuery::page(0, 100))
            .expect("journal");
        let started = journal
            .iter()
            .position(|e| e.text.contains("order 1 (dikdroog) started"))
            .expect("the start is journalled");
        for text in ["lassen begint", "state 1 waits", "verder?"] {
            let at = journal
                .iter()
                .position(|e| e.text == text)
                .unwrap_or_else(|| panic!("{text} not journalled: {journal:?}"));
            assert!(at > started, "{text} before the start: {journal:?}");
            assert_eq!(journal[at].order, Some(1), "{text} without its order");
        }
        // The question still waits for its answer.
        let (a, out) = r.api("console", ApiRequest::Answer { text: "ja".into() });
        assert!(reply(&out, a).is_some_and(|r| r.is_ok()), "{out:?}");
        assert!(out
            .iter()
            .any(|x| matches!(x, Output::Respond { ticket, .. } if *ticket == q)));
    }

    #[test]
    fn stop_ends_the_order_and_roles_are_checked_again() {
        let mut r = Rig::new();
        r.add(1);
        let refused = r.ask("observer", ApiRequest::Start);
        assert!(refused.is_err_and(|e| e.contains("needs")));
        assert!(r.ask("mallory", ApiRequest::Status).is_err());
        assert!(r.start().is_ok());
        let (t, out) = r.api("console", ApiRequest::Stop);
        assert_eq!(
            call(&out),
            Some(CellCall::Stop {
                name: name("dikdroog")
            })
        );
        assert_eq!(r.status().running, None);
        let out = r.answer(Err("no reply from cell"));
        let Some(Ok(ApiReply::Done(text))) = reply(&out, t) else {
            panic!("{out:?}")
        };
        assert!(text.contains("the cell did not confirm the stop"), "{text}");
        assert_eq!(r.order(1).state, OrderState::Stopped);
        // A late end of the stopped job changes nothing.
        assert!(r.job(JobEvent::Done).is_empty());
        assert_eq!(r.order(1).state, OrderState::Stopped);
    }

    #[test]
    fn a_stopped_order_resumes_at_the_cell_and_a_refused_restart_leaves_it_as_it_was() {
        let mut r = Rig::new();
        r.add(2);
        assert!(r.start().is_ok());
        let (_, _) = r.api("console", ApiRequest::Stop);
        r.answer(Ok(()));
        assert_eq!(r.order(1).state, OrderState::Stopped);
        let restart = |order, from| ApiRequest::Restart { order, from };
        // Without --from, a stopped order resumes where it stopped.
        let (t, out) = r.api("console", restart(1, None));
        assert_eq!(
            call(&out),
            Some(CellCall::Pass(Request::Resume {
                name: name("dikdroog")
            }))
        );
        assert_eq!(r.order(1).state, OrderState::Running);
        // The cell refuses: back to stopped, never queued (it ran).
        let out = r.answer(Err("Resume refused"));
        assert!(reply(&out, t).is_some_and(|r| r.is_err()), "{out:?}");
        assert_eq!(r.order(1).state, OrderState::Stopped);
        assert_eq!(r.order(2).state, OrderState::Queued);
        // From a state: the recipe must have it.
        let e = r.ask("console", restart(1, Some(9))).unwrap_err();
        assert!(e.contains("dikdroog has no state 9"), "{e}");
        let e = r.ask("console", restart(2, None)).unwrap_err();
        assert!(e.contains("order 2 is queued: falc start runs it"), "{e}");
        let e = r.ask("console", restart(7, None)).unwrap_err();
        assert!(e.contains("there is no order 7"), "{e}");
        let e = r.ask("observer", restart(1, None)).unwrap_err();
        assert!(e.contains("needs Operator"), "{e}");
    }

    #[test]
    fn modes_pass_to_the_cell_and_maintenance_waits_until_no_order_runs() {
        let mut r = Rig::new();
        r.add(1);
        assert!(r.start().is_ok());
        let mode = |mode, stations: Vec<&str>| ApiRequest::Mode {
            mode,
            stations: stations.into_iter().map(st).collect(),
        };
        let e = r
            .ask("console", mode(CellMode::Maintenance, vec![]))
            .unwrap_err();
        assert!(e.contains("only when no order runs"), "{e}");
        let e = r
            .ask("console", mode(CellMode::Auto, vec!["welding"]))
            .unwrap_err();
        assert!(e.contains("only in step mode"), "{e}");
        let e = r
            .ask("console", mode(CellMode::Step, vec!["operator"]))
            .unwrap_err();
        assert!(e.contains("operator is not a workstation of cell"), "{e}");
        let e = r
            .ask("console", mode(CellMode::Step, vec!["welding"; 5000]))
            .unwrap_err();
        assert!(e.contains("welding is named more than once"), "{e}");
        assert!(e.len() < 100, "{e}");
        let (t, out) = r.api("console", mode(CellMode::Step, vec!["welding"]));
        assert_eq!(
            call(&out),
            Some(CellCall::Pass(Request::Mode(ModeSetting {
                mode: CellMode::Step,
                stepping: vec![st("cell"), st("welding")],
            })))
        );
        let out = r.answer(Ok(()));
        let Some(Ok(ApiReply::Done(text))) = reply(&out, t) else {
            panic!("{out:?}")
        };
        assert_eq!(text, "mode step (cell, welding)");
        let journal = &r.list.records().journal;
        assert!(journal
            .iter()
            .any(|e| e.who == "console" && e.text == "mode step (cell, welding)"));
        // A manual operation is the maintainer's, passed on as it is.
        let manual = ApiRequest::Manual {
            station: st("transport"),
            action: falc_model::mode::ManualAction::Press("A".into()),
        };
        let e = r.ask("console", manual.clone()).unwrap_err();
        assert!(e.contains("needs Maintainer"), "{e}");
        let (_, out) = r.api("maintainer", manual);
        assert!(matches!(
            call(&out),
            Some(CellCall::Pass(Request::Manual { by, .. })) if by == "maintainer"
        ));
    }

    #[test]
    fn a_defective_recipe_set_refuses_the_start_and_delivers_nothing() {
        let mut r = Rig::new();
        r.add(1);
        r.list.source.broken = true;
        let (t, out) = r.api("console", ApiRequest::Start);
        assert!(call(&out).is_none(), "nothing delivered");
        let e = reply(&out, t).and_then(|r| r.err()).unwrap_or_default();
        assert!(e.contains("cell/dikdroog.rcp:3: unknown state 9"), "{e}");
        assert_eq!(r.order(1).state, OrderState::Queued);
    }

    #[test]
    fn the_list_takes_at_most_its_limit_of_waiting_orders() {
        let mut r = Rig::new();
        r.list = std::mem::replace(&mut r.list, Rig::new().list).with_max_queued(2);
        r.add(2);
        let e = r
            .ask("console", ApiRequest::order_add("dikdroog"))
            .unwrap_err();
        assert!(e.contains("holds 2 queued orders, its limit"), "{e}");
        assert_eq!(r.list.db.orders().map(|o| o.len()), Ok(2));
        // Removing one makes room.
        assert!(r.ask("console", ApiRequest::OrderRemove { id: 1 }).is_ok());
        r.add(1);
    }

    /// `order add` with a count, a priority, a due time and a cell: the
    /// orders added and journalled; the start takes the highest priority,
    /// then the one due first; a cell the list does not run on, and more
    /// than the limit holds, are refused with nothing added.
    #[test]
    fn placed_orders_run_by_priority_and_due_time_and_a_foreign_cell_is_refused() {
        use falc_model::console::Placement;
        use falc_model::ids::CellId;
        let mut r = Rig::new();
        r.list = std::mem::replace(&mut r.list, Rig::new().list).with_max_queued(6);
        let add = |priority: i32, due_ms: Option<i64>, cell: Option<&str>, count: u16| {
            ApiRequest::OrderAdd {
                recipe: "dikdroog".into(),
                placement: Placement {
                    cell: cell.map(|c| CellId::new(c).expect("id")),
                    priority,
                    due_ms,
                },
                count,
            }
        };
        let three = r.ask("console", add(0, None, None, 3));
        assert!(
            matches!(&three, Ok(ApiReply::Orders(v)) if v.iter().map(|o| o.id).eq(1..=3)),
            "{three:?}"
        );
        let due = r.ask("console", add(0, Some(1_795_611_600_000), Some("falc1"), 1));
        assert!(
            matches!(&due, Ok(ApiReply::Order(o)) if o.id == 4),
            "{due:?}"
        );
        let urgent = r.ask("console", add(5, None, None, 1));
        assert!(
            matches!(&urgent, Ok(ApiReply::Order(o)) if o.id == 5),
            "{urgent:?}"
        );
        let texts = r.list.db.texts();
        assert!(
            texts
                .iter()
                .any(|t| t == "added order 4 (dikdroog, due 2026-11-25 13:00 UTC, for falc1)"),
            "{texts:?}"
        );
        assert!(texts
            .iter()
            .any(|t| t == "added order 5 (dikdroog, priority 5)"));
        let e = r
            .ask("console", add(0, None, Some("falc2"), 1))
            .unwrap_err();
        assert!(e.contains("there is no cell falc2"), "{e}");
        let e = r.ask("console", add(0, None, None, 2)).unwrap_err();
        assert!(e.contains("2 more do not fit"), "{e}");
        assert_eq!(
            r.list.db.orders().map(|o| o.len()),
            Ok(5),
            "none of them added"
        );
        assert!(r.start().is_ok());
        let running = r.status().running.map(|o| (o.id, o.cell));
        assert_eq!(
            running,
            Some((5, Some("falc1".into()))),
            "the urgent one first"
        );
        assert_eq!(r.order(4).state, OrderState::Queued);
    }

    #[test]
    fn a_manual_operation_with_a_huge_argument_is_refused_with_a_quote() {
        use falc_model::mode::ManualAction;
        let mut r = Rig::new();
        let e = r
            .ask(
                "maintainer",
                ApiRequest::Manual {
                    station: st("transport"),
                    action: ManualAction::Press("A".repeat(60_000)),
                },
            )
            .unwrap_err();
        assert!(e.contains("60000 characters") && e.len() < 200, "{e}");
        assert!(
            r.list.db.texts().iter().all(|t| t.len() < 200),
            "nothing of it journalled"
        );
    }

    #[test]
    fn a_workstation_lost_while_idle_is_an_alarm_that_clears_when_it_returns() {
        let mut r = Rig::new();
        r.list.handle_presence(r.now, st("welding"), true);
        r.list.handle_presence(r.now, st("welding"), false);
        let s = r.status();
        let lost: Vec<_> = s
            .alarms
            .iter()
            .filter(|a| a.station == "welding" && a.class == AlarmClass::Communication)
            .collect();
        assert_eq!(lost.len(), 1, "{:?}", s.alarms);
        assert_eq!(lost[0].text, "no connection with station welding");
        assert_eq!(s.list, ListState::Alarm, "start waits for the ack");
        // The cell passing the same loss on, still listed: both clear when
        // welding is back; a station named alike is not welding.
        r.list.handle_publication(
            r.now,
            Unconfirmed::Report {
                station: st("cell"),
                severity: Severity::Alarm(AlarmClass::Communication),
                text: "alarm in state 13: no connection with station WELDING".into(),
            },
        );
        r.list.handle_presence(r.now, st("welding2"), true);
        assert!(r.status().alarms.iter().all(|a| a.cleared_ms.is_none()));
        r.list.handle_presence(r.now, st("welding"), true);
        let s = r.status();
        assert_eq!(s.alarms.len(), 2, "{:?}", s.alarms);
        assert!(
            s.alarms.iter().all(|a| a.cleared_ms.is_some()),
            "{:?}",
            s.alarms
        );
        assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
        assert!(r.status().alarms.is_empty(), "acknowledged and cleared");
        // The cell is no workstation: its loss is the association's alarm.
        r.list.handle_presence(r.now, st("cell"), false);
        assert!(r.status().alarms.is_empty());
    }

    #[test]
    fn what_the_cell_shows_and_asks_is_bounded() {
        let mut r = Rig::new();
        r.add(1);
        assert!(r.start().is_ok());
        let output = |r: &mut Rig, lines: Vec<String>| {
            let t = r.ticket();
            r.list
                .handle_cell_request(r.now, t, Request::Output { lines });
            r.outputs().into_iter().find_map(|o| match o {
                Output::Respond { ticket, result } if ticket == t => Some(result),
                _ => None,
            })
        };
        let many = output(&mut r, vec!["x".into(); MAX_OUTPUT_LINES + 1]);
        assert!(
            matches!(&many, Some(Err(e)) if e.to_string().contains("at most 100")),
            "{many:?}"
        );
        let long = output(&mut r, vec!["y".repeat(MAX_OUTPUT_CHARS + 1)]);
        let Some(Err(e)) = long else {
            panic!("{long:?}")
        };
        assert!(e.to_string().len() < 300, "quoted short: {e}");
        // 30 lines, then a question: it carries the newest 20, the
        // journal all 30.
        for i in 0..30 {
            assert_eq!(
                output(&mut r, vec![format!("line {i}")]),
                Some(Ok(Response::Done))
            );
        }
        r.question("ok?");
        let q = r.status().question.expect("a question");
        assert_eq!(q.lines().count(), QUESTION_WINDOW_LINES + 1, "{q}");
        assert!(q.starts_with("line 10\n") && q.ends_with("ok?"), "{q}");
        let journalled = r.list.db.texts();
        assert!(
            journalled.iter().any(|t| t.contains("line 0")),
            "{journalled:?}"
        );
        let huge = r.ticket();
        r.list.handle_cell_request(
            r.now,
            huge,
            Request::Input {
                prompt: "z".repeat(MAX_OUTPUT_CHARS + 1),
                timeout_s: None,
            },
        );
        assert!(r
            .outputs()
            .iter()
            .any(|o| matches!(o, Output::Respond { ticket, result: Err(_) } if *ticket == huge)));
        assert!(r.status().question.is_some_and(|q| q.ends_with("ok?")));
    }

    #[test]
    fn a_workstation_back_on_the_bus_is_associated_again_through_the_cell() {
        let mut r = Rig::new();
        r.add(1);
        assert!(r.start().is_ok());
        r.job(JobEvent::Done);
        // Its first appearance (the cell associated): the cell is
        // initiated again, harmlessly.
        r.list.handle_presence(r.now, st("transport"), true);
        assert_eq!(call(&r.outputs()), Some(CellCall::Initiate));
        r.answer(Ok(()));
        r.list.handle_presence(r.now, st("transport"), false);
        r.list.handle_presence(r.now, st("transport"), true);
        let out = r.outputs();
        assert_eq!(call(&out), Some(CellCall::Initiate), "{out:?}");
        let out = r.answer(Ok(()));
        assert!(said(&out, "EVENT rejoined station=transport"), "{out:?}");
    }
}
