//! The operator's order list, sans-I/O (the quinn-proto style): the order
//! list worked through the cell, operator communication (the cell's
//! `output` and `input`), alarms and their acknowledgement, recipe delivery
//! and the answers to the operator API.
//!
//! Events come in with the time they happen (`handle_*`); what the node
//! must do comes out of [`OrderList::poll_output`]: one request to the cell
//! at a time ([`CellCall`], answered with [`OrderList::handle_cell_answer`]),
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
//!
//! Here: the list's state, its outputs and the journal and alarm helpers
//! every part uses. By concern: `lane` (the cell lane's sequencing: jobs,
//! connection, starts, ends, stops, the cell's answers), `questions` (the
//! cell's `input` and `output`), `reports` (what the stations publish and
//! their presence), `replay` (reports read again after a cut), `restart` (restart planning, held order ends), `api`
//! (the operator API's dispatch); `tests` drives it all on a virtual clock.

use crate::alarm_list::{AlarmList, Raised};
use crate::recipe_source::{Delivery, PutError, RecipeSet, RecipeSource};
use crate::records::{EntryQuery, Records};
use falc_model::alarm::{Alarm, AlarmClass};
use falc_model::api::{
    ApiReply, ApiRequest, ApiResult, CellStatus, ListState, Placement, StationView,
    MAX_OUTPUT_CHARS, MAX_OUTPUT_LINES, MAX_QUEUED_ORDERS, QUESTION_WINDOW_LINES,
};
use falc_model::ids::{CellId, ObjectName, StationName};
use falc_model::mms::domain::content_hash;
use falc_model::mms::error::{ErrorClass, ServiceError};
use falc_model::mms::pdu::{JobEvent, Peer, Request, Response, Severity, Unconfirmed};
use falc_model::mms::program::PiState;
use falc_model::mms::vmd::{PhysicalStatus, VmdStatus};
use falc_model::mode::{CellMode, ModeSetting};
use falc_model::product::{RecipeVersion, UsedRecipe};
use falc_model::recipe_file::RecipeFile;
use falc_model::records::{EntryKind, Order, OrderState};
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
/// through [`OrderList::handle_cell_answer`].
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
    /// Read what `station` kept after its report number `after`: the
    /// answer comes back through [`OrderList::handle_kept_reports`].
    ReadReports {
        /// Whose reports.
        station: StationName,
        /// The last number filed.
        after: u64,
    },
}

/// A question the cell asked, waiting for `answer`.
#[derive(Debug)]
struct Question {
    prompt: String,
    ticket: Ticket,
}

/// The cell's lines to the operator since its last question, and the
/// question waiting. Its rules: at most one question waits (a newer one
/// replaces it, handed back to be refused); the lines kept are the newest
/// [`QUESTION_WINDOW_LINES`] (the journal has them all), and go with the
/// next question.
#[derive(Debug, Default)]
struct Questions {
    waiting: Option<Question>,
    shown: Vec<String>,
}

impl Questions {
    /// Lines the cell showed.
    fn show(&mut self, lines: Vec<String>) {
        self.shown.extend(lines);
        let over = self.shown.len().saturating_sub(QUESTION_WINDOW_LINES);
        self.shown.drain(..over);
    }

    /// The cell asks `prompt` (answered under `ticket`): the lines shown
    /// since the last question go with it. The question it replaces, if
    /// one waited.
    fn ask(&mut self, prompt: &str, ticket: Ticket) -> Option<Question> {
        let mut text = self.shown.join("\n");
        if !text.is_empty() {
            text.push('\n');
        }
        text.push_str(prompt);
        self.shown.clear();
        self.waiting.replace(Question {
            prompt: text,
            ticket,
        })
    }

    /// The question waiting, taken (answered, refused or dropped).
    fn take(&mut self) -> Option<Question> {
        self.waiting.take()
    }

    /// What the waiting question shows, with the lines before it.
    fn prompt(&self) -> Option<&str> {
        self.waiting.as_ref().map(|q| q.prompt.as_str())
    }

    /// A new order starts: what the last one showed goes with no question
    /// of this one.
    fn new_order(&mut self) {
        self.shown.clear();
    }
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
    /// The cell initiated again (what it lost below associated again)
    /// before a start or the deliveries.
    Initiating(Option<Caller>),
    Starting {
        order: Order,
        started_ms: i64,
        by: Option<Caller>,
        /// A restarted order as it was: what a refusal puts back (never
        /// the queue: it ran before).
        previous: Option<Box<Order>>,
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
    /// Whether the list works, as last kept in the records.
    recorded_working: Option<bool>,
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
    /// The cell's lines since its last question, and the question waiting.
    questions: Questions,
    shutdown_pending: bool,
    /// The wall time (ms since the Unix epoch) at `now` = 0: what the
    /// records are stamped with ([`Self::clocked_from`]).
    origin_ms: i64,
    statuses: BTreeMap<StationName, VmdStatus>,
    /// The stations on the bus now.
    present: BTreeSet<StationName>,
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
    /// The consoles' answers, in order ([`Self::poll_reply`]).
    replies: VecDeque<(Ticket, ApiResult)>,
    /// The status as last told by [`Output::Changed`].
    told: Option<CellStatus>,
    /// Whether the status may differ from the one told: something
    /// happened to this list since (computing it reads the records). What
    /// another cell's list changes in the records all share (the plant's
    /// queue and journal) makes no list compute its status again: the
    /// changing list tells [`Output::Changed`], and that word is the
    /// plant's (a console then asks every cell's status afresh).
    stale: bool,
    /// What the list has of each station's numbered reports.
    heard: BTreeMap<StationName, replay::Heard>,
    /// Filing a replayed report made at this time (ms since the Unix
    /// epoch): its entries get that time and are marked.
    replaying: Option<i64>,
}

/// How an order was placed, for its journal line (`, priority 5, for
/// falc2`), empty for the default.
fn placed(order: &Order) -> String {
    let mut v = Vec::new();
    if order.priority != 0 {
        v.push(format!("priority {}", order.priority));
    }
    if let Some(due) = order.due_ms {
        v.push(format!("due {}", falc_model::time::utc_text(due)));
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
        let heard = replay::kept_filed(&db);
        // Alarms that cannot be read are not silently gone: the list
        // starts with an alarm saying so, which holds the cell until it
        // is acknowledged.
        let (alarms, unread) = match AlarmList::load(&db) {
            Ok(l) => (l, None),
            Err(e) => (AlarmList::default(), Some(e.to_string())),
        };
        let list = Self {
            me,
            cell,
            topology,
            db,
            source,
            hashes: hashes_of(&recipes),
            versions: BTreeMap::new(),
            recorded_mode: None,
            recorded_working: None,
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
            questions: Questions::default(),
            shutdown_pending: false,
            origin_ms: 0,
            statuses: BTreeMap::new(),
            present: BTreeSet::new(),
            unwritten_ends: Vec::new(),
            last_ended: None,
            busy: None,
            jobs: VecDeque::new(),
            early: Vec::new(),
            next_try: Duration::ZERO,
            out: VecDeque::new(),
            replies: VecDeque::new(),
            told: None,
            stale: true,
            heard,
            replaying: None,
        }
        .versioned();
        match unread {
            Some(why) => list.alarms_unread(&why),
            None => list,
        }
    }

    /// The records' alarms could not be read (`why`): said, and raised as
    /// an alarm of the operator's own that holds the cell until someone
    /// acknowledged it, since an alarm raised before this start may be
    /// among them.
    fn alarms_unread(mut self, why: &str) -> Self {
        let text = format!(
            "the alarm list could not be read from the records ({why}): an alarm raised \
             before this start may not be shown; mend the records and start the operator \
             again, or acknowledge this to go on without them"
        );
        tracing::error!("{text}");
        let me = self.me.clone();
        self.raise(&me, None, AlarmClass::Device, text);
        self
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
        // The recipes by domain, then the robot programs (by file alone).
        let files: Vec<(RecipeFile, String, Option<ObjectName>)> = self
            .recipes
            .deliveries
            .iter()
            .map(|d| {
                let text = String::from_utf8_lossy(&d.content).into_owned();
                (d.file.clone(), text, Some(d.domain.clone()))
            })
            .chain(
                self.recipes
                    .programs
                    .iter()
                    .map(|r| (r.file.clone(), r.program.text.clone(), None)),
            )
            .collect();
        for (file, text, domain) in files {
            let me = self.me.to_string();
            match self
                .db
                .add_version(&file, &text, &me, "found in the recipe store")
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
                    if let Some(domain) = domain {
                        versions.insert(domain, v);
                    }
                }
                Err(e) => return self.db_failed(&e),
            }
        }
        self.versions = versions;
    }

    /// The recipe versions an order of cell recipe `recipe` runs: the
    /// cell recipe, each workstation recipe it starts, and the robot
    /// programs those start (where the store delivers them).
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
        // The cell recipe, each workstation recipe it starts, then each
        // robot program those start, each once.
        let mut out = vec![cell];
        let mut at = 0;
        while at < out.len() {
            let more: Vec<UsedRecipe> = out[at]
                .starts
                .iter()
                .filter(|s| !out.iter().any(|u| &u.domain == *s))
                .filter_map(|s| used(s))
                .collect();
            for u in more {
                if !out.iter().any(|o| o.domain == u.domain) {
                    out.push(u);
                }
            }
            at += 1;
        }
        out
    }

    /// Takes over `order`, which was running on this cell when this node
    /// stopped (the records still say `running`): the cell may have run it
    /// on, so it is asked how the run stands once it is associated.
    pub fn adopting(mut self, order: Order) -> Self {
        self.running = Some(order);
        self.away = Some(Away::Running);
        self
    }

    /// The wall time, in ms since the Unix epoch, at `now` = 0 of the
    /// clock its driver gives it (0 unless given): the list's records are
    /// stamped by that one clock (`falc-operator`: the system's time at its
    /// start; `falc-sim`: its virtual clock from a fixed day).
    pub fn clocked_from(mut self, origin_ms: i64) -> Self {
        self.origin_ms = origin_ms;
        self
    }

    /// Gives the records the time `now` is on the wall clock, and marks
    /// the status to be computed again: called first by every entry that
    /// has a `now`.
    pub(super) fn tick(&mut self, now: Duration) {
        self.stale = true;
        let ms = i64::try_from(now.as_millis()).unwrap_or(i64::MAX);
        self.db.set_now(self.origin_ms.saturating_add(ms));
    }

    /// At most `max` orders wait in the list; one more is refused.
    pub fn with_max_queued(mut self, max: usize) -> Self {
        self.max_queued = max;
        self
    }

    /// The next console's answer (the answers are the plant's to carry:
    /// a request of several cells is answered once all are in).
    pub fn poll_reply(&mut self) -> Option<(Ticket, ApiResult)> {
        self.replies.pop_front()
    }

    /// The next thing the node must do. When nothing else is left and
    /// something happened since the status was last computed, an
    /// [`Output::Changed`] if the status differs from the one last told.
    pub fn poll_output(&mut self) -> Option<Output> {
        if let Some(out) = self.out.pop_front() {
            return Some(out);
        }
        if !self.stale {
            return None;
        }
        let now = self.status().ok()?;
        self.stale = false;
        if self.told.as_ref() == Some(&now) {
            return None;
        }
        // Each station's recipe state as it changes, for the log.
        for v in &now.stations {
            let state = |s: &CellStatus| {
                s.stations
                    .iter()
                    .find(|w| w.name == v.name)
                    .and_then(|w| w.status.as_ref())
                    .map(|st| st.local_detail)
            };
            let after = v.status.as_ref().map(|st| st.local_detail);
            if let Some(after) = after.filter(|a| self.told.as_ref().and_then(state) != Some(*a)) {
                let line = format!("EVENT recipe-state station={} state={after}", v.name);
                self.out.push_back(Output::Say(line));
            }
        }
        self.told = Some(now);
        Some(Output::Changed)
    }

    /// When to call [`Self::handle_timeout`]: the next attempt to
    /// associate the cell or deliver to it, while it is needed.
    pub fn poll_timeout(&self) -> Option<Duration> {
        let idle = self.busy.is_none() && self.jobs.is_empty();
        let deliver = self.running.is_none() && self.undelivered().next().is_some();
        let retry = (idle && (!self.associated || deliver)).then_some(self.next_try);
        match (retry, self.read_again_at()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// The time of [`Self::poll_timeout`] has come: try the cell again.
    pub fn handle_timeout(&mut self, now: Duration) {
        self.tick(now);
        self.read_again(now);
        let idle = self.busy.is_none() && self.jobs.is_empty();
        let deliver = self.running.is_none() && self.undelivered().next().is_some();
        if idle && (!self.associated || deliver) && self.next_try <= now {
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
        self.replies.push_back((ticket, result));
    }

    fn call(&mut self, call: CellCall, busy: Busy) {
        self.out.push_back(Output::Cell(call));
        self.busy = Some(busy);
    }

    /// Journals; a failure to write stops the list (`db_failed`).
    pub fn journal(&mut self, kind: EntryKind, order: Option<i64>, who: &str, text: &str) {
        self.stale = true;
        let written = match self.replaying {
            None => self.db.journal(kind, order, who, text),
            Some(at) => {
                let text = format!("{text}{}", replay::REPLAYED);
                self.db.journal_at(at, kind, order, who, &text)
            }
        };
        match written {
            Ok(e) => self.say(format!(
                "JOURNAL {} {} {who}: {}",
                e.id,
                kind.as_str(),
                e.text.replace('\n', " / ")
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
        let me = self.me.clone();
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
    fn raise_alarm(
        &mut self,
        station: &StationName,
        class: AlarmClass,
        text: &str,
        order: Option<i64>,
    ) {
        let (raised, error) = self.alarms.raise(&mut self.db, station, class, text, order);
        self.raised(raised, class);
        if let Some(e) = error {
            self.db_failed(&e);
        }
    }

    /// Raises an alarm of `station` that this node journals (a station's
    /// own reports are journalled as they come), under `order` (the order
    /// that failed, which no longer runs by now).
    fn raise(
        &mut self,
        station: &StationName,
        order: Option<i64>,
        class: AlarmClass,
        text: String,
    ) {
        self.raise_alarm(station, class, &text, order);
        self.journal(EntryKind::Alarm, order, station.as_str(), &text);
    }

    /// Clears the alarms of `station` whose condition is gone, from its
    /// latest status and presence.
    fn settle_alarms(&mut self, station: &StationName) {
        let status = self.statuses.get(station);
        let present = self.present.contains(station);
        let (cleared, error) = self.alarms.settle(&mut self.db, station, status, present);
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

    /// Begins the waiting jobs while no call to the cell is out.
    fn pump(&mut self, now: Duration) {
        while self.busy.is_none() {
            let Some(job) = self.jobs.pop_front() else {
                break;
            };
            self.begin(now, job);
        }
        self.note_working();
    }

    /// Keeps in the records whether the list works, when that changed:
    /// running, or held by an alarm that stopped it while it ran (without
    /// a shift calendar the figures plan the cell busy while it worked).
    fn note_working(&mut self) {
        let held = self.alarms.blocking().is_some() && self.recorded_working == Some(true);
        let working = self.list == ListState::Running || held;
        if self.recorded_working == Some(working) {
            return;
        }
        match self.db.record_working(working) {
            Ok(()) => self.recorded_working = Some(working),
            Err(e) => self.db_failed(&e),
        }
    }
}

mod api;
mod lane;
mod questions;
mod replay;
mod reports;
mod restart;
#[cfg(test)]
mod tests;
