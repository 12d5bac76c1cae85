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
use crate::recipes::Shipped;
use falc_control::cell_node::{CellAction, CellNode};
use falc_control::controller::Controller;
use falc_control::coordination::{workstation_domain, Awaiting, Reply, Stations};
use falc_control::pass_on::PASS_LIMIT;
use falc_control::workstation_node::{Linked, WorkstationAction, WorkstationNode};
use falc_dnc::procedure::{Link as DncLink, Priority, Timing};
use falc_dnc::robot::Robot;
use falc_dnc::telegram::Mode;
use falc_dnc::twin::{Note, RcmTwin};
use falc_dnc::workstation::{self, LineEvent, Welding};
use falc_factory::order_list::{CellCall, OrderList, Output as ListOutput, Ticket, CELL_LIMIT};
use falc_factory::plant::{Plant, PlantOutput};
use falc_factory::recipe_source::{RecipeSet, RecipeSource};
use falc_factory::records::memory::Memory;
use falc_factory::records::shared::{plant, Shared};
use falc_factory::records::Records;
use falc_model::console::{ApiRequest, ApiResult};
use falc_model::ids::{CellId, ObjectName, StationName};
use falc_model::mms::association::Associations;
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
use falc_plc::conveyor::{Conveyor, Spot};
use falc_plc::map::{Coil, Inputs, COILS};
use falc_plc::workstation::{Pace, Plc, PlcCommand, PlcEvent, IDLE_POLL_MS, POLL_MS};
use falc_recipe::commands::RecipeKind;
use falc_recipe::engine::START_CONFIRM_LIMIT;
use rand::rngs::StdRng;
use rand::SeedableRng;
use std::cell::RefCell;
use std::collections::{BTreeMap, VecDeque};
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
/// How long one byte chunk takes on the serial line.
const WIRE: Duration = Duration::from_millis(2);
/// The transport's poll periods (the link's defaults).
const POLL_BUSY: Duration = Duration::from_millis(POLL_MS);
const POLL_IDLE: Duration = Duration::from_millis(IDLE_POLL_MS);
/// Where carriers stand when an order may start.
pub const HOME: [&str; 2] = ["W2", "W2"];
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

/// The welding workstation: its node and its end of the line.
struct WeldingNode {
    /// The node around the robot.
    node: WorkstationNode<Welding, (Node, u64)>,
    link: DncLink,
}

/// The transport workstation: its node and its Modbus link (the poller
/// `falc_node::plc_link` runs as a task).
struct TransportNode {
    /// The node around the PLC.
    node: WorkstationNode<Plc, (Node, u64)>,
    pace: Pace,
    next_poll: Duration,
    done: u64,
    last: Option<Inputs>,
    wrote: bool,
}

/// A cell's order list as `falc-operator` starts it.
fn order_list(view: Shared, source: Shipped, set: RecipeSet) -> OrderList<Shared, Shipped> {
    OrderList::new(
        name(Role::Operator),
        name(Role::Cell),
        source.topology().clone(),
        view,
        source,
        set,
    )
    .clocked_from(EPOCH_MS)
}

/// The cell controller's node as `falc-cell` starts it.
fn cell_node(topology: &Topology) -> CellNode<(Node, u64)> {
    let me = name(Role::Cell);
    let alone = Associations::of(topology, &me).runs_alone();
    CellNode::new(
        me,
        Some(name(Role::Operator)),
        vec![name(Role::Welding), name(Role::Transport)],
        alone,
    )
}

/// A workstation's node as `falc_node::controller_node` starts it.
fn workstation_node<D: Linked>(
    topology: &Topology,
    role: Role,
    kind: RecipeKind,
    confirm_limit: Duration,
    device: D,
) -> WorkstationNode<D, (Node, u64)> {
    let me = name(role);
    let alone = Associations::of(topology, &me).runs_alone();
    WorkstationNode::new(me, kind, confirm_limit, device, alone)
}

fn welding_node(topology: &Topology, now: Duration, timing: Timing) -> WeldingNode {
    let device = Welding::new("sim-serial", &timing);
    let limit = workstation::confirm_limit(&timing);
    let mut node = workstation_node(topology, Role::Welding, RecipeKind::Welding, limit, device);
    node.handle_link(now, LineEvent::Opened);
    WeldingNode {
        node,
        link: DncLink::new(Priority::Low, timing).awaiting_answers(),
    }
}

fn transport_node(topology: &Topology, now: Duration, coils: &[bool]) -> TransportNode {
    let device = Plc::new("sim-plc:502".into());
    let kind = RecipeKind::Transport;
    let mut node = workstation_node(topology, Role::Transport, kind, START_CONFIRM_LIMIT, device);
    let mut held = [false; COILS as usize];
    for (h, c) in held.iter_mut().zip(coils) {
        *h = *c;
    }
    let coils = Some(held);
    node.handle_link(now, PlcEvent::Connected { coils });
    TransportNode {
        node,
        pace: Pace::Idle,
        next_poll: now,
        done: 0,
        last: None,
        wrote: true,
    }
}

/// The station name of `role` (the shipped topologies' names, checked
/// when the world is built).
fn name(role: Role) -> StationName {
    // The four names are valid station names.
    StationName::new(role.station()).unwrap_or_else(|e| unreachable!("{role:?}: {e}"))
}

fn station(n: Node) -> StationName {
    name(n.role)
}

/// The cell topologies of `layout`, each checked to have the stations
/// the simulation drives: an operator over a cell controller over a
/// welding and a transport workstation.
fn cell_topologies(layout: &Layout) -> Result<Vec<Topology>, String> {
    let cells: Vec<Topology> = match layout {
        Layout::Cell(t) => vec![t.clone()],
        Layout::Plant(p) => p.cells().iter().map(|c| c.topology().clone()).collect(),
    };
    for t in &cells {
        let mut names: Vec<&str> = t.stations().iter().map(|s| s.name.as_str()).collect();
        names.sort_unstable();
        let mut want: Vec<&str> = Role::ALL.iter().map(|r| r.station()).collect();
        want.sort_unstable();
        let shape = Role::ALL.iter().skip(1).all(|r| {
            let commander = match r {
                Role::Cell => Role::Operator,
                _ => Role::Cell,
            };
            t.commander_of(&name(*r)) == Some(&name(commander))
        });
        if names != want || !shape {
            return Err(format!(
                "cell {}: the simulation drives an operator over a cell controller `cell` over \
                 `welding` and `transport`; the topology has {}",
                t.cell(),
                names.join(", ")
            ));
        }
    }
    Ok(cells)
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

/// One cell's processes and equipment (the operator's place in it is
/// the plant's).
pub struct CellParts {
    /// Its topology.
    topology: Topology,
    /// The cell controller's node, as `falc-cell` runs it; a ticket is
    /// the indication's sender and id.
    cell: CellNode<(Node, u64)>,
    /// The commander's Starts the cell has not answered yet: their
    /// tickets, and the order each names (counted once answered).
    starting: BTreeMap<(Node, u64), i64>,
    /// The welding workstation.
    welding: WeldingNode,
    /// The transport workstation.
    transport: TransportNode,
    /// The robot controller's twin.
    pub rcm: RcmTwin,
    /// Bytes on the serial line: (arrival, towards the twin, bytes).
    wire: VecDeque<(Duration, bool, Vec<u8>)>,
    /// The serial line is plugged in.
    pub plugged: bool,
    /// The conveyor's twin.
    pub conveyor: Conveyor,
}

impl CellParts {
    fn new(topology: Topology, time_scale: f64, timing: Timing) -> Result<Self, String> {
        let home: Vec<Spot> = HOME.iter().filter_map(|s| Spot::parse(s)).collect();
        let conveyor = Conveyor::new(&home, time_scale)?;
        let now = Duration::ZERO;
        Ok(Self {
            cell: cell_node(&topology),
            starting: BTreeMap::new(),
            welding: welding_node(&topology, now, timing),
            transport: transport_node(&topology, now, conveyor.coils()),
            rcm: RcmTwin::new(Robot::new(Mode::AutomaticExternal, time_scale), timing),
            wire: VecDeque::new(),
            plugged: true,
            conveyor,
            topology,
        })
    }

    /// The cell controller's recipe runtime.
    pub fn controller(&self) -> &Controller<Stations> {
        self.cell.controller()
    }

    /// The welding workstation's recipe runtime (its robot: `.device`).
    pub fn welding(&self) -> &Controller<Welding> {
        self.welding.node.controller()
    }

    /// The transport workstation's recipe runtime (its PLC: `.device`).
    pub fn transport(&self) -> &Controller<Plc> {
        self.transport.node.controller()
    }
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
    pub plant: Plant<Shared, Shipped>,
    /// A second handle on each cell's records and recipe store, for an
    /// operator started again.
    durable: Vec<(Shared, Shipped)>,
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
    /// plant); `seed` drives every random choice.
    pub fn new(layout: &Layout, seed: u64, time_scale: f64, link: Link) -> Result<Self, String> {
        let topologies = cell_topologies(layout)?;
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
            let source = Shipped::new(topology.clone(), name(Role::Cell));
            let set = source.load().map_err(|p| p.join("\n"))?;
            // What the list writes as it starts is stamped at the run's start.
            view.set_now(EPOCH_MS);
            durable.push((view.clone(), source.clone()));
            lists.push(order_list(view, source, set));
            cells.push(CellParts::new(topology, time_scale, timing)?);
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
            for n in Node::all_of(c) {
                w.new_run(n);
            }
            for r in [Role::Cell, Role::Welding, Role::Transport] {
                w.list(c).handle_presence(now, name(r), true);
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
    fn list(&mut self, c: usize) -> &mut OrderList<Shared, Shipped> {
        self.plant
            .list(c)
            .unwrap_or_else(|| unreachable!("the plant has a list per cell"))
    }

    /// Cell `c`'s welding workstation's recipe runtime.
    pub fn welding(&self, c: usize) -> &Controller<Welding> {
        self.part(c).welding()
    }

    /// Cell `c`'s transport workstation's recipe runtime.
    pub fn transport(&self, c: usize) -> &Controller<Plc> {
        self.part(c).transport()
    }

    /// Cell `c`'s order list, to read.
    pub fn order_list(&self, c: usize) -> &OrderList<Shared, Shipped> {
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
            station: station(n),
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
        let cells = self.cells.iter().enumerate().flat_map(|(c, p)| {
            let cell = self.is_running(Node::new(c, Role::Cell));
            [
                p.cell.poll_timeout().filter(|_| cell),
                p.welding.node.poll_timeout(),
                p.welding.link.poll_timeout(),
                p.rcm.poll_timeout(),
                p.wire.iter().map(|w| w.0).min(),
                p.transport.node.poll_timeout(),
                Some(p.transport.next_poll),
                p.conveyor.poll_timeout(),
            ]
        });
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
                    ServiceError::unreachable(format!("no reply from {}: no route", p.to))
                } else {
                    ServiceError::timeout(format!("no confirm from {} in time", p.to))
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
        let cell_runs = self.is_running(Node::new(c, Role::Cell));
        let welding_runs = self.is_running(Node::new(c, Role::Welding));
        let p = self.part_mut(c);
        if cell_runs && p.cell.poll_timeout().is_some_and(|t| t <= now) {
            p.cell.handle_timeout(now);
        }
        if p.welding.node.poll_timeout().is_some_and(|t| t <= now) {
            p.welding.node.handle_timeout(now);
        }
        if p.welding.link.poll_timeout().is_some_and(|t| t <= now) {
            p.welding.link.handle_timeout(now);
        }
        if p.rcm.poll_timeout().is_some_and(|t| t <= now) {
            p.rcm.handle_timeout(now);
        }
        while let Some(i) = p.wire.iter().position(|w| w.0 <= now) {
            let Some((_, to_twin, bytes)) = p.wire.remove(i) else {
                break;
            };
            if !p.plugged {
                continue;
            }
            if to_twin {
                p.rcm.handle_bytes(now, &bytes);
            } else if welding_runs {
                p.welding.link.handle_bytes(now, &bytes);
            }
        }
        if p.transport.node.poll_timeout().is_some_and(|t| t <= now) {
            p.transport.node.handle_timeout(now);
        }
        if p.conveyor.poll_timeout().is_some_and(|t| t <= now) {
            p.conveyor.handle_timeout(now);
        }
        if p.transport.next_poll <= now {
            self.poll_plc(c);
        }
    }

    /// Cell `c`'s transport's Modbus poll: the inputs as the PLC has them,
    /// handed on when they changed or after a write (as
    /// `falc_node::plc_link`).
    fn poll_plc(&mut self, c: usize) {
        let now = self.now;
        let running = self.is_running(Node::new(c, Role::Transport));
        let p = self.part_mut(c);
        let t = &mut p.transport;
        t.next_poll = now
            + match t.pace {
                Pace::Busy => POLL_BUSY,
                Pace::Idle => POLL_IDLE,
            };
        if !running {
            return;
        }
        p.conveyor.handle_timeout(now);
        let inputs = p.conveyor.inputs();
        if t.wrote || t.last != Some(inputs) {
            t.wrote = false;
            t.last = Some(inputs);
            let commands_done = t.done;
            t.node.handle_link(
                now,
                PlcEvent::Inputs {
                    inputs,
                    commands_done,
                },
            );
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
                busy |= self.pump_welding(c);
                busy |= self.pump_transport(c);
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
                let (run, last, holes) = self.order_list(n.cell).filed(&station(*n))?;
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
            station: station(n),
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
            Role::Welding | Role::Transport => &[Node::operator(c), Node::new(c, Role::Cell)],
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
            let (me, cell) = (Node::operator(c), Node::new(c, Role::Cell));
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
                        let delivery =
                            Delivery::new(name(Role::Cell), d.domain, &d.content, d.is_cell);
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
                ListOutput::Say(line) => self.note(format!("operator: {line}")),
                ListOutput::Changed => {}
                ListOutput::ReadReports { station, after } => {
                    if let Some(to) = Node::of(c, &station) {
                        let msg = move |id| Msg::ReadKept { id, after };
                        self.request(me, to, msg, CELL_LIMIT, Waiter::Kept(to));
                    }
                }
            }
        }
    }

    fn pump_cell(&mut self, c: usize) -> bool {
        let me = Node::new(c, Role::Cell);
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
                    let Some(to) = Node::of(c, &cmd.to) else {
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
                CellAction::Ask { id, to, request } => match Node::of(c, &to) {
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
                    self.note(format!("{me}: {name} delivered to {to}"));
                }
                CellAction::Warn(text) => self.note(format!("{me}: {text}")),
                CellAction::Publish(u) => self.publish(me, u),
            }
        }
        any
    }

    /// Carries what cell `c`'s welding node decided: its telegrams over
    /// the 3964R link to the line (as `falc_node::dnc_link`'s task), what
    /// the link reports back to the node, until both are quiet.
    fn pump_welding(&mut self, c: usize) -> bool {
        let me = Node::new(c, Role::Welding);
        if !self.is_running(me) {
            return false;
        }
        let mut any = false;
        let now = self.now;
        loop {
            while let Some(a) = self.part_mut(c).welding.node.poll(now) {
                any = true;
                if let Some(t) = self.carry_workstation(me, a) {
                    self.part_mut(c).welding.link.send(now, t.encode());
                }
            }
            let p = self.part_mut(c);
            let mut more = false;
            while let Some(ev) = p.welding.link.poll_event() {
                more = true;
                p.welding.node.handle_link(now, LineEvent::Link(ev));
            }
            while let Some(bytes) = p.welding.link.poll_transmit() {
                p.wire.push_back((now + WIRE, true, bytes));
            }
            if !more {
                break;
            }
        }
        let p = self.part_mut(c);
        while let Some(bytes) = p.rcm.poll_transmit() {
            p.wire.push_back((now + WIRE, false, bytes));
        }
        let mut troubles = Vec::new();
        while let Some(note) = p.rcm.poll_note() {
            // Each telegram received is too many lines for the trace.
            if let Note::Trouble(why) = note {
                troubles.push(why);
            }
        }
        for why in troubles {
            self.note(format!("rcm{}: {why}", at_cell(c)));
        }
        any
    }

    /// Carries what cell `c`'s transport node decided: its commands to
    /// the conveyor's twin (as `falc_node::plc_link`'s task writes coils
    /// and sets its pace).
    fn pump_transport(&mut self, c: usize) -> bool {
        let me = Node::new(c, Role::Transport);
        if !self.is_running(me) {
            return false;
        }
        let mut any = false;
        let now = self.now;
        while let Some(a) = self.part_mut(c).transport.node.poll(now) {
            any = true;
            let command = self.carry_workstation(me, a);
            let p = self.part_mut(c);
            match command {
                Some(PlcCommand::Write(coil, v)) => {
                    write_coil(&mut p.conveyor, now, coil, v);
                    p.transport.done += 1;
                    p.transport.wrote = true;
                }
                Some(PlcCommand::WriteAll(values)) => {
                    for (o, v) in values.iter().enumerate() {
                        if let Some(coil) = Coil::at(o as u16) {
                            write_coil(&mut p.conveyor, now, coil, *v);
                        }
                    }
                    p.transport.done += 1;
                    p.transport.wrote = true;
                }
                Some(PlcCommand::Pace(pace)) => {
                    p.transport.pace = pace;
                    if pace == Pace::Busy {
                        p.transport.next_poll = p.transport.next_poll.min(now + POLL_BUSY);
                    }
                }
                None => {}
            }
        }
        let p = self.part_mut(c);
        if p.transport.wrote {
            // The link reads right after a write.
            p.transport.next_poll = p.transport.next_poll.min(now + POLL_BUSY);
        }
        let mut notes = Vec::new();
        while let Some(note) = p.conveyor.poll_note() {
            notes.push(note);
        }
        for note in notes {
            self.note(format!("plc{}: {note}", at_cell(c)));
        }
        any
    }

    /// Carries out a workstation's action on the bus (an answer, a
    /// publication, a line for the trace); a command for its device's
    /// link is returned, for the caller to carry.
    fn carry_workstation<C>(
        &mut self,
        at: Node,
        action: WorkstationAction<(Node, u64), C>,
    ) -> Option<C> {
        match action {
            WorkstationAction::Answer {
                ticket: (to, id),
                result,
            } => self.respond(at, to, id, result),
            WorkstationAction::Publish(u) => self.publish(at, u),
            WorkstationAction::Event(line) => self.note(format!("{at}: {line}")),
            WorkstationAction::Command(c) => return Some(c),
        }
        None
    }

    /// A publication the bus carried to `to`, taken in.
    fn heard(&mut self, now: Duration, to: Node, p: Publication) {
        match to.role {
            Role::Operator => self.list(to.cell).handle_heard(now, p.stamp, p.message),
            Role::Cell => self
                .part_mut(to.cell)
                .cell
                .handle_publication(now, &p.message),
            _ => {}
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
                    let e = ServiceError::unreachable(format!("no reply from {to}"));
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
                    let kept = heard::take_kept(&station(n), kept).map_err(|e| e.to_string());
                    self.list(n.cell).handle_kept_reports(now, station(n), kept);
                }
            }
            // What a receiver takes in, as on the bus: the sender is the
            // station it came from, texts bounded.
            (to, Msg::Publish(p)) => {
                if let Ok((p, _)) = heard::take_publication(&station(a.from), p) {
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
                self.list(n.cell)
                    .handle_kept_reports(now, station(n), Err(why));
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
            Waiter::Cell(c, ..) | Waiter::Pass(c, _) => Node::new(*c, Role::Cell),
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
        let Some(to) = Node::of(c, &sub) else {
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
        let Some(to) = Node::of(from.cell, delivery.to()) else {
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
            let what = format!(
                "the delivery of {name} to {} was confirmed, but {} does not hold it whole",
                d.to, d.to
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
                Serve::Initiate { to, request, limit } => match Node::of(c, &to) {
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
                    if let Some(to) = Node::of(c, &to) {
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
                    Role::Welding => {
                        self.part_mut(c)
                            .welding
                            .node
                            .handle_indication(now, (from, id), &request)
                    }
                    Role::Transport => {
                        self.part_mut(c).transport.node.handle_indication(
                            now,
                            (from, id),
                            &request,
                        );
                    }
                },
                Serve::Associated(p) => {
                    self.note(format!("{at}: associated with {}", p.station));
                    let parts = self.part_mut(c);
                    match at.role {
                        Role::Cell => parts.cell.handle_associated(now),
                        Role::Welding => parts.welding.node.handle_associated(now),
                        Role::Transport => parts.transport.node.handle_associated(now),
                        Role::Operator => {}
                    }
                }
                Serve::Abort(ind) => {
                    let (name, role) = (&ind.peer.station, ind.role);
                    match at.role {
                        Role::Cell => self.part_mut(c).cell.handle_abort(now, name, role),
                        Role::Welding => {
                            self.part_mut(c).welding.node.handle_abort(now, name, role)
                        }
                        Role::Transport => self
                            .part_mut(c)
                            .transport
                            .node
                            .handle_abort(now, name, role),
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
        self.note(format!("{}: order {n} started", Node::new(c, Role::Cell)));
        if let Some(what) = self.lacking(c).filter(|_| self.started_lacking.is_none()) {
            self.note(what.clone());
            self.started_lacking = Some(format!(
                "order {n} started at {} while {what}",
                Node::new(c, Role::Cell)
            ));
        }
    }

    /// A workstation of cell `c` associated with its cell controller that
    /// lacks a recipe the controller holds for it (or holds another
    /// version), said.
    fn lacking(&self, c: usize) -> Option<String> {
        let cell = self.part(c).controller().vmd();
        let assoc = self
            .ups
            .get(&Node::new(c, Role::Cell))?
            .serving
            .associations();
        for ws in [Node::new(c, Role::Welding), Node::new(c, Role::Transport)] {
            if !self.is_running(ws) || assoc.subordinate(&station(ws)) != Some(&self.peer(ws)) {
                continue;
            }
            for d in cell.domains() {
                let Some((to, name)) = workstation_domain(d.name()) else {
                    continue;
                };
                if to == station(ws) && !self.holds(ws, &name, content_hash(d.content())) {
                    return Some(format!("{ws} lacks its recipe {name}"));
                }
            }
        }
        None
    }

    /// Whether node `n`'s VMD holds domain `name` whole (loaded) with
    /// content hash `hash`.
    fn holds(&self, n: Node, name: &ObjectName, hash: u64) -> bool {
        let p = self.part(n.cell);
        let vmd = match n.role {
            Role::Cell => p.controller().vmd(),
            Role::Welding => p.welding().vmd(),
            Role::Transport => p.transport().vmd(),
            Role::Operator => return false,
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
        self.note(format!("bus: {n} {}", if cut { "cut off" } else { "back" }));
        if cut {
            let at = self.now + self.lease;
            self.leases.push((at, Parting::Node(n)));
        } else {
            self.back(n);
        }
        self.pump();
    }

    /// Cell `c`'s uplink to the factory router is cut (or joined again):
    /// the cell runs on, parted from the operator.
    pub fn cut_uplink(&mut self, c: usize, cut: bool) {
        self.bus.set_uplink_cut(c, cut);
        let what = if cut { "cut" } else { "back" };
        self.note(format!("bus: cell {} uplink {what}", self.cell_id(c)));
        if cut {
            let at = self.now + self.lease;
            self.leases.push((at, Parting::Uplink(c)));
        } else {
            self.parted_cells.remove(&c);
            self.seen_again(c);
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
        for r in [Role::Cell, Role::Welding, Role::Transport] {
            self.present(Node::new(c, r));
        }
    }

    /// The operator's list of `n`'s cell sees `n` present, if it reaches
    /// it and `n` runs.
    fn present(&mut self, n: Node) {
        let now = self.now;
        if self.bus.reachable(Node::operator(n.cell), n) && self.is_running(n) {
            self.list(n.cell).handle_presence(now, station(n), true);
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
                    p.to
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
        self.note(format!("bus: {n} lost"));
        for p in self.places(n) {
            self.finalize(p);
        }
        let reason = format!("no connection with {n}");
        let cells: Vec<usize> = match n.role {
            Role::Operator => (0..self.cells.len()).collect(),
            _ => vec![n.cell],
        };
        for c in cells {
            let (op, cell) = (Node::operator(c), Node::new(c, Role::Cell));
            if n.is_operator() || n == cell {
                self.sees_lost(cell, op, &reason);
                self.sees_lost(op, cell, &reason);
            }
            let seen = match n.role {
                Role::Operator => vec![Role::Cell, Role::Welding, Role::Transport],
                other => vec![other],
            };
            for s in seen {
                self.list(c).handle_presence(now, name(s), false);
            }
            for ws in [Node::new(c, Role::Welding), Node::new(c, Role::Transport)] {
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
        let (op, cell) = (Node::operator(c), Node::new(c, Role::Cell));
        let reason = format!("no connection with cell {}", self.cell_id(c));
        self.sees_lost(cell, op, &reason);
        self.sees_lost(op, cell, &reason);
        for r in [Role::Cell, Role::Welding, Role::Transport] {
            self.list(c).handle_presence(now, name(r), false);
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

    /// Random bytes on cell `c`'s serial line, towards both ends.
    pub fn noise(&mut self, c: usize, bytes: Vec<u8>) {
        let at = self.now + WIRE;
        self.note(format!(
            "serial{}: {} bytes of noise",
            at_cell(c),
            bytes.len()
        ));
        let p = self.part_mut(c);
        p.wire.push_back((at, true, bytes.clone()));
        p.wire.push_back((at, false, bytes));
    }

    /// Node `n`'s process dies: only the twins' state survives (and the
    /// operator's records).
    pub fn crash(&mut self, n: Node) {
        self.note(format!("{n}: process killed"));
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
            let reason = format!("no connection with {n}");
            for p in &places {
                self.finalize(*p);
                self.sees_lost(Node::new(p.cell, Role::Cell), *p, &reason);
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
        let p = self.part_mut(n.cell);
        match n.role {
            Role::Welding => p.welding.node.set_recipe_memory(bytes),
            Role::Transport => p.transport.node.set_recipe_memory(bytes),
            Role::Operator | Role::Cell => {}
        }
    }

    /// Node `n` starts again: empty, but for the operator's records.
    pub fn restart(&mut self, n: Node) {
        let now = self.now;
        self.note(format!("{n}: process started again"));
        let timing = self.timing;
        let p = self.part_mut(n.cell);
        match n.role {
            Role::Welding => {
                p.welding = welding_node(&p.topology, now, timing);
                p.wire.retain(|w| w.1);
            }
            Role::Cell => {
                p.cell = cell_node(&p.topology);
                p.starting.clear();
            }
            Role::Operator => {
                self.restart_operator();
                return;
            }
            Role::Transport => {
                p.transport = transport_node(&p.topology, now, p.conveyor.coils());
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
            let mut list = order_list(view, source, set);
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

/// ` at cell c` for cells past the first, for the trace.
fn at_cell(c: usize) -> String {
    match c {
        0 => String::new(),
        c => format!("@{c}"),
    }
}

/// Writes `coil` on the conveyor's twin.
fn write_coil(conveyor: &mut Conveyor, now: Duration, coil: Coil, v: bool) {
    if let Some(o) = coil.offset() {
        conveyor.write_coil(now, o, v);
    }
}
