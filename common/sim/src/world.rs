//! A cell, or a plant of cells, wired together on one virtual clock: the
//! operator's plant of order lists (records in memory), and in each cell
//! the cell controller, both workstations with their devices, the robot
//! controller's twin behind a serial line with the 3964R procedure at both
//! ends, and the conveyor's twin behind the I/O map. Every core is the one
//! the nodes run; this module is their driver, as `falc_node` is on the
//! real bus.
//!
//! [`World::step`] advances the clock to the next thing due and handles
//! everything due then; what the cores put out is carried to where it
//! goes at once (and arrives after the bus's latency).

use crate::bus::{Arrival, Bus, Link, Msg, Node, Role};
use crate::cell::{Action, CellParts, Settled, Workstation};
use crate::recipes::Recipes;
use falc_control::cell_node::CellAction;
use falc_control::coordination::{workstation_domain, Awaiting, Reply};
use falc_control::pass_on::PASS_LIMIT;
use falc_dnc::procedure::Timing;
use falc_factory::order_list::{CellCall, OrderList, Output as ListOutput, Ticket, CELL_LIMIT};
use falc_factory::plant::{Plant, PlantOutput};
use falc_factory::recipe_source::{RecipeSet, RecipeSource};
use falc_factory::records::memory::Memory;
use falc_factory::records::shared::{plant, Shared};
use falc_factory::records::Records;
use falc_model::api::{ApiRequest, ApiResult};
use falc_model::ids::{CellId, ObjectName, StationName};
use falc_model::mms::delivery::{Delivery, DeliveryStep, STEP_LIMIT};
use falc_model::mms::domain::{content_hash, DomainState};
use falc_model::mms::error::ServiceError;
use falc_model::mms::heard;
use falc_model::mms::journal::{Publication, ReportLog, ReportsAsked};
use falc_model::mms::pdu::{Peer, Request, Response, Unconfirmed};
use falc_model::mms::serving::{Action as Serve, Serving};
use falc_model::mms::vmd::RECIPE_MEMORY;
use falc_model::plant::Layout;
use falc_model::topology::Topology;
use rand::rngs::StdRng;
use rand::SeedableRng;
use std::cell::RefCell;
use std::collections::{BTreeMap, VecDeque};
use std::path::Path;
use std::rc::Rc;
use std::time::Duration;

/// The shipped topology: operator, cell, welding, transport.
const TOPOLOGY: &str = include_str!("../../../launch/cell.toml");

/// The shipped cell (`launch/cell.toml`), a plant of one.
pub fn shipped_cell() -> Result<Layout, String> {
    Topology::parse(TOPOLOGY, "launch/cell.toml")
        .map(Layout::Cell)
        .map_err(|e| e.to_string())
}
/// The wall time the virtual clock starts at (2026-01-01 00:00 UTC): the
/// records are stamped with it plus the virtual time.
pub const EPOCH_MS: i64 = 1_767_225_600_000;
/// At most this many lines of the trace are kept.
const TRACE: usize = 400;

/// A request out, waiting for its confirm.
#[derive(Debug)]
struct Pending {
    to: Node,
    deadline: Duration,
    waiter: Waiter,
    /// Sent by or to a node parted from the router: no route, no reply.
    parted: bool,
}

/// Who waits for a confirm.
#[derive(Debug)]
enum Waiter {
    /// Cell `c`'s order list's cell call.
    List(usize),
    /// Cell `c`'s request to a station or its operator (on that
    /// station's lane).
    Cell(usize, StationName, Awaiting),
    /// The order list's read of what a station kept.
    Kept(Node),
    /// A station's Initiate of its subordinate (for its [`Serving`]).
    Initiate(Node, StationName),
    /// A step of delivery `n` ([`World::deliveries`]).
    Delivery(u64),
    /// The operator's Initiate of cell `c`'s controller, the root's
    /// ([`World::associate`]).
    Associate(usize, StationName),
    /// A workstation's confirm of what cell `c`'s pass-on asked (its id).
    Pass(usize, u64),
}

/// A recipe delivery under way: its steps go over the bus one by one.
#[derive(Debug)]
struct Delivering {
    from: Node,
    to: Node,
    /// The receiver's session when it began: a receiver started again
    /// meanwhile holds none of it.
    session: String,
    delivery: Delivery,
    then: Then,
}

/// Who takes a delivery's outcome.
#[derive(Debug, Clone, Copy)]
enum Then {
    /// Cell `c`'s order list (its delivery to the cell).
    List(usize),
    /// Cell `c`'s pass-on ([`CellNode::handle_delivered`] with this id).
    Pass(usize, u64),
}

/// A node's process: whether it runs, its session, its association
/// services (the core `falc_bus::station` drives on zenoh).
#[derive(Debug)]
struct Up {
    /// Its process runs (not crashed).
    running: bool,
    /// Its session: a process started again is another peer.
    session: String,
    /// Its commander and subordinates, and the Initiate in progress.
    serving: Serving<(Node, u64)>,
}

/// A cell's order list as `falc-operator` starts it.
fn order_list(
    part: &CellParts,
    view: Shared,
    source: Recipes,
    set: RecipeSet,
) -> OrderList<Shared, Recipes> {
    OrderList::new(
        part.name(Role::Operator).clone(),
        part.name(Role::Cell).clone(),
        source.topology().clone(),
        view,
        source,
        set,
    )
    .clocked_from(EPOCH_MS)
}

/// What a console hears while the operator's process is down.
const NO_OPERATOR: &str = "no connection with the operator";

/// The order a cell-level Start names (`order N`).
fn order_of(argument: &str) -> Option<i64> {
    argument
        .strip_prefix("order ")
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
}

/// The whole cell, or plant.
pub struct World {
    /// Virtual time since the start.
    pub now: Duration,
    /// Events handled so far (invariants are checked after each).
    pub steps: u64,
    /// The seeded source of every random choice.
    pub rng: StdRng,
    /// The bus.
    pub bus: Bus,
    /// The records (durable: they survive an operator's restart).
    pub records: Rc<RefCell<Memory>>,
    /// The operator's plant, as `falc-operator` runs it: a cell of its
    /// own is a plant of one (cell `c`'s order list: [`Self::order_list`]).
    pub plant: Plant<Shared, Recipes>,
    /// A second handle on each cell's records and recipe store, for an
    /// operator started again.
    durable: Vec<(Shared, Recipes)>,
    /// Console requests up to this ticket that were not answered when the
    /// operator died are refused (its API went with it).
    lost_before: u64,
    tickets: u64,
    /// Console answers not taken yet.
    replies: BTreeMap<Ticket, ApiResult>,
    /// The cells' indications at the operator: ticket → request id.
    indications: BTreeMap<Ticket, u64>,
    /// The cells.
    cells: Vec<CellParts>,
    /// How long a silent peer is still taken for present (the topology's).
    lease: Duration,
    /// Each node's process and associations.
    ups: BTreeMap<Node, Up>,
    timing: Timing,
    pending: BTreeMap<u64, Pending>,
    next_id: u64,
    /// Deliveries under way, by number.
    deliveries: BTreeMap<u64, Delivering>,
    /// Abort indications due when a lease runs out: (when, what parted).
    leases: Vec<(Duration, Parting)>,
    /// Nodes cut off whose lease ran out: parted from their router until
    /// joined again.
    parted: std::collections::BTreeSet<Node>,
    /// Cells whose uplink was cut for longer than the lease: parted from
    /// the operator until joined again.
    parted_cells: std::collections::BTreeSet<usize>,
    /// Cell-level Starts confirmed, per order id.
    pub starts: BTreeMap<i64, u32>,
    /// The highest order id each cell confirmed a Start of (0: none).
    pub last_started: Vec<i64>,
    /// The first order started more than once, and how often.
    pub started_twice: Option<(i64, u32)>,
    /// The first order a cell started while a workstation lacked a
    /// recipe the cell holds for it.
    pub started_lacking: Option<String>,
    /// The first delivery confirmed whose receiver does not hold it.
    pub false_delivery: Option<String>,
    /// Each workstation's recipe memory, where not the default (it
    /// survives a restart: it is the controller's).
    memory: BTreeMap<Node, usize>,
    /// The last lines of what happened, for a broken invariant's report.
    pub trace: VecDeque<String>,
    /// Each station's kept reports: a process's own, a new run when it
    /// starts again.
    kept: BTreeMap<Node, ReportLog>,
    /// Processes started so far (each a run of its own).
    runs: u64,
}

/// What a cut parts when its lease runs out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Parting {
    /// A node's link to its router.
    Node(Node),
    /// A cell's uplink to the factory router.
    Uplink(usize),
}

impl World {
    /// The cells of `layout` at rest at time zero, the twins at
    /// `time_scale`, the bus with `link` for every node (and uplink, in a
    /// plant); the recipes of the tree `recipes` (None: the shipped ones);
    /// `seed` drives every random choice.
    pub fn new(
        layout: &Layout,
        recipes: Option<&Path>,
        seed: u64,
        time_scale: f64,
        link: Link,
    ) -> Result<Self, String> {
        let topologies: Vec<Topology> = match layout {
            Layout::Cell(t) => vec![t.clone()],
            Layout::Plant(p) => p.cells().iter().map(|c| c.topology().clone()).collect(),
        };
        let lease = topologies
            .first()
            .map(Topology::lease)
            .ok_or("the layout has no cell")?;
        let ids: Vec<&str> = topologies.iter().map(|t| t.cell().as_str()).collect();
        let views = plant(&ids);
        let records = views.first().map(|v| v.all.clone()).ok_or("no records")?;
        let timing = Timing::default();
        let mut lists = Vec::new();
        let mut durable = Vec::new();
        let mut cells = Vec::new();
        for (topology, mut view) in topologies.into_iter().zip(views) {
            let part = CellParts::new(topology.clone(), time_scale, timing)?;
            let cell = part.name(Role::Cell).clone();
            let source = match recipes {
                None => Recipes::new(topology, cell),
                Some(dir) => Recipes::read(dir, topology, cell)?,
            };
            let set = source.load().map_err(|p| p.join("\n"))?;
            // What the list writes as it starts is stamped at the run's start.
            view.set_now(EPOCH_MS);
            durable.push((view.clone(), source.clone()));
            lists.push(order_list(&part, view, source, set));
            cells.push(part);
        }
        let uplinks = match layout {
            Layout::Cell(_) => 0,
            Layout::Plant(_) => cells.len(),
        };
        let now = Duration::ZERO;
        let mut w = Self {
            now,
            steps: 0,
            rng: StdRng::seed_from_u64(seed),
            bus: Bus::new(link, uplinks),
            records,
            plant: Plant::new(lists),
            durable,
            lost_before: 0,
            tickets: 0,
            replies: BTreeMap::new(),
            indications: BTreeMap::new(),
            last_started: vec![0; cells.len()],
            cells,
            lease,
            ups: BTreeMap::new(),
            timing,
            pending: BTreeMap::new(),
            next_id: 0,
            deliveries: BTreeMap::new(),
            leases: Vec::new(),
            parted: Default::default(),
            parted_cells: Default::default(),
            starts: BTreeMap::new(),
            started_twice: None,
            false_delivery: None,
            started_lacking: None,
            memory: BTreeMap::new(),
            trace: VecDeque::new(),
            kept: BTreeMap::new(),
            runs: 0,
        };
        for c in 0..w.cells.len() {
            for n in w.nodes_of(c) {
                w.new_run(n);
            }
            for n in w.stations_of(c) {
                let name = w.name(n);
                w.list(c).handle_presence(now, name, true);
            }
        }
        w.pump();
        Ok(w)
    }

    /// How many cells.
    pub fn cell_count(&self) -> usize {
        self.cells.len()
    }

    /// Cell `c`'s id in the topology.
    pub fn cell_id(&self, c: usize) -> &CellId {
        self.part(c).topology.cell()
    }

    /// Cell `c`'s processes and equipment.
    pub fn part(&self, c: usize) -> &CellParts {
        self.cells
            .get(c)
            .unwrap_or_else(|| unreachable!("cell {c} of {}", self.cells.len()))
    }

    /// Cell `c`'s processes and equipment, to change (its twins).
    pub fn part_mut(&mut self, c: usize) -> &mut CellParts {
        let n = self.cells.len();
        self.cells
            .get_mut(c)
            .unwrap_or_else(|| unreachable!("cell {c} of {n}"))
    }

    /// Cell `c`'s order list in the operator's plant.
    fn list(&mut self, c: usize) -> &mut OrderList<Shared, Recipes> {
        self.plant
            .list(c)
            .unwrap_or_else(|| unreachable!("the plant has a list per cell"))
    }

    /// Every node of cell `c`: the operator's place, the controller, the
    /// workstations in the topology's order.
    pub fn nodes_of(&self, c: usize) -> Vec<Node> {
        let roles = self.part(c).roles();
        roles.into_iter().map(|r| Node::new(c, r)).collect()
    }

    /// Cell `c`'s stations the operator sees: the controller and the
    /// workstations.
    fn stations_of(&self, c: usize) -> Vec<Node> {
        let mut v = self.nodes_of(c);
        v.retain(|n| !n.is_operator());
        v
    }

    /// Cell `c`'s workstations.
    fn workstations_of(&self, c: usize) -> Vec<Node> {
        let k = self.part(c).workstations();
        k.map(|k| Node::workstation(c, k)).collect()
    }

    /// `n`'s station name.
    fn name(&self, n: Node) -> StationName {
        self.part(n.cell).name(n.role).clone()
    }

    /// The node of cell `c` that is station `name`.
    fn node_of(&self, c: usize, name: &StationName) -> Option<Node> {
        self.part(c).role_of(name).map(|r| Node::new(c, r))
    }

    /// `falc2/` before a line of cell `c`'s in a plant; nothing in a cell
    /// of its own.
    fn cell_tag(&self, c: usize) -> String {
        match self.cells.len() {
            1 => String::new(),
            _ => format!("{}/", self.cell_id(c)),
        }
    }

    /// `n` as the trace names it: its station, with its cell in a plant.
    pub fn label(&self, n: Node) -> String {
        match (self.cells.len(), n.role) {
            (1, _) | (_, Role::Operator) => self.name(n).to_string(),
            _ => format!("{}/{}", self.cell_id(n.cell), self.name(n)),
        }
    }

    /// Cell `c`'s order list, to read.
    pub fn order_list(&self, c: usize) -> &OrderList<Shared, Recipes> {
        self.plant
            .list_at(c)
            .unwrap_or_else(|| unreachable!("the plant has a list per cell"))
    }

    /// Notes a line in the trace.
    pub fn note(&mut self, line: impl Into<String>) {
        if self.trace.len() == TRACE {
            self.trace.pop_front();
        }
        let line = line.into();
        self.trace.push_back(format!(
            "{:>10.3} s #{:<7} {line}",
            self.now.as_secs_f64(),
            self.steps
        ));
    }

    /// A console request as `user`, for cell `cell` (None: as the
    /// console gives no `--cell`); its answer comes later ([`Self::reply`]).
    pub fn api(&mut self, user: &str, cell: Option<usize>, request: ApiRequest) -> Ticket {
        self.tickets += 1;
        let t = Ticket(self.tickets);
        self.note(format!("console {user}: {request:?}"));
        let cell = cell.map(|c| self.cell_id(c).clone());
        match StationName::new(user) {
            Ok(_) if !self.operator_runs() => {
                self.replies.insert(t, Err(NO_OPERATOR.into()));
            }
            Ok(u) => {
                let now = self.now;
                self.plant.handle_api(now, t, &u, cell.as_ref(), request);
            }
            Err(e) => {
                self.replies.insert(t, Err(e.to_string()));
            }
        }
        self.pump();
        t
    }

    /// The answer to console request `t`, once it came.
    pub fn reply(&mut self, t: Ticket) -> Option<ApiResult> {
        self.replies
            .remove(&t)
            .or_else(|| (t.0 <= self.lost_before).then(|| Err(NO_OPERATOR.into())))
    }

    /// Whether `n`'s process runs.
    pub fn is_running(&self, n: Node) -> bool {
        self.ups.get(&n).map_or(true, |u| u.running)
    }

    /// Whether the operator's process runs.
    pub fn operator_runs(&self) -> bool {
        self.is_running(Node::operator(0))
    }

    /// The virtual clock's time as the records stamp it.
    fn wall_ms(&self) -> i64 {
        EPOCH_MS.saturating_add(i64::try_from(self.now.as_millis()).unwrap_or(i64::MAX))
    }

    /// `n`'s process and associations.
    fn up(&mut self, n: Node) -> Option<&mut Up> {
        self.ups.get_mut(&n)
    }

    /// `n`'s process as its peers know it: its station and session.
    fn peer(&self, n: Node) -> Peer {
        Peer {
            station: self.name(n),
            session: self
                .ups
                .get(&n)
                .map_or_else(|| format!("sim-{n}"), |u| u.session.clone()),
        }
    }

    /// The places `n`'s process has: the operator's in every cell, any
    /// other its own.
    fn places(&self, n: Node) -> Vec<Node> {
        match n.role {
            Role::Operator => (0..self.cells.len()).map(Node::operator).collect(),
            _ => vec![n],
        }
    }

    /// When something is next due.
    fn next_due(&self) -> Option<Duration> {
        let op = self.operator_runs();
        let plant = [
            self.bus.poll_timeout(),
            self.plant.poll_timeout().filter(|_| op),
        ];
        let cells = self
            .cells
            .iter()
            .enumerate()
            .map(|(c, p)| p.poll_timeout(self.is_running(Node::cell(c))));
        let rest = [
            self.pending.values().map(|p| p.deadline).min(),
            self.leases.iter().map(|l| l.0).min(),
        ];
        let mut t = plant.into_iter().chain(cells).chain(rest).flatten().min();
        if let Some(x) = &mut t {
            *x = (*x).max(self.now);
        }
        t
    }

    /// Advances the clock to the next thing due, but not past `until`, and
    /// handles everything due then.
    pub fn step(&mut self, until: Duration) {
        let next = self.next_due().map_or(until, |t| t.min(until));
        self.now = next.max(self.now);
        self.steps += 1;
        let now = self.now;
        // The bus.
        while let Some(a) = self.bus.poll_delivery(now) {
            self.arrive(a);
        }
        // Confirms that did not come in time.
        let late: Vec<u64> = self
            .pending
            .iter()
            .filter(|(_, p)| p.deadline <= now)
            .map(|(id, _)| *id)
            .collect();
        for id in late {
            if let Some(p) = self.pending.remove(&id) {
                let e = if p.parted {
                    ServiceError::unreachable(format!(
                        "no reply from {}: no route",
                        self.label(p.to)
                    ))
                } else {
                    ServiceError::timeout(format!("no confirm from {} in time", self.label(p.to)))
                };
                self.confirm(p.waiter, Err(e));
            }
        }
        // Leases.
        let due: Vec<Parting> = self
            .leases
            .iter()
            .filter(|l| l.0 <= now)
            .map(|l| l.1)
            .collect();
        self.leases.retain(|l| l.0 > now);
        for p in due {
            match p {
                Parting::Node(n) if self.bus.is_cut(n) => {
                    self.parted.extend(self.places(n));
                    self.lost(n);
                }
                Parting::Uplink(c) if self.bus.is_uplink_cut(c) => {
                    self.parted_cells.insert(c);
                    self.lost_uplink(c);
                }
                Parting::Node(_) | Parting::Uplink(_) => {}
            }
        }
        // Clocks.
        if self.operator_runs() && self.plant.poll_timeout().is_some_and(|t| t <= now) {
            self.plant.handle_timeout(now);
        }
        for c in 0..self.cells.len() {
            self.clocks(c);
        }
        self.pump();
    }

    /// Cell `c`'s timers due now.
    fn clocks(&mut self, c: usize) {
        let now = self.now;
        // Borrowed apart: the processes' states to read, the cell's parts
        // to change (every step: nothing allocated).
        let ups = &self.ups;
        let runs = |r| ups.get(&Node::new(c, r)).map_or(true, |u| u.running);
        if let Some(p) = self.cells.get_mut(c) {
            p.handle_timeout(now, runs);
        }
    }

    /// Carries what every core put out to where it goes, until all are
    /// quiet.
    pub fn pump(&mut self) {
        // The order lists' outputs all go on the bus: once is enough.
        self.pump_list();
        for _ in 0..64 {
            let mut busy = false;
            for c in 0..self.cells.len() {
                busy |= self.pump_cell(c);
                for k in self.part(c).workstations() {
                    busy |= self.pump_workstation(Node::workstation(c, k));
                }
            }
            if !busy {
                return;
            }
        }
    }

    /// Whether `a` and `b` are parted from each other's router: no route.
    fn is_parted(&self, a: Node, b: Node) -> bool {
        // Between the operator and a cell's station: across that cell's
        // uplink.
        let across = a.is_operator() != b.is_operator();
        let cut_off = |n: Node| !n.is_operator() && self.parted_cells.contains(&n.cell);
        self.parted.contains(&a)
            || self.parted.contains(&b)
            || (across && (cut_off(a) || cut_off(b)))
    }

    fn request(
        &mut self,
        from: Node,
        to: Node,
        msg: impl FnOnce(u64) -> Msg,
        limit: Duration,
        waiter: Waiter,
    ) {
        self.next_id += 1;
        let id = self.next_id;
        // A session parted from its router (its lease ran out while cut)
        // knows no queryable: zenoh ends such a query at once, with no
        // reply (at the next step here).
        let parted = self.is_parted(from, to);
        let deadline = if parted { self.now } else { self.now + limit };
        self.pending.insert(
            id,
            Pending {
                to,
                deadline,
                waiter,
                parted,
            },
        );
        if !parted {
            let now = self.now;
            self.bus.send(now, from, to, msg(id), &mut self.rng);
        }
    }

    fn respond(&mut self, from: Node, to: Node, id: u64, result: Result<Response, ServiceError>) {
        let now = self.now;
        self.bus
            .send(now, from, to, Msg::Response { id, result }, &mut self.rng);
    }

    /// The stations whose reports the order lists have not all filed: each
    /// running station's current run, as far as its list heard it, must be
    /// filed up to its last report (what a cut kept read back).
    pub fn unfiled(&self) -> Vec<String> {
        if !self.operator_runs() {
            return Vec::new();
        }
        self.kept
            .iter()
            .filter(|(n, _)| self.is_running(**n))
            .filter_map(|(n, log)| {
                let (run, last, holes) = self.order_list(n.cell).filed(&self.name(*n))?;
                (run == log.run() && (last != log.last() || holes > 0)).then(|| {
                    format!(
                        "{n} made {} reports in run {run}; the list filed up to {last}, \
                         {holes} of them never",
                        log.last()
                    )
                })
            })
            .collect()
    }

    /// Node `n`'s process starts: a new session with no associations, and
    /// its kept reports are a new run's.
    fn new_run(&mut self, n: Node) {
        self.runs += 1;
        let run = format!("{n}-{}", self.runs);
        let session = format!("sim-{run}");
        let me = Peer {
            station: self.name(n),
            session: session.clone(),
        };
        let up = Up {
            running: true,
            session,
            serving: Serving::of(&self.part(n.cell).topology, me),
        };
        self.ups.insert(n, up);
        if !n.is_operator() {
            self.kept.insert(n, ReportLog::new(run));
        }
    }

    fn publish(&mut self, from: Node, u: Unconfirmed) {
        // Numbered and kept as the bus does (stamped by the virtual clock).
        let at_ms = self.wall_ms();
        let u = match self.kept.get_mut(&from) {
            Some(log) => log.publication(at_ms, u),
            None => Publication {
                stamp: None,
                message: u,
            },
        };
        let c = from.cell;
        let to: &[Node] = match from.role {
            Role::Workstation(_) => &[Node::operator(c), Node::cell(c)],
            Role::Cell => &[Node::operator(c)],
            Role::Operator => &[],
        };
        let now = self.now;
        for t in to {
            self.bus
                .send(now, from, *t, Msg::Publish(u.clone()), &mut self.rng);
        }
    }

    fn pump_list(&mut self) {
        if !self.operator_runs() {
            return;
        }
        while let Some(out) = self.plant.poll_output() {
            let (c, out) = match out {
                PlantOutput::Reply { ticket, result } => {
                    self.replies.insert(ticket, *result);
                    continue;
                }
                PlantOutput::Cell(c, out) => (c, out),
            };
            let (me, cell) = (Node::operator(c), Node::cell(c));
            match out {
                ListOutput::Cell(CellCall::Associate) => self.associate(c),
                ListOutput::Cell(call) => match call.request(&self.peer(me)) {
                    Ok(request) => self.request(
                        me,
                        cell,
                        |id| Msg::Request { id, request },
                        CELL_LIMIT,
                        Waiter::List(c),
                    ),
                    Err(d) => {
                        let to = self.name(cell);
                        let delivery = Delivery::new(to, d.domain, &d.content, d.is_cell);
                        self.deliver(me, delivery, Then::List(c));
                    }
                },
                ListOutput::Respond { ticket, result } => {
                    if let Some(id) = self.indications.remove(&ticket) {
                        self.respond(me, cell, id, result);
                    }
                }
                ListOutput::Forget(ticket) => {
                    // Dropped unanswered: zenoh ends a query whose
                    // responder is dropped with no reply, at once.
                    if let Some(id) = self.indications.remove(&ticket) {
                        let e = ServiceError::unreachable("no reply to the question (dropped)");
                        self.respond(me, cell, id, Err(e));
                    }
                }
                ListOutput::Say(line) => self.note(format!("{}operator: {line}", self.cell_tag(c))),
                ListOutput::Changed => {}
                ListOutput::ReadReports { station, after } => {
                    if let Some(to) = self.node_of(c, &station) {
                        let msg = move |id| Msg::ReadKept { id, after };
                        self.request(me, to, msg, CELL_LIMIT, Waiter::Kept(to));
                    }
                }
            }
        }
    }

    fn pump_cell(&mut self, c: usize) -> bool {
        let me = Node::cell(c);
        if !self.is_running(me) {
            return false;
        }
        let mut any = false;
        loop {
            let now = self.now;
            let Some(action) = self.part_mut(c).cell.poll(now) else {
                break;
            };
            any = true;
            match action {
                CellAction::Request(cmd) => {
                    let Some(to) = self.node_of(c, &cmd.to) else {
                        let e = ServiceError::unreachable(format!("no station {}", cmd.to));
                        let reply = Reply {
                            awaiting: cmd.awaiting,
                            result: Err(e),
                        };
                        let now = self.now;
                        self.part_mut(c).cell.handle_reply(now, &cmd.to, reply);
                        continue;
                    };
                    let request = cmd.request;
                    self.request(
                        me,
                        to,
                        |id| Msg::Request { id, request },
                        cmd.limit,
                        Waiter::Cell(c, cmd.to, cmd.awaiting),
                    );
                }
                CellAction::Answer {
                    ticket: (to, id),
                    result,
                } => {
                    let starting = self.part_mut(c).starting.remove(&(to, id));
                    if let (Some(n), true) = (starting, result.is_ok()) {
                        self.started(c, n);
                    }
                    self.respond(me, to, id, result)
                }
                CellAction::Ask { id, to, request } => match self.node_of(c, &to) {
                    Some(ws) => self.request(
                        me,
                        ws,
                        |id| Msg::Request { id, request },
                        PASS_LIMIT,
                        Waiter::Pass(c, id),
                    ),
                    None => {
                        let e = ServiceError::unreachable(format!("no station {to}"));
                        self.part_mut(c).cell.handle_confirm(id, Err(e));
                    }
                },
                CellAction::Deliver { id, delivery } => {
                    self.deliver(me, delivery, Then::Pass(c, id));
                }
                CellAction::Delivered { to, name } => {
                    self.note(format!("{}: {name} delivered to {to}", self.label(me)));
                }
                CellAction::Warn(text) => self.note(format!("{}: {text}", self.label(me))),
                CellAction::Publish(u) => self.publish(me, u),
            }
        }
        any
    }

    /// Carries what workstation `n`'s node decided to its device's link
    /// (the link tasks' job, [`crate::cell`]) and on the bus.
    fn pump_workstation(&mut self, n: Node) -> bool {
        let Role::Workstation(k) = n.role else {
            return false;
        };
        if !self.is_running(n) {
            return false;
        }
        let now = self.now;
        match self.part_mut(n.cell).workstation_mut(k) {
            Some(Workstation::Welding(w)) => {
                let out = w.settle(now);
                self.carry_workstation(n, out)
            }
            Some(Workstation::Transport(t)) => {
                let out = t.settle(now);
                self.carry_workstation(n, out)
            }
            None => false,
        }
    }

    /// Carries out a workstation's actions on the bus (answers,
    /// publications, lines for the trace, in order) and its twin's lines;
    /// whether the node did anything.
    fn carry_workstation<C>(&mut self, at: Node, out: Settled<C>) -> bool {
        for action in out.actions {
            match action {
                Action::Answer {
                    ticket: (to, id),
                    result,
                } => self.respond(at, to, id, result),
                Action::Publish(u) => self.publish(at, u),
                Action::Event(line) => self.note(format!("{}: {line}", self.label(at))),
                // Carried to the link while it settled.
                Action::Command(_) => {}
            }
        }
        for note in out.notes {
            self.note(format!("{}{note}", self.cell_tag(at.cell)));
        }
        out.any
    }

    /// A publication the bus carried to `to`, taken in.
    fn heard(&mut self, now: Duration, to: Node, p: Publication) {
        match to.role {
            Role::Operator => self.list(to.cell).handle_heard(now, p.stamp, p.message),
            Role::Cell => self
                .part_mut(to.cell)
                .cell
                .handle_publication(now, &p.message),
            Role::Workstation(_) => {}
        }
    }

    /// A message arrived.
    fn arrive(&mut self, a: Arrival) {
        let now = self.now;
        match (a.to, a.msg) {
            (_, Msg::Response { id, result }) => {
                if let Some(p) = self.pending.remove(&id) {
                    self.confirm(p.waiter, result);
                }
            }
            // A dead process's queryables went with its session: the
            // router ends a query to it at once, with no reply.
            (to, Msg::Request { id, .. } | Msg::ReadKept { id, .. }) if !self.is_running(to) => {
                if let Some(p) = self.pending.remove(&id) {
                    let e = ServiceError::unreachable(format!("no reply from {}", self.label(to)));
                    self.confirm(p.waiter, Err(e));
                }
            }
            (to, _) if !self.is_running(to) => {}
            (_, Msg::Kept { id, kept }) => {
                if let Some(Pending {
                    waiter: Waiter::Kept(n),
                    ..
                }) = self.pending.remove(&id)
                {
                    let name = self.name(n);
                    let kept = heard::take_kept(&name, kept).map_err(|e| e.to_string());
                    self.list(n.cell).handle_kept_reports(now, name, kept);
                }
            }
            // What a receiver takes in, as on the bus: the sender is the
            // station it came from, texts bounded.
            (to, Msg::Publish(p)) => {
                if let Ok((p, _)) = heard::take_publication(&self.name(a.from), p) {
                    self.heard(now, to, p);
                }
            }
            (to, Msg::ReadKept { id, after }) => {
                if let Some(log) = self.kept.get(&to) {
                    let kept = log.after(ReportsAsked { after });
                    self.bus
                        .send(now, to, a.from, Msg::Kept { id, kept }, &mut self.rng);
                }
            }
            (to, Msg::Request { id, request }) => {
                if let Some(up) = self.up(to) {
                    up.serving.handle_request((a.from, id), request);
                }
                self.carry_serving(to);
            }
        }
    }

    fn confirm(&mut self, waiter: Waiter, result: Result<Response, ServiceError>) {
        let now = self.now;
        match waiter {
            Waiter::List(c) => self.list(c).handle_cell_answer(now, result),
            Waiter::Cell(c, to, awaiting) => {
                let reply = Reply { awaiting, result };
                self.part_mut(c).cell.handle_reply(now, &to, reply);
            }
            Waiter::Kept(n) => {
                let why = result.err().map_or_else(String::new, |e| e.to_string());
                let name = self.name(n);
                self.list(n.cell).handle_kept_reports(now, name, Err(why));
            }
            Waiter::Delivery(n) => {
                if let Some(d) = self.deliveries.get_mut(&n) {
                    let step = d.delivery.answered(result);
                    self.delivery_step(n, step);
                }
            }
            Waiter::Pass(c, id) => self.part_mut(c).cell.handle_confirm(id, result),
            Waiter::Associate(c, sub) => {
                let me = Node::operator(c);
                let made = self
                    .up(me)
                    .map(|u| u.serving.record_initiates(vec![(sub, result)]));
                self.carry_serving(me);
                let answer = match made {
                    Some(Ok(_)) => Ok(Response::Done),
                    Some(Err(e)) => Err(e),
                    None => Err(ServiceError::unreachable("the operator is not running")),
                };
                self.list(c).handle_cell_answer(now, answer);
            }
            Waiter::Initiate(at, sub) => {
                if let Some(up) = self.up(at) {
                    up.serving.handle_initiated(&sub, result);
                }
                self.carry_serving(at);
            }
        }
    }

    /// The node that waits for `waiter`'s confirm (whose process it dies
    /// with).
    fn waits_at(&self, waiter: &Waiter) -> Node {
        match waiter {
            Waiter::List(c) | Waiter::Associate(c, _) => Node::operator(*c),
            Waiter::Kept(n) => Node::operator(n.cell),
            Waiter::Cell(c, ..) | Waiter::Pass(c, _) => Node::cell(*c),
            Waiter::Initiate(at, _) => *at,
            Waiter::Delivery(n) => self.deliveries.get(n).map_or(Node::operator(0), |d| d.from),
        }
    }

    /// The operator associates cell `c`'s controller, as `falc-operator`'s
    /// station for that cell does as the root: the Initiates its
    /// [`Serving`] sends (a cell's operator has one subordinate, the
    /// cell), recorded once confirmed.
    fn associate(&mut self, c: usize) {
        let me = Node::operator(c);
        let due = self
            .up(me)
            .map(|u| u.serving.initiates())
            .unwrap_or_default();
        let now = self.now;
        let Some((sub, limit)) = due.into_iter().next() else {
            let e = ServiceError::undefined("the operator commands no cell in the topology");
            self.list(c).handle_cell_answer(now, Err(e));
            return;
        };
        let Some(to) = self.node_of(c, &sub) else {
            let e = ServiceError::unreachable(format!("no station {sub}"));
            self.list(c).handle_cell_answer(now, Err(e));
            return;
        };
        let request = Request::Initiate {
            calling: self.peer(me),
        };
        let msg = |id| Msg::Request { id, request };
        self.request(me, to, msg, limit, Waiter::Associate(c, sub));
    }

    /// Starts `delivery` from `from`; its outcome goes to `then`.
    fn deliver(&mut self, from: Node, delivery: Delivery, then: Then) {
        let Some(to) = self.node_of(from.cell, delivery.to()) else {
            let e = ServiceError::unreachable(format!("no station {}", delivery.to()));
            self.delivered(then, Err(e));
            return;
        };
        self.next_id += 1;
        let n = self.next_id;
        let mut d = Delivering {
            from,
            to,
            session: self.peer(to).session,
            delivery,
            then,
        };
        let step = d.delivery.start();
        self.deliveries.insert(n, d);
        self.delivery_step(n, step);
    }

    /// Carries out delivery `n`'s next step: a request over the bus, or
    /// its outcome to whom it goes.
    fn delivery_step(&mut self, n: u64, step: DeliveryStep) {
        let Some(d) = self.deliveries.get(&n) else {
            return;
        };
        let (from, to, then) = (d.from, d.to, d.then);
        match step {
            DeliveryStep::Send(request) => self.request(
                from,
                to,
                |id| Msg::Request { id, request },
                STEP_LIMIT,
                Waiter::Delivery(n),
            ),
            DeliveryStep::Done(result) => {
                if let (Some(d), Ok(())) = (self.deliveries.remove(&n), &result) {
                    self.check_held(&d);
                }
                self.delivered(then, result);
            }
        }
    }

    /// A delivery confirmed: its receiver, if it still runs the session
    /// it began in, holds the domain, whole (else noted as the first
    /// [`World::false_delivery`]).
    fn check_held(&mut self, d: &Delivering) {
        if d.to.is_operator() || !self.is_running(d.to) || self.peer(d.to).session != d.session {
            return;
        }
        let name = d.delivery.name();
        let held = self.holds(d.to, name, d.delivery.content_hash());
        if !held && self.false_delivery.is_none() {
            let to = self.label(d.to);
            let what = format!(
                "the delivery of {name} to {to} was confirmed, but {to} does not hold it whole"
            );
            self.note(what.clone());
            self.false_delivery = Some(what);
        }
    }

    /// A delivery's outcome, to whom it goes.
    fn delivered(&mut self, then: Then, result: Result<(), ServiceError>) {
        match then {
            Then::List(c) => {
                let now = self.now;
                self.list(c)
                    .handle_cell_answer(now, result.map(|()| Response::Done));
            }
            Then::Pass(c, id) => self.part_mut(c).cell.handle_delivered(id, result),
        }
    }

    /// What node `n`'s process waited for dies with it: its requests out
    /// and its deliveries.
    fn forget_waits_of(&mut self, n: Node) {
        let gone: Vec<u64> = self
            .pending
            .iter()
            .filter(|(_, p)| self.waits_at(&p.waiter) == n)
            .map(|(id, _)| *id)
            .collect();
        for id in gone {
            self.pending.remove(&id);
        }
        self.deliveries.retain(|_, d| d.from != n);
    }

    /// Carries out what station `at`'s association services ask (as
    /// `falc_bus::station` does on zenoh): answers, Initiates of its
    /// subordinates, Concludes and Aborts told, and what its node takes in.
    /// The simulation watches no token: its leases and crashes tell a loss.
    fn carry_serving(&mut self, at: Node) {
        let now = self.now;
        let c = at.cell;
        while let Some(action) = self
            .up(at)
            .filter(|u| u.running)
            .and_then(|u| u.serving.poll())
        {
            match action {
                Serve::Respond((to, id), result) => self.respond(at, to, id, result),
                Serve::Initiate { to, request, limit } => match self.node_of(c, &to) {
                    Some(sub) => {
                        let msg = |id| Msg::Request { id, request };
                        self.request(at, sub, msg, limit, Waiter::Initiate(at, to));
                    }
                    None => {
                        let e = ServiceError::unreachable(format!("no station {to}"));
                        if let Some(up) = self.up(at) {
                            up.serving.handle_initiated(&to, Err(e));
                        }
                    }
                },
                Serve::Tell { to, request } => {
                    if let Some(to) = self.node_of(c, &to) {
                        self.next_id += 1;
                        let id = self.next_id;
                        self.bus
                            .send(now, at, to, Msg::Request { id, request }, &mut self.rng);
                    }
                }
                Serve::Watch(_) | Serve::Unwatch(_) | Serve::Concluded(_) => {}
                Serve::Indication((from, id), request) => match at.role {
                    // The cell's questions and lines, for the order list.
                    Role::Operator => {
                        self.tickets += 1;
                        let t = Ticket(self.tickets);
                        self.indications.insert(t, id);
                        self.list(c).handle_cell_request(now, t, request);
                    }
                    Role::Cell => {
                        let p = self.part_mut(c);
                        if let Request::Start { argument, .. } = &request {
                            // Watched for the invariant: counted once answered.
                            if let Some(n) = order_of(argument) {
                                p.starting.insert((from, id), n);
                            }
                        }
                        p.cell.handle_indication((from, id), request);
                    }
                    Role::Workstation(k) => match self.part_mut(c).workstation_mut(k) {
                        Some(Workstation::Welding(w)) => {
                            w.node_mut().handle_indication(now, (from, id), &request)
                        }
                        Some(Workstation::Transport(t)) => {
                            t.node_mut().handle_indication(now, (from, id), &request)
                        }
                        None => {}
                    },
                },
                Serve::Associated(p) => {
                    self.note(format!("{}: associated with {}", self.label(at), p.station));
                    let parts = self.part_mut(c);
                    match at.role {
                        Role::Cell => parts.cell.handle_associated(now),
                        Role::Workstation(k) => match parts.workstation_mut(k) {
                            Some(Workstation::Welding(w)) => w.node_mut().handle_associated(now),
                            Some(Workstation::Transport(t)) => t.node_mut().handle_associated(now),
                            None => {}
                        },
                        Role::Operator => {}
                    }
                }
                Serve::Abort(ind) => {
                    let (name, role) = (&ind.peer.station, ind.role);
                    match at.role {
                        Role::Cell => self.part_mut(c).cell.handle_abort(now, name, role),
                        Role::Workstation(k) => match self.part_mut(c).workstation_mut(k) {
                            Some(Workstation::Welding(w)) => {
                                w.node_mut().handle_abort(now, name, role)
                            }
                            Some(Workstation::Transport(t)) => {
                                t.node_mut().handle_abort(now, name, role)
                            }
                            None => {}
                        },
                        Role::Operator => self.list(c).handle_abort(now, &ind.reason),
                    }
                }
            }
        }
    }

    /// Cell `c` answered its commander's Start of order `n`: counted.
    fn started(&mut self, c: usize, n: i64) {
        let count = self.starts.entry(n).or_default();
        *count += 1;
        if *count > 1 && self.started_twice.is_none() {
            self.started_twice = Some((n, *count));
        }
        if let Some(last) = self.last_started.get_mut(c) {
            *last = (*last).max(n);
        }
        let cell = self.label(Node::cell(c));
        self.note(format!("{cell}: order {n} started"));
        if let Some(what) = self.lacking(c).filter(|_| self.started_lacking.is_none()) {
            self.note(what.clone());
            self.started_lacking = Some(format!("order {n} started at {cell} while {what}"));
        }
    }

    /// A workstation of cell `c` associated with its cell controller that
    /// lacks a recipe the controller holds for it (or holds another
    /// version), said.
    fn lacking(&self, c: usize) -> Option<String> {
        let cell = self.part(c).controller().vmd();
        let assoc = self.ups.get(&Node::cell(c))?.serving.associations();
        for ws in self.workstations_of(c) {
            let me = self.name(ws);
            if !self.is_running(ws) || assoc.subordinate(&me) != Some(&self.peer(ws)) {
                continue;
            }
            for d in cell.domains() {
                let Some((to, name)) = workstation_domain(d.name()) else {
                    continue;
                };
                if to == me && !self.holds(ws, &name, content_hash(d.content())) {
                    return Some(format!("{} lacks its recipe {name}", self.label(ws)));
                }
            }
        }
        None
    }

    /// Whether node `n`'s VMD holds domain `name` whole (loaded) with
    /// content hash `hash`.
    fn holds(&self, n: Node, name: &ObjectName, hash: u64) -> bool {
        let Some(vmd) = self.part(n.cell).vmd(n.role) else {
            return false;
        };
        vmd.domain(name).is_some_and(|d| {
            matches!(d.state(), DomainState::Ready | DomainState::InUse)
                && content_hash(d.content()) == hash
        })
    }

    /// `n`'s link to its router is cut (or joined again); the operator's
    /// is one for all its places.
    pub fn cut(&mut self, n: Node, cut: bool) {
        self.bus.set_cut(n, cut);
        self.parting(Parting::Node(n), cut);
    }

    /// Cell `c`'s uplink to the factory router is cut (or joined again):
    /// the cell runs on, parted from the operator.
    pub fn cut_uplink(&mut self, c: usize, cut: bool) {
        self.bus.set_uplink_cut(c, cut);
        self.parting(Parting::Uplink(c), cut);
    }

    /// What the bus's cut (or join) of `p` leads to: a cut is a loss once
    /// the lease runs out; a join makes what was parted seen again.
    fn parting(&mut self, p: Parting, cut: bool) {
        let what = if cut { "cut off" } else { "back" };
        let who = match p {
            Parting::Node(n) => self.label(n),
            Parting::Uplink(c) => format!("cell {} uplink", self.cell_id(c)),
        };
        self.note(format!("bus: {who} {what}"));
        match (p, cut) {
            (_, true) => {
                let at = self.now + self.lease;
                self.leases.push((at, p));
            }
            (Parting::Node(n), false) => self.back(n),
            (Parting::Uplink(c), false) => {
                self.parted_cells.remove(&c);
                self.seen_again(c);
            }
        }
        self.pump();
    }

    /// The operator sees `n` (and, for the operator, everyone) again.
    fn back(&mut self, n: Node) {
        for p in self.places(n) {
            self.parted.remove(&p);
        }
        match n.role {
            Role::Operator => {
                for c in 0..self.cells.len() {
                    self.seen_again(c);
                }
            }
            _ => self.present(n),
        }
    }

    /// The operator sees cell `c`'s stations it reaches again.
    fn seen_again(&mut self, c: usize) {
        for n in self.stations_of(c) {
            self.present(n);
        }
    }

    /// The operator's list of `n`'s cell sees `n` present, if it reaches
    /// it and `n` runs.
    fn present(&mut self, n: Node) {
        let now = self.now;
        if self.bus.reachable(Node::operator(n.cell), n) && self.is_running(n) {
            let name = self.name(n);
            self.list(n.cell).handle_presence(now, name, true);
        }
    }

    /// The requests between nodes for which `gone` holds end with no reply
    /// at once, as zenoh's router finalizes a closed face's pending
    /// queries (`finalize_pending_queries`): those routed to a parted node
    /// and those it sent and still waits for, which its own session had
    /// routed to the router's face, closed on its side too.
    fn finalize_where(&mut self, gone: impl Fn(Node, Node) -> bool) {
        let ids: Vec<u64> = self
            .pending
            .iter()
            .filter(|(_, p)| gone(self.waits_at(&p.waiter), p.to))
            .map(|(id, _)| *id)
            .collect();
        for id in ids {
            if let Some(p) = self.pending.remove(&id) {
                let e = ServiceError::unreachable(format!(
                    "no reply from {}: the session closed",
                    self.label(p.to)
                ));
                self.confirm(p.waiter, Err(e));
            }
        }
    }

    /// `n`'s session and its router parted: what it waits for and what
    /// waits for it ends.
    fn finalize(&mut self, n: Node) {
        self.finalize_where(|from, to| to == n || from == n);
    }

    /// `n`'s associations ended (its lease ran out, or it crashed): every
    /// peer associated with it takes the abort indication, and a cut `n`
    /// takes theirs. The operator's places all go together.
    fn lost(&mut self, n: Node) {
        let now = self.now;
        self.note(format!("bus: {} lost", self.label(n)));
        for p in self.places(n) {
            self.finalize(p);
        }
        let reason = format!("no connection with {}", self.label(n));
        let cells: Vec<usize> = match n.role {
            Role::Operator => (0..self.cells.len()).collect(),
            _ => vec![n.cell],
        };
        for c in cells {
            let (op, cell) = (Node::operator(c), Node::cell(c));
            if n.is_operator() || n == cell {
                self.sees_lost(cell, op, &reason);
                self.sees_lost(op, cell, &reason);
            }
            let seen = match n.role {
                Role::Operator => self.stations_of(c),
                _ => vec![n],
            };
            for s in seen {
                let name = self.name(s);
                self.list(c).handle_presence(now, name, false);
            }
            for ws in self.workstations_of(c) {
                if n == cell || n == ws {
                    self.sees_lost(cell, ws, &reason);
                    self.sees_lost(ws, cell, &reason);
                }
            }
        }
    }

    /// Cell `c`'s uplink stayed cut past the lease: the operator and the
    /// cell's stations lose each other (the cell's own associations hold).
    fn lost_uplink(&mut self, c: usize) {
        let now = self.now;
        self.note(format!("bus: cell {} lost", self.cell_id(c)));
        self.finalize_where(|from, to| {
            (from.is_operator() != to.is_operator()) && from.cell == c && to.cell == c
        });
        let (op, cell) = (Node::operator(c), Node::cell(c));
        let reason = format!("no connection with cell {}", self.cell_id(c));
        self.sees_lost(cell, op, &reason);
        self.sees_lost(op, cell, &reason);
        for n in self.stations_of(c) {
            let name = self.name(n);
            self.list(c).handle_presence(now, name, false);
        }
    }

    /// Node `at` loses its association with `gone` (if it had one and
    /// runs): the abort indication, as its station hands it on.
    fn sees_lost(&mut self, at: Node, gone: Node, reason: &str) {
        let peer = self.peer(gone);
        if let Some(up) = self.up(at).filter(|u| u.running) {
            up.serving.handle_lost(&peer, reason);
        }
        self.carry_serving(at);
    }

    /// Random bytes on the serial line of workstation `n` (a welding
    /// one), towards both ends.
    pub fn noise(&mut self, n: Node, bytes: Vec<u8>) {
        let (now, len) = (self.now, bytes.len());
        self.note(format!("{}: serial: {len} bytes of noise", self.label(n)));
        if let Role::Workstation(k) = n.role {
            if let Some(w) = self.part_mut(n.cell).welding_mut(k) {
                w.noise(now, bytes);
            }
        }
    }

    /// Node `n`'s process dies: only the twins' state survives (and the
    /// operator's records).
    pub fn crash(&mut self, n: Node) {
        self.note(format!("{}: process killed", self.label(n)));
        let places = self.places(n);
        for p in &places {
            if let Some(up) = self.up(*p) {
                up.running = false;
            }
            // Its requests out die with it.
            self.forget_waits_of(*p);
        }
        if n.is_operator() {
            // Its indications and its API go with it; the routers end the
            // cells' queries to it; each cell runs its order on alone.
            self.indications.clear();
            self.lost_before = self.tickets;
            let reason = format!("no connection with {}", self.label(n));
            for p in &places {
                self.finalize(*p);
                self.sees_lost(Node::cell(p.cell), *p, &reason);
            }
        } else {
            // Its liveliness token goes with its session: seen at once.
            self.lost(n);
        }
        // A dead process holds no association.
        for p in places {
            let fresh = Serving::of(&self.part(p.cell).topology, self.peer(p));
            if let Some(up) = self.up(p) {
                up.serving = fresh;
            }
        }
        self.pump();
    }

    /// Workstation `n`'s recipe memory is `bytes` from now on (None: the
    /// default), also after a restart.
    pub fn set_recipe_memory(&mut self, n: Node, bytes: Option<usize>) {
        match bytes {
            Some(b) => self.memory.insert(n, b),
            None => self.memory.remove(&n),
        };
        self.apply_memory(n);
    }

    fn apply_memory(&mut self, n: Node) {
        let bytes = self.memory.get(&n).copied().unwrap_or(RECIPE_MEMORY);
        let Role::Workstation(k) = n.role else {
            return;
        };
        match self.part_mut(n.cell).workstation_mut(k) {
            Some(Workstation::Welding(w)) => w.node_mut().set_recipe_memory(bytes),
            Some(Workstation::Transport(t)) => t.node_mut().set_recipe_memory(bytes),
            None => {}
        }
    }

    /// Node `n` starts again: empty, but for the operator's records.
    pub fn restart(&mut self, n: Node) {
        let now = self.now;
        self.note(format!("{}: process started again", self.label(n)));
        let (timing, me) = (self.timing, self.name(n));
        let p = self.part_mut(n.cell);
        match n.role {
            Role::Operator => {
                self.restart_operator();
                return;
            }
            Role::Cell => p.restart_cell(),
            Role::Workstation(k) => {
                let topology = p.topology.clone();
                match p.workstation_mut(k) {
                    Some(Workstation::Welding(w)) => w.restart(&topology, &me, now, timing),
                    Some(Workstation::Transport(t)) => t.restart(&topology, &me, now),
                    None => {}
                }
            }
        }
        self.apply_memory(n);
        self.new_run(n);
        self.present(n);
        self.pump();
    }

    /// The operator starts again on its records: the order each cell's
    /// records hold as running is adopted (the cell is asked how it
    /// ended), as `falc-operator` does at start.
    fn restart_operator(&mut self) {
        let ids: Vec<String> = (0..self.cells.len())
            .map(|c| self.cell_id(c).to_string())
            .collect();
        let ids: Vec<&str> = ids.iter().map(String::as_str).collect();
        let mut adopted = Vec::new();
        let mut lists = Vec::new();
        for (i, (mut view, source)) in self.durable.clone().into_iter().enumerate() {
            view.set_now(self.wall_ms());
            if i == 0 {
                adopted = match view.recover(&ids) {
                    Ok(r) => r.adopted,
                    Err(e) => {
                        // The real node exits and is started again; here it
                        // starts with nothing adopted, and says so.
                        self.note(format!("operator: cannot recover: {e}"));
                        Vec::new()
                    }
                };
            }
            let set = match source.load() {
                Ok(set) => set,
                Err(problems) => {
                    self.note(format!(
                        "operator: recipes refused: {}",
                        problems.join("; ")
                    ));
                    return;
                }
            };
            let mut list = order_list(self.part(i), view, source, set);
            let cell = list.cell().to_string();
            if let Some(k) = adopted
                .iter()
                .position(|o| o.cell.as_deref() == Some(cell.as_str()))
            {
                let o = adopted.swap_remove(k);
                self.note(format!("operator: adopted order {} on {cell}", o.id));
                list = list.adopting(o);
            }
            lists.push(list);
        }
        self.plant = Plant::new(lists);
        for c in 0..self.cells.len() {
            self.new_run(Node::operator(c));
            self.seen_again(c);
        }
        self.pump();
    }
}
