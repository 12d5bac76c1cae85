//! The whole cell wired together on one virtual clock: the operator's
//! order list (records in memory), the cell controller, both workstations
//! with their devices, the robot controller's twin behind a serial line
//! with the 3964R procedure at both ends, and the conveyor's twin behind
//! the I/O map. Every core is the one the nodes run; this module is their
//! driver, as `falc_node` is on the real bus.
//!
//! [`World::step`] advances the clock to the next thing due and handles
//! everything due then; what the cores put out is carried to where it
//! goes at once (and arrives after the bus's latency).

use crate::bus::{Arrival, Bus, Link, Msg, Node};
use crate::recipes::Shipped;
use falc_control::cell_node::{CellAction, CellNode};
use falc_control::controller::Controller;
use falc_control::coordination::{workstation_domain, Awaiting, Reply};
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
use falc_model::ids::{ObjectName, StationName};
use falc_model::mms::association::Associations;
use falc_model::mms::delivery::{Delivery, DeliveryStep, STEP_LIMIT};
use falc_model::mms::domain::{content_hash, DomainState};
use falc_model::mms::error::ServiceError;
use falc_model::mms::heard;
use falc_model::mms::journal::{Publication, ReportLog, ReportsAsked};
use falc_model::mms::pdu::{Peer, Request, Response, Unconfirmed};
use falc_model::mms::serving::{Action as Serve, Serving};
use falc_model::mms::vmd::RECIPE_MEMORY;
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
    /// The order list's cell call.
    List,
    /// The cell's request to a station or its operator (on that
    /// station's lane).
    Cell(StationName, Awaiting),
    /// The order list's read of what a station kept.
    Kept(Node),
    /// A station's Initiate of its subordinate (for its [`Serving`]).
    Initiate(Node, StationName),
    /// A step of delivery `n` ([`World::deliveries`]).
    Delivery(u64),
    /// The operator's Initiate of its cell, the root's ([`World::associate`]).
    Associate(StationName),
    /// A workstation's confirm of what the cell's pass-on asked (its id).
    Pass(u64),
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
    /// The order list (its delivery to the cell).
    List,
    /// The cell's pass-on ([`PassOn::handle_delivered`] with this id).
    Pass(u64),
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

/// The operator's order list as `falc-operator` starts it.
fn order_list(view: Shared, source: Shipped, set: RecipeSet) -> OrderList<Shared, Shipped> {
    OrderList::new(
        station(Node::Operator),
        station(Node::Cell),
        source.topology().clone(),
        view,
        source,
        set,
    )
    .clocked_from(EPOCH_MS)
}

/// The cell controller's node as `falc-cell` starts it.
fn cell_node(topology: &Topology) -> CellNode<(Node, u64)> {
    let me = station(Node::Cell);
    let alone = Associations::of(topology, &me).runs_alone();
    CellNode::new(
        me,
        Some(station(Node::Operator)),
        vec![station(Node::Welding), station(Node::Transport)],
        alone,
    )
}

/// Workstation `n`'s node as `falc_node::controller_node` starts it.
fn workstation_node<D: Linked>(
    topology: &Topology,
    n: Node,
    kind: RecipeKind,
    confirm_limit: Duration,
    device: D,
) -> WorkstationNode<D, (Node, u64)> {
    let me = station(n);
    let alone = Associations::of(topology, &me).runs_alone();
    WorkstationNode::new(me, kind, confirm_limit, device, alone)
}

fn welding_node(topology: &Topology, now: Duration, timing: Timing) -> WeldingNode {
    let device = Welding::new("sim-serial", &timing);
    let limit = workstation::confirm_limit(&timing);
    let mut node = workstation_node(topology, Node::Welding, RecipeKind::Welding, limit, device);
    node.handle_link(now, LineEvent::Opened);
    WeldingNode {
        node,
        link: DncLink::new(Priority::Low, timing).awaiting_answers(),
    }
}

fn transport_node(topology: &Topology, now: Duration, coils: &[bool]) -> TransportNode {
    let device = Plc::new("sim-plc:502".into());
    let kind = RecipeKind::Transport;
    let mut node = workstation_node(topology, Node::Transport, kind, START_CONFIRM_LIMIT, device);
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

fn station(n: Node) -> StationName {
    // The four names are valid station names.
    StationName::new(n.station()).unwrap_or_else(|e| unreachable!("{n}: {e}"))
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

/// The whole cell.
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
    /// own is a plant of one (its order list: [`Self::order_list`]).
    pub plant: Plant<Shared, Shipped>,
    /// A second handle on the records and the recipe store, for an
    /// operator started again.
    durable: (Shared, Shipped),
    /// Console requests up to this ticket that were not answered when the
    /// operator died are refused (its API went with it).
    lost_before: u64,
    tickets: u64,
    /// Console answers not taken yet.
    replies: BTreeMap<Ticket, ApiResult>,
    /// The cell's indications at the operator: ticket → request id.
    indications: BTreeMap<Ticket, u64>,
    /// The cell controller's node, as `falc-cell` runs it; a ticket is
    /// the indication's sender and id.
    pub cell: CellNode<(Node, u64)>,
    /// The commander's Starts the cell has not answered yet: their
    /// tickets, and the order each names (counted once answered).
    starting: BTreeMap<(Node, u64), i64>,
    /// The cell's stations.
    topology: Topology,
    /// How long a silent peer is still taken for present (the topology's).
    lease: Duration,
    /// The welding workstation.
    welding: WeldingNode,
    /// The transport workstation.
    transport: TransportNode,
    /// Each node's process and associations.
    ups: BTreeMap<Node, Up>,
    /// The robot controller's twin.
    pub rcm: RcmTwin,
    /// Bytes on the serial line: (arrival, towards the twin, bytes).
    wire: VecDeque<(Duration, bool, Vec<u8>)>,
    /// The serial line is plugged in.
    pub plugged: bool,
    /// The conveyor's twin.
    pub conveyor: Conveyor,
    timing: Timing,
    pending: BTreeMap<u64, Pending>,
    next_id: u64,
    /// Deliveries under way, by number.
    deliveries: BTreeMap<u64, Delivering>,
    /// Abort indications due when a lease runs out: (when, node).
    leases: Vec<(Duration, Node)>,
    /// Nodes cut off whose lease ran out: parted from the router until
    /// joined again.
    parted: std::collections::BTreeSet<Node>,
    /// Cell-level Starts confirmed, per order id.
    pub starts: BTreeMap<i64, u32>,
    /// The first order started more than once, and how often.
    pub started_twice: Option<(i64, u32)>,
    /// The first order the cell started while a workstation lacked a
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

impl World {
    /// A cell at rest at time zero, the twins at `time_scale`, the bus
    /// with `link` for every node; `seed` drives every random choice.
    pub fn new(seed: u64, time_scale: f64, link: Link) -> Result<Self, String> {
        let topology = Topology::parse(TOPOLOGY, "launch/cell.toml").map_err(|e| e.to_string())?;
        let source = Shipped::new(topology.clone(), station(Node::Cell));
        let set = source.load().map_err(|p| p.join("\n"))?;
        let mut views = plant(&[topology.cell().as_str()]);
        let mut view = views.pop().ok_or("no records")?;
        // What the list writes as it starts is stamped at the run's start.
        view.set_now(EPOCH_MS);
        let records = view.all.clone();
        let durable = (view.clone(), source.clone());
        let list = order_list(view, source, set);
        let timing = Timing::default();
        let home: Vec<Spot> = HOME.iter().filter_map(|s| Spot::parse(s)).collect();
        let conveyor = Conveyor::new(&home, time_scale)?;
        let now = Duration::ZERO;
        let transport = transport_node(&topology, now, conveyor.coils());
        let cell = cell_node(&topology);
        let mut w = Self {
            now,
            steps: 0,
            rng: StdRng::seed_from_u64(seed),
            bus: Bus::new(link),
            records,
            plant: Plant::new(vec![list]),
            durable,
            lost_before: 0,
            tickets: 0,
            replies: BTreeMap::new(),
            indications: BTreeMap::new(),
            cell,
            starting: BTreeMap::new(),
            lease: topology.lease(),
            welding: welding_node(&topology, now, timing),
            transport,
            ups: BTreeMap::new(),
            rcm: RcmTwin::new(Robot::new(Mode::AutomaticExternal, time_scale), timing),
            wire: VecDeque::new(),
            plugged: true,
            conveyor,
            timing,
            pending: BTreeMap::new(),
            next_id: 0,
            deliveries: BTreeMap::new(),
            leases: Vec::new(),
            parted: Default::default(),
            starts: BTreeMap::new(),
            started_twice: None,
            false_delivery: None,
            started_lacking: None,
            memory: BTreeMap::new(),
            trace: VecDeque::new(),
            kept: BTreeMap::new(),
            runs: 0,
            topology,
        };
        for n in Node::ALL {
            w.new_run(n);
        }
        for n in [Node::Cell, Node::Welding, Node::Transport] {
            w.list().handle_presence(now, station(n), true);
        }
        w.pump();
        Ok(w)
    }

    /// The cell's order list in the operator's plant.
    fn list(&mut self) -> &mut OrderList<Shared, Shipped> {
        self.plant
            .list(0)
            .unwrap_or_else(|| unreachable!("a plant of one cell has its list"))
    }

    /// The welding workstation's recipe runtime (its robot: `.device`).
    pub fn welding(&self) -> &Controller<Welding> {
        self.welding.node.controller()
    }

    /// The transport workstation's recipe runtime (its PLC: `.device`).
    pub fn transport(&self) -> &Controller<Plc> {
        self.transport.node.controller()
    }

    /// The cell's order list, to read.
    pub fn order_list(&self) -> &OrderList<Shared, Shipped> {
        self.plant
            .list_at(0)
            .unwrap_or_else(|| unreachable!("a plant of one cell has its list"))
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

    /// A console request as `user`; its answer comes later ([`Self::reply`]).
    pub fn api(&mut self, user: &str, request: ApiRequest) -> Ticket {
        self.tickets += 1;
        let t = Ticket(self.tickets);
        self.note(format!("console {user}: {request:?}"));
        match StationName::new(user) {
            Ok(_) if !self.is_running(Node::Operator) => {
                self.replies.insert(t, Err(NO_OPERATOR.into()));
            }
            Ok(u) => {
                let now = self.now;
                self.plant.handle_api(now, t, &u, None, request);
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

    /// When something is next due.
    fn next_due(&self) -> Option<Duration> {
        let mut t = [
            self.bus.poll_timeout(),
            self.plant
                .poll_timeout()
                .filter(|_| self.is_running(Node::Operator)),
            self.cell
                .poll_timeout()
                .filter(|_| self.is_running(Node::Cell)),
            self.welding.node.poll_timeout(),
            self.welding.link.poll_timeout(),
            self.rcm.poll_timeout(),
            self.wire.iter().map(|w| w.0).min(),
            self.transport.node.poll_timeout(),
            Some(self.transport.next_poll),
            self.conveyor.poll_timeout(),
            self.pending.values().map(|p| p.deadline).min(),
            self.leases.iter().map(|l| l.0).min(),
        ]
        .into_iter()
        .flatten()
        .min();
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
        let due: Vec<Node> = self
            .leases
            .iter()
            .filter(|l| l.0 <= now)
            .map(|l| l.1)
            .collect();
        self.leases.retain(|l| l.0 > now);
        for n in due {
            if self.bus.is_cut(n) {
                self.parted.insert(n);
                self.lost(n);
            }
        }
        // Clocks.
        if self.is_running(Node::Operator) && self.plant.poll_timeout().is_some_and(|t| t <= now) {
            self.plant.handle_timeout(now);
        }
        if self.is_running(Node::Cell) && self.cell.poll_timeout().is_some_and(|t| t <= now) {
            self.cell.handle_timeout(now);
        }
        if self.welding.node.poll_timeout().is_some_and(|t| t <= now) {
            self.welding.node.handle_timeout(now);
        }
        if self.welding.link.poll_timeout().is_some_and(|t| t <= now) {
            self.welding.link.handle_timeout(now);
        }
        if self.rcm.poll_timeout().is_some_and(|t| t <= now) {
            self.rcm.handle_timeout(now);
        }
        while let Some(i) = self.wire.iter().position(|w| w.0 <= now) {
            let Some((_, to_twin, bytes)) = self.wire.remove(i) else {
                break;
            };
            if !self.plugged {
                continue;
            }
            if to_twin {
                self.rcm.handle_bytes(now, &bytes);
            } else if self.is_running(Node::Welding) {
                self.welding.link.handle_bytes(now, &bytes);
            }
        }
        if self.transport.node.poll_timeout().is_some_and(|t| t <= now) {
            self.transport.node.handle_timeout(now);
        }
        if self.conveyor.poll_timeout().is_some_and(|t| t <= now) {
            self.conveyor.handle_timeout(now);
        }
        if self.transport.next_poll <= now {
            self.poll_plc();
        }
        self.pump();
    }

    /// The transport's Modbus poll: the inputs as the PLC has them, handed
    /// on when they changed or after a write (as `falc_node::plc_link`).
    fn poll_plc(&mut self) {
        let now = self.now;
        let running = self.is_running(Node::Transport);
        let t = &mut self.transport;
        t.next_poll = now
            + match t.pace {
                Pace::Busy => POLL_BUSY,
                Pace::Idle => POLL_IDLE,
            };
        if !running {
            return;
        }
        self.conveyor.handle_timeout(now);
        let inputs = self.conveyor.inputs();
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
        // The order list's outputs all go on the bus: once is enough.
        self.pump_list();
        for _ in 0..64 {
            let mut busy = self.pump_cell();
            busy |= self.pump_welding();
            busy |= self.pump_transport();
            if !busy {
                return;
            }
        }
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
        let parted = self.parted.contains(&from) || self.parted.contains(&to);
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

    /// The stations whose reports the order list has not all filed: each
    /// running station's current run, as far as the list heard it, must be
    /// filed up to its last report (what a cut kept read back).
    pub fn unfiled(&self) -> Vec<String> {
        if !self.is_running(Node::Operator) {
            return Vec::new();
        }
        self.kept
            .iter()
            .filter(|(n, _)| self.is_running(**n))
            .filter_map(|(n, log)| {
                let (run, last, holes) = self.order_list().filed(&station(*n))?;
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
            serving: Serving::of(&self.topology, me),
        };
        self.ups.insert(n, up);
        if n != Node::Operator {
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
        let to: &[Node] = match from {
            Node::Welding | Node::Transport => &[Node::Operator, Node::Cell],
            Node::Cell => &[Node::Operator],
            Node::Operator => &[],
        };
        let now = self.now;
        for t in to {
            self.bus
                .send(now, from, *t, Msg::Publish(u.clone()), &mut self.rng);
        }
    }

    fn pump_list(&mut self) {
        if !self.is_running(Node::Operator) {
            return;
        }
        while let Some(out) = self.plant.poll_output() {
            let out = match out {
                PlantOutput::Reply { ticket, result } => {
                    self.replies.insert(ticket, *result);
                    continue;
                }
                PlantOutput::Cell(_, out) => out,
            };
            match out {
                ListOutput::Cell(CellCall::Associate) => self.associate(),
                ListOutput::Cell(call) => match call.request(&self.peer(Node::Operator)) {
                    Ok(request) => self.request(
                        Node::Operator,
                        Node::Cell,
                        |id| Msg::Request { id, request },
                        CELL_LIMIT,
                        Waiter::List,
                    ),
                    Err(d) => {
                        let delivery =
                            Delivery::new(station(Node::Cell), d.domain, &d.content, d.is_cell);
                        self.deliver(Node::Operator, delivery, Then::List);
                    }
                },
                ListOutput::Respond { ticket, result } => {
                    if let Some(id) = self.indications.remove(&ticket) {
                        self.respond(Node::Operator, Node::Cell, id, result);
                    }
                }
                ListOutput::Forget(ticket) => {
                    // Dropped unanswered: zenoh ends a query whose
                    // responder is dropped with no reply, at once.
                    if let Some(id) = self.indications.remove(&ticket) {
                        let e = ServiceError::unreachable("no reply to the question (dropped)");
                        self.respond(Node::Operator, Node::Cell, id, Err(e));
                    }
                }
                ListOutput::Say(line) => self.note(format!("operator: {line}")),
                ListOutput::Changed => {}
                ListOutput::ReadReports { station, after } => {
                    if let Some(to) = Node::of(&station) {
                        let msg = move |id| Msg::ReadKept { id, after };
                        self.request(Node::Operator, to, msg, CELL_LIMIT, Waiter::Kept(to));
                    }
                }
            }
        }
    }

    fn pump_cell(&mut self) -> bool {
        if !self.is_running(Node::Cell) {
            return false;
        }
        let mut any = false;
        while let Some(action) = self.cell.poll(self.now) {
            any = true;
            match action {
                CellAction::Request(cmd) => {
                    let Some(to) = Node::of(&cmd.to) else {
                        let e = ServiceError::unreachable(format!("no station {}", cmd.to));
                        let reply = Reply {
                            awaiting: cmd.awaiting,
                            result: Err(e),
                        };
                        self.cell.handle_reply(self.now, &cmd.to, reply);
                        continue;
                    };
                    let request = cmd.request;
                    self.request(
                        Node::Cell,
                        to,
                        |id| Msg::Request { id, request },
                        cmd.limit,
                        Waiter::Cell(cmd.to, cmd.awaiting),
                    );
                }
                CellAction::Answer {
                    ticket: (to, id),
                    result,
                } => {
                    if let (Some(n), true) = (self.starting.remove(&(to, id)), result.is_ok()) {
                        self.started(n);
                    }
                    self.respond(Node::Cell, to, id, result)
                }
                CellAction::Ask { id, to, request } => match Node::of(&to) {
                    Some(ws) => self.request(
                        Node::Cell,
                        ws,
                        |id| Msg::Request { id, request },
                        PASS_LIMIT,
                        Waiter::Pass(id),
                    ),
                    None => {
                        let e = ServiceError::unreachable(format!("no station {to}"));
                        self.cell.handle_confirm(id, Err(e));
                    }
                },
                CellAction::Deliver { id, delivery } => {
                    self.deliver(Node::Cell, delivery, Then::Pass(id));
                }
                CellAction::Delivered { to, name } => {
                    self.note(format!("cell: {name} delivered to {to}"));
                }
                CellAction::Warn(text) => self.note(format!("cell: {text}")),
                CellAction::Publish(u) => self.publish(Node::Cell, u),
            }
        }
        any
    }

    /// Carries what the welding node decided: its telegrams over the
    /// 3964R link to the line (as `falc_node::dnc_link`'s task), what the
    /// link reports back to the node, until both are quiet.
    fn pump_welding(&mut self) -> bool {
        if !self.is_running(Node::Welding) {
            return false;
        }
        let mut any = false;
        let now = self.now;
        loop {
            while let Some(a) = self.welding.node.poll(now) {
                any = true;
                if let Some(t) = self.carry_workstation(Node::Welding, a) {
                    self.welding.link.send(now, t.encode());
                }
            }
            let mut more = false;
            while let Some(ev) = self.welding.link.poll_event() {
                more = true;
                self.welding.node.handle_link(now, LineEvent::Link(ev));
            }
            while let Some(bytes) = self.welding.link.poll_transmit() {
                self.wire.push_back((now + WIRE, true, bytes));
            }
            if !more {
                break;
            }
        }
        while let Some(bytes) = self.rcm.poll_transmit() {
            self.wire.push_back((now + WIRE, false, bytes));
        }
        while let Some(note) = self.rcm.poll_note() {
            // Each telegram received is too many lines for the trace.
            if let Note::Trouble(why) = note {
                self.note(format!("rcm: {why}"));
            }
        }
        any
    }

    /// Carries what the transport node decided: its commands to the
    /// conveyor's twin (as `falc_node::plc_link`'s task writes coils and
    /// sets its pace).
    fn pump_transport(&mut self) -> bool {
        if !self.is_running(Node::Transport) {
            return false;
        }
        let mut any = false;
        let now = self.now;
        while let Some(a) = self.transport.node.poll(now) {
            any = true;
            match self.carry_workstation(Node::Transport, a) {
                Some(PlcCommand::Write(coil, v)) => {
                    self.write_coil(coil, v);
                    self.transport.done += 1;
                    self.transport.wrote = true;
                }
                Some(PlcCommand::WriteAll(values)) => {
                    for (o, v) in values.iter().enumerate() {
                        if let Some(coil) = Coil::at(o as u16) {
                            self.write_coil(coil, *v);
                        }
                    }
                    self.transport.done += 1;
                    self.transport.wrote = true;
                }
                Some(PlcCommand::Pace(p)) => {
                    self.transport.pace = p;
                    if p == Pace::Busy {
                        self.transport.next_poll = self.transport.next_poll.min(now + POLL_BUSY);
                    }
                }
                None => {}
            }
        }
        if self.transport.wrote {
            // The link reads right after a write.
            self.transport.next_poll = self.transport.next_poll.min(now + POLL_BUSY);
        }
        while let Some(note) = self.conveyor.poll_note() {
            self.note(format!("plc: {note}"));
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

    fn write_coil(&mut self, coil: Coil, v: bool) {
        if let Some(o) = coil.offset() {
            let now = self.now;
            self.conveyor.write_coil(now, o, v);
        }
    }

    /// A publication the bus carried to `to`, taken in.
    fn heard(&mut self, now: Duration, to: Node, p: Publication) {
        match to {
            Node::Operator => self.list().handle_heard(now, p.stamp, p.message),
            Node::Cell => self.cell.handle_publication(now, &p.message),
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
                    self.list().handle_kept_reports(now, station(n), kept);
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
            Waiter::List => self.list().handle_cell_answer(now, result),
            Waiter::Cell(to, awaiting) => {
                self.cell.handle_reply(now, &to, Reply { awaiting, result });
            }
            Waiter::Kept(n) => {
                let why = result.err().map_or_else(String::new, |e| e.to_string());
                self.list().handle_kept_reports(now, station(n), Err(why));
            }
            Waiter::Delivery(n) => {
                if let Some(d) = self.deliveries.get_mut(&n) {
                    let step = d.delivery.answered(result);
                    self.delivery_step(n, step);
                }
            }
            Waiter::Pass(id) => self.cell.handle_confirm(id, result),
            Waiter::Associate(sub) => {
                let made = self
                    .up(Node::Operator)
                    .map(|u| u.serving.record_initiates(vec![(sub, result)]));
                self.carry_serving(Node::Operator);
                let answer = match made {
                    Some(Ok(_)) => Ok(Response::Done),
                    Some(Err(e)) => Err(e),
                    None => Err(ServiceError::unreachable("the operator is not running")),
                };
                self.list().handle_cell_answer(now, answer);
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
            Waiter::List | Waiter::Kept(_) => Node::Operator,
            Waiter::Cell(..) | Waiter::Pass(_) => Node::Cell,
            Waiter::Initiate(at, _) => *at,
            Waiter::Associate(_) => Node::Operator,
            Waiter::Delivery(n) => self.deliveries.get(n).map_or(Node::Operator, |d| d.from),
        }
    }

    /// The operator associates its cell, as `falc-operator`'s station does
    /// as the root: the Initiates its [`Serving`] sends (a cell's operator
    /// has one subordinate, the cell), recorded once confirmed.
    fn associate(&mut self) {
        let due = self
            .up(Node::Operator)
            .map(|u| u.serving.initiates())
            .unwrap_or_default();
        let Some((sub, limit)) = due.into_iter().next() else {
            let e = ServiceError::undefined("the operator commands no cell in the topology");
            let now = self.now;
            self.list().handle_cell_answer(now, Err(e));
            return;
        };
        let Some(to) = Node::of(&sub) else {
            let e = ServiceError::unreachable(format!("no station {sub}"));
            let now = self.now;
            self.list().handle_cell_answer(now, Err(e));
            return;
        };
        let request = Request::Initiate {
            calling: self.peer(Node::Operator),
        };
        let msg = |id| Msg::Request { id, request };
        self.request(Node::Operator, to, msg, limit, Waiter::Associate(sub));
    }

    /// Starts `delivery` from `from`; its outcome goes to `then`.
    fn deliver(&mut self, from: Node, delivery: Delivery, then: Then) {
        let Some(to) = Node::of(delivery.to()) else {
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
        if d.to == Node::Operator || !self.is_running(d.to) || self.peer(d.to).session != d.session
        {
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
            Then::List => {
                let now = self.now;
                self.list()
                    .handle_cell_answer(now, result.map(|()| Response::Done));
            }
            Then::Pass(id) => self.cell.handle_delivered(id, result),
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
        while let Some(action) = self
            .up(at)
            .filter(|u| u.running)
            .and_then(|u| u.serving.poll())
        {
            match action {
                Serve::Respond((to, id), result) => self.respond(at, to, id, result),
                Serve::Initiate { to, request, limit } => match Node::of(&to) {
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
                    if let Some(to) = Node::of(&to) {
                        self.next_id += 1;
                        let id = self.next_id;
                        self.bus
                            .send(now, at, to, Msg::Request { id, request }, &mut self.rng);
                    }
                }
                Serve::Watch(_) | Serve::Unwatch(_) | Serve::Concluded(_) => {}
                Serve::Indication((from, id), request) => match at {
                    // The cell's questions and lines, for the order list.
                    Node::Operator => {
                        self.tickets += 1;
                        let t = Ticket(self.tickets);
                        self.indications.insert(t, id);
                        self.list().handle_cell_request(now, t, request);
                    }
                    Node::Cell => {
                        if let Request::Start { argument, .. } = &request {
                            // Watched for the invariant: counted once answered.
                            if let Some(n) = order_of(argument) {
                                self.starting.insert((from, id), n);
                            }
                        }
                        self.cell.handle_indication((from, id), request);
                    }
                    Node::Welding => self
                        .welding
                        .node
                        .handle_indication(now, (from, id), &request),
                    Node::Transport => {
                        self.transport
                            .node
                            .handle_indication(now, (from, id), &request);
                    }
                },
                Serve::Associated(p) => {
                    self.note(format!("{at}: associated with {}", p.station));
                    match at {
                        Node::Cell => self.cell.handle_associated(now),
                        Node::Welding => self.welding.node.handle_associated(now),
                        Node::Transport => self.transport.node.handle_associated(now),
                        Node::Operator => {}
                    }
                }
                Serve::Abort(ind) => {
                    let (name, role) = (&ind.peer.station, ind.role);
                    match at {
                        Node::Cell => self.cell.handle_abort(now, name, role),
                        Node::Welding => self.welding.node.handle_abort(now, name, role),
                        Node::Transport => self.transport.node.handle_abort(now, name, role),
                        Node::Operator => self.list().handle_abort(now, &ind.reason),
                    }
                }
            }
        }
    }

    /// The cell answered its commander's Start of order `n`: counted.
    fn started(&mut self, n: i64) {
        let count = self.starts.entry(n).or_default();
        *count += 1;
        if *count > 1 && self.started_twice.is_none() {
            self.started_twice = Some((n, *count));
        }
        self.note(format!("cell: order {n} started"));
        if let Some(what) = self.lacking().filter(|_| self.started_lacking.is_none()) {
            self.note(what.clone());
            self.started_lacking = Some(format!("order {n} started at the cell while {what}"));
        }
    }

    /// A workstation associated with the cell that lacks a recipe the
    /// cell holds for it (or holds another version), said.
    fn lacking(&self) -> Option<String> {
        let cell = self.cell.controller().vmd();
        let assoc = self.ups.get(&Node::Cell)?.serving.associations();
        for ws in [Node::Welding, Node::Transport] {
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
        let vmd = match n {
            Node::Cell => self.cell.controller().vmd(),
            Node::Welding => self.welding().vmd(),
            Node::Transport => self.transport().vmd(),
            Node::Operator => return false,
        };
        vmd.domain(name).is_some_and(|d| {
            matches!(d.state(), DomainState::Ready | DomainState::InUse)
                && content_hash(d.content()) == hash
        })
    }

    /// `n`'s link to the router is cut (or joined again).
    pub fn cut(&mut self, n: Node, cut: bool) {
        self.bus.set_cut(n, cut);
        self.note(format!("bus: {n} {}", if cut { "cut off" } else { "back" }));
        if cut {
            let at = self.now + self.lease;
            self.leases.push((at, n));
        } else {
            self.back(n);
        }
        self.pump();
    }

    /// The operator sees `n` (and, for the operator, everyone) again.
    fn back(&mut self, n: Node) {
        let now = self.now;
        self.parted.remove(&n);
        let seen: Vec<Node> = match n {
            Node::Operator => vec![Node::Cell, Node::Welding, Node::Transport],
            other => vec![other],
        };
        for s in seen {
            if self.bus.reachable(Node::Operator, s) && self.is_running(s) {
                self.list().handle_presence(now, station(s), true);
            }
        }
    }

    /// `n`'s session and its router parted: the requests routed to it end
    /// with no reply at once, as zenoh's router finalizes a closed face's
    /// pending queries (`finalize_pending_queries`); and so do the requests
    /// `n` sent and still waits for, which its own session had routed to
    /// the router's face, closed on its side too.
    fn finalize(&mut self, n: Node) {
        let ids: Vec<u64> = self
            .pending
            .iter()
            .filter(|(_, p)| p.to == n || self.waits_at(&p.waiter) == n)
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

    /// `n`'s associations ended (its lease ran out, or it crashed): every
    /// peer associated with it takes the abort indication, and a cut `n`
    /// takes theirs.
    fn lost(&mut self, n: Node) {
        let now = self.now;
        self.note(format!("bus: {n} lost"));
        self.finalize(n);
        let reason = format!("no connection with {n}");
        if matches!(n, Node::Operator | Node::Cell) {
            self.sees_lost(Node::Cell, Node::Operator, &reason);
            self.sees_lost(Node::Operator, Node::Cell, &reason);
        }
        let seen = match n {
            Node::Operator => vec![Node::Cell, Node::Welding, Node::Transport],
            other => vec![other],
        };
        for s in seen {
            self.list().handle_presence(now, station(s), false);
        }
        for ws in [Node::Welding, Node::Transport] {
            if n == Node::Cell || n == ws {
                self.sees_lost(Node::Cell, ws, &reason);
                self.sees_lost(ws, Node::Cell, &reason);
            }
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

    /// Random bytes on the serial line, towards both ends.
    pub fn noise(&mut self, bytes: Vec<u8>) {
        let at = self.now + WIRE;
        self.note(format!("serial: {} bytes of noise", bytes.len()));
        self.wire.push_back((at, true, bytes.clone()));
        self.wire.push_back((at, false, bytes));
    }

    /// Node `n`'s process dies: only the twins' state survives (and the
    /// operator's records).
    pub fn crash(&mut self, n: Node) {
        self.note(format!("{n}: process killed"));
        if let Some(up) = self.up(n) {
            up.running = false;
        }
        // Its requests out die with it.
        self.forget_waits_of(n);
        if n == Node::Operator {
            // Its indications and its API go with it; the router ends the
            // cell's queries to it; the cell runs its order on alone.
            self.indications.clear();
            self.lost_before = self.tickets;
            self.finalize(Node::Operator);
            let reason = format!("no connection with {n}");
            self.sees_lost(Node::Cell, Node::Operator, &reason);
        } else {
            // Its liveliness token goes with its session: seen at once.
            self.lost(n);
        }
        // A dead process holds no association.
        let fresh = Serving::of(&self.topology, self.peer(n));
        if let Some(up) = self.up(n) {
            up.serving = fresh;
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
        match n {
            Node::Welding => self.welding.node.set_recipe_memory(bytes),
            Node::Transport => self.transport.node.set_recipe_memory(bytes),
            Node::Operator | Node::Cell => {}
        }
    }

    /// Node `n` starts again: empty, but for the operator's records.
    pub fn restart(&mut self, n: Node) {
        let now = self.now;
        self.note(format!("{n}: process started again"));
        match n {
            Node::Welding => {
                self.welding = welding_node(&self.topology, now, self.timing);
                self.wire.retain(|w| w.1);
            }
            Node::Cell => {
                self.cell = cell_node(&self.topology);
                self.starting.clear();
            }
            Node::Operator => {
                self.restart_operator();
                return;
            }
            Node::Transport => {
                self.transport = transport_node(&self.topology, now, self.conveyor.coils());
            }
        }
        self.apply_memory(n);
        self.new_run(n);
        if self.bus.reachable(Node::Operator, n) {
            self.list().handle_presence(now, station(n), true);
        }
        self.pump();
    }

    /// The operator starts again on its records: the order they hold as
    /// running is adopted (the cell is asked how it ended), as
    /// `falc-operator` does at start.
    fn restart_operator(&mut self) {
        let now = self.now;
        let (mut view, source) = self.durable.clone();
        view.set_now(self.wall_ms());
        let recovered = match view.recover(&[source.topology().cell().as_str()]) {
            Ok(r) => r,
            Err(e) => {
                // The real node exits and is started again; here it
                // starts with nothing adopted, and says so.
                self.note(format!("operator: cannot recover: {e}"));
                Default::default()
            }
        };
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
        if let Some(o) = recovered.adopted.into_iter().next() {
            self.note(format!("operator: adopted order {}", o.id));
            list = list.adopting(o);
        }
        self.plant = Plant::new(vec![list]);
        self.new_run(Node::Operator);
        for s in [Node::Cell, Node::Welding, Node::Transport] {
            if self.bus.reachable(Node::Operator, s) && self.is_running(s) {
                self.list().handle_presence(now, station(s), true);
            }
        }
        self.pump();
    }
}
