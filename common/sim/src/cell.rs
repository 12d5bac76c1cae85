//! One cell's processes and equipment, built from its topology: the cell
//! controller's node, and each workstation's node with what its device is
//! linked to (the welding station's 3964R line to the robot controller's
//! twin, the transport station's Modbus poll of the conveyor's twin). The
//! parts carry a workstation's commands to its twin as the link tasks of
//! `falc_node` do; what goes on the bus is handed to [`crate::world`].

use crate::bus::{Node, Role};
use falc_control::cell_node::CellNode;
use falc_control::controller::Controller;
use falc_control::coordination::Stations;
use falc_control::workstation_node::{Linked, WorkstationAction, WorkstationNode};
use falc_dnc::procedure::{Link as DncLink, Priority, Timing};
use falc_dnc::robot::Robot;
use falc_dnc::telegram::{Mode, Telegram};
use falc_dnc::twin::{Note, RcmTwin};
use falc_dnc::workstation::{self, LineEvent, Welding};
use falc_equipment::Equipment;
use falc_model::ids::StationName;
use falc_model::mms::association::Associations;
use falc_model::mms::vmd::Vmd;
use falc_model::topology::{StationKind, Topology};
use falc_plc::conveyor::Conveyor;
use falc_plc::map::{Coils, Inputs};
use falc_plc::workstation::{Pace, Plc, PlcCommand, PlcEvent, IDLE_POLL_MS, POLL_MS};
use falc_recipe::commands::RecipeKind;
use falc_recipe::engine::START_CONFIRM_LIMIT;
use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;
use std::time::Duration;

/// How long one byte chunk takes on the serial line.
const WIRE: Duration = Duration::from_millis(2);
/// The transport's poll periods (the link's defaults).
const POLL_BUSY: Duration = Duration::from_millis(POLL_MS);
const POLL_IDLE: Duration = Duration::from_millis(IDLE_POLL_MS);

/// A ticket of the nodes: the indication's sender and request id.
pub type Ticket = (Node, u64);
/// What a workstation's node asks the outside to do, its commands taken.
pub type Action<C> = WorkstationAction<Ticket, C>;

/// A welding workstation: its node, its end of the serial line, the line
/// and the robot controller's twin at the other end.
pub struct WeldingParts {
    node: WorkstationNode<Welding, Ticket>,
    link: DncLink,
    /// The robot controller's twin.
    pub rcm: RcmTwin,
    /// Bytes on the serial line: (arrival, towards the twin, bytes).
    wire: VecDeque<(Duration, bool, Vec<u8>)>,
    /// The serial line is plugged in.
    pub plugged: bool,
}

/// A transport workstation: its node, its Modbus link (the poller
/// `falc_node::plc_link` runs as a task) and the conveyor's twin.
pub struct TransportParts {
    node: WorkstationNode<Plc, Ticket>,
    pace: Pace,
    next_poll: Duration,
    done: u64,
    last: Option<Inputs>,
    wrote: bool,
    /// The conveyor's twin.
    pub conveyor: Conveyor,
}

/// A workstation and its equipment.
pub enum Workstation {
    /// A welding station (boxed, as the other: their nodes and twins are
    /// large and of different sizes).
    Welding(Box<WeldingParts>),
    /// A transport station.
    Transport(Box<TransportParts>),
}

/// One cell's processes and equipment (the operator's place in it is the
/// plant's).
pub struct CellParts {
    /// Its topology.
    pub(crate) topology: Topology,
    /// The operator's and the cell controller's station names.
    operator: StationName,
    cell_name: StationName,
    /// The cell controller's node, as `falc-cell` runs it.
    pub(crate) cell: CellNode<Ticket>,
    /// The commander's Starts the cell has not answered yet: their
    /// tickets, and the order each names (counted once answered).
    pub(crate) starting: BTreeMap<Ticket, i64>,
    /// The workstations, in the topology's order, with their names.
    stations: Vec<(StationName, Workstation)>,
}

/// A workstation's node as `falc_node::controller_node` starts it.
fn workstation_node<D: Linked>(
    topology: &Topology,
    me: &StationName,
    kind: RecipeKind,
    confirm_limit: Duration,
    device: D,
) -> WorkstationNode<D, Ticket> {
    let alone = Associations::of(topology, me).runs_alone();
    WorkstationNode::new(me.clone(), kind, confirm_limit, device, alone)
}

fn welding_node(
    topology: &Topology,
    me: &StationName,
    now: Duration,
    timing: Timing,
) -> (WorkstationNode<Welding, Ticket>, DncLink) {
    let device = Welding::new("sim-serial", &timing);
    let limit = workstation::confirm_limit(&timing);
    let mut node = workstation_node(topology, me, RecipeKind::Welding, limit, device);
    node.handle_link(now, LineEvent::Opened);
    (node, DncLink::new(Priority::Low, timing).awaiting_answers())
}

fn transport_node(
    topology: &Topology,
    me: &StationName,
    now: Duration,
    equipment: Arc<Equipment>,
    held: Coils,
) -> WorkstationNode<Plc, Ticket> {
    let device = Plc::new("sim-plc:502".into(), equipment);
    let kind = RecipeKind::Transport;
    let mut node = workstation_node(topology, me, kind, START_CONFIRM_LIMIT, device);
    node.handle_link(now, PlcEvent::Connected { coils: Some(held) });
    node
}

/// The cell controller's node as `falc-cell` starts it.
fn cell_node(topology: &Topology, me: &StationName, operator: &StationName) -> CellNode<Ticket> {
    let alone = Associations::of(topology, me).runs_alone();
    let subordinates = topology.subordinates_of(me).into_iter().cloned().collect();
    CellNode::new(me.clone(), Some(operator.clone()), subordinates, alone)
}

impl CellParts {
    /// The cell of `topology` at rest at time zero, its twins at
    /// `time_scale`. A topology the simulation cannot drive is refused,
    /// naming the cell: it drives an operator over one cell controller
    /// over welding and transport workstations.
    pub fn new(topology: Topology, time_scale: f64, timing: Timing) -> Result<Self, String> {
        let shape = |why: String| {
            format!(
                "cell {}: the simulation drives an operator over one cell controller over \
                 welding and transport workstations; {why}",
                topology.cell()
            )
        };
        let operator = topology.root().name.clone();
        let cells: Vec<&StationName> = topology.subordinates_of(&operator);
        let cell_name = match cells.as_slice() {
            [c] if topology
                .station(c)
                .is_some_and(|s| s.kind == StationKind::Cell) =>
            {
                (*c).clone()
            }
            _ => {
                let names: Vec<&str> = cells.iter().map(|c| c.as_str()).collect();
                return Err(shape(format!("{operator} commands {}", names.join(", "))));
            }
        };
        let now = Duration::ZERO;
        let mut stations = Vec::new();
        for s in topology.stations() {
            if s.name == operator || s.name == cell_name {
                continue;
            }
            if topology.commander_of(&s.name) != Some(&cell_name) {
                return Err(shape(format!("{} is not commanded by {cell_name}", s.name)));
            }
            let ws = match s.kind {
                StationKind::Welding => {
                    let (node, link) = welding_node(&topology, &s.name, now, timing);
                    Workstation::Welding(Box::new(WeldingParts {
                        node,
                        link,
                        rcm: RcmTwin::new(Robot::new(Mode::AutomaticExternal, time_scale), timing),
                        wire: VecDeque::new(),
                        plugged: true,
                    }))
                }
                StationKind::Transport => {
                    let equipment = Equipment::of_stanza(s.equipment.as_deref())
                        .map_err(|e| format!("station {}: {e}", s.name))?;
                    let home = equipment.carriers().to_vec();
                    let conveyor = Conveyor::new(equipment.clone(), &home, time_scale)?;
                    let node = transport_node(&topology, &s.name, now, equipment, conveyor.coils());
                    Workstation::Transport(Box::new(TransportParts {
                        node,
                        pace: Pace::Idle,
                        next_poll: now,
                        done: 0,
                        last: None,
                        wrote: true,
                        conveyor,
                    }))
                }
                other => {
                    return Err(shape(format!("{} is a {} station", s.name, other.as_str())));
                }
            };
            stations.push((s.name.clone(), ws));
        }
        Ok(Self {
            cell: cell_node(&topology, &cell_name, &operator),
            starting: BTreeMap::new(),
            operator,
            cell_name,
            stations,
            topology,
        })
    }

    /// The cell controller's process starts again, empty.
    pub(crate) fn restart_cell(&mut self) {
        self.cell = cell_node(&self.topology, &self.cell_name, &self.operator);
        self.starting.clear();
    }

    /// The station name of `role` here.
    pub fn name(&self, role: Role) -> &StationName {
        match role {
            Role::Operator => &self.operator,
            Role::Cell => &self.cell_name,
            Role::Workstation(k) => self.stations.get(k).map_or(&self.cell_name, |s| &s.0),
        }
    }

    /// The role of station `name` here.
    pub fn role_of(&self, name: &StationName) -> Option<Role> {
        if name == &self.operator {
            Some(Role::Operator)
        } else if name == &self.cell_name {
            Some(Role::Cell)
        } else {
            self.stations
                .iter()
                .position(|s| &s.0 == name)
                .map(Role::Workstation)
        }
    }

    /// Every role of the cell: the operator's place, the controller, the
    /// workstations in the topology's order.
    pub fn roles(&self) -> Vec<Role> {
        let mut v = vec![Role::Operator, Role::Cell];
        v.extend((0..self.stations.len()).map(Role::Workstation));
        v
    }

    /// The workstations' numbers.
    pub fn workstations(&self) -> std::ops::Range<usize> {
        0..self.stations.len()
    }

    /// The welding workstations' numbers.
    pub fn weldings(&self) -> Vec<usize> {
        self.workstations()
            .filter(|k| self.welding_parts(*k).is_some())
            .collect()
    }

    /// The transport workstations' numbers.
    pub fn transports(&self) -> Vec<usize> {
        self.workstations()
            .filter(|k| self.transport_parts(*k).is_some())
            .collect()
    }

    /// The cell controller's recipe runtime.
    pub fn controller(&self) -> &Controller<Stations> {
        self.cell.controller()
    }

    /// Workstation `k`, if it is a welding one.
    pub fn welding_parts(&self, k: usize) -> Option<&WeldingParts> {
        match self.stations.get(k) {
            Some((_, Workstation::Welding(w))) => Some(w),
            _ => None,
        }
    }

    /// Workstation `k`, if it is a welding one, to change (its twin).
    pub fn welding_mut(&mut self, k: usize) -> Option<&mut WeldingParts> {
        match self.stations.get_mut(k) {
            Some((_, Workstation::Welding(w))) => Some(w),
            _ => None,
        }
    }

    /// Workstation `k`, if it is a transport one.
    pub fn transport_parts(&self, k: usize) -> Option<&TransportParts> {
        match self.stations.get(k) {
            Some((_, Workstation::Transport(t))) => Some(t),
            _ => None,
        }
    }

    /// Workstation `k`, if it is a transport one, to change (its twin).
    pub fn transport_mut(&mut self, k: usize) -> Option<&mut TransportParts> {
        match self.stations.get_mut(k) {
            Some((_, Workstation::Transport(t))) => Some(t),
            _ => None,
        }
    }

    /// Workstation `k`.
    pub(crate) fn workstation_mut(&mut self, k: usize) -> Option<&mut Workstation> {
        self.stations.get_mut(k).map(|s| &mut s.1)
    }

    /// The VMD of `role`'s station (the operator has none here).
    pub fn vmd(&self, role: Role) -> Option<&Vmd> {
        match role {
            Role::Operator => None,
            Role::Cell => Some(self.controller().vmd()),
            Role::Workstation(k) => match self.stations.get(k) {
                Some((_, Workstation::Welding(w))) => Some(w.controller().vmd()),
                Some((_, Workstation::Transport(t))) => Some(t.controller().vmd()),
                None => None,
            },
        }
    }

    /// When something of the cell is next due (the controller's only if
    /// its process runs).
    pub fn poll_timeout(&self, cell_runs: bool) -> Option<Duration> {
        let cell = self.cell.poll_timeout().filter(|_| cell_runs);
        let ws = self.stations.iter().flat_map(|(_, w)| match w {
            Workstation::Welding(w) => [
                w.node.poll_timeout(),
                w.link.poll_timeout(),
                w.rcm.poll_timeout(),
                w.wire.iter().map(|x| x.0).min(),
            ],
            Workstation::Transport(t) => [
                t.node.poll_timeout(),
                Some(t.next_poll),
                t.conveyor.poll_timeout(),
                None,
            ],
        });
        std::iter::once(cell).chain(ws).flatten().min()
    }

    /// The cell's timers due at `now`; `runs` says whose process runs.
    pub fn handle_timeout(&mut self, now: Duration, runs: impl Fn(Role) -> bool) {
        if runs(Role::Cell) && self.cell.poll_timeout().is_some_and(|t| t <= now) {
            self.cell.handle_timeout(now);
        }
        for (k, (_, ws)) in self.stations.iter_mut().enumerate() {
            let up = runs(Role::Workstation(k));
            match ws {
                Workstation::Welding(w) => w.handle_timeout(now, up),
                Workstation::Transport(t) => t.handle_timeout(now, up),
            }
        }
    }
}

impl WeldingParts {
    /// The workstation's recipe runtime (its robot: `.device`).
    pub fn controller(&self) -> &Controller<Welding> {
        self.node.controller()
    }

    /// The node, for the bus's indications and associations.
    pub(crate) fn node_mut(&mut self) -> &mut WorkstationNode<Welding, Ticket> {
        &mut self.node
    }

    fn handle_timeout(&mut self, now: Duration, runs: bool) {
        if self.node.poll_timeout().is_some_and(|t| t <= now) {
            self.node.handle_timeout(now);
        }
        if self.link.poll_timeout().is_some_and(|t| t <= now) {
            self.link.handle_timeout(now);
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
            } else if runs {
                self.link.handle_bytes(now, &bytes);
            }
        }
    }

    /// Carries what the node decided: its telegrams over the 3964R link
    /// to the line (as `falc_node::dnc_link`'s task), what the link
    /// reports back to the node, until both are quiet. What goes on the
    /// bus is returned in order, with the twin's troubles for the trace;
    /// `any`: the node did something.
    pub(crate) fn settle(&mut self, now: Duration) -> Settled<Telegram> {
        let mut out = Settled::default();
        loop {
            while let Some(a) = self.node.poll(now) {
                out.any = true;
                match a {
                    WorkstationAction::Command(t) => self.link.send(now, t.encode()),
                    other => out.actions.push(other),
                }
            }
            let mut more = false;
            while let Some(ev) = self.link.poll_event() {
                more = true;
                self.node.handle_link(now, LineEvent::Link(ev));
            }
            while let Some(bytes) = self.link.poll_transmit() {
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
                out.notes.push(format!("rcm: {why}"));
            }
        }
        out
    }

    /// The process starts again: a new node and end of line; the bytes
    /// on their way to it are lost.
    pub(crate) fn restart(
        &mut self,
        topology: &Topology,
        me: &StationName,
        now: Duration,
        timing: Timing,
    ) {
        let (node, link) = welding_node(topology, me, now, timing);
        self.node = node;
        self.link = link;
        self.wire.retain(|w| w.1);
    }

    /// Random bytes on the serial line at `at`, towards both ends.
    pub(crate) fn noise(&mut self, at: Duration, bytes: Vec<u8>) {
        self.wire.push_back((at + WIRE, true, bytes.clone()));
        self.wire.push_back((at + WIRE, false, bytes));
    }
}

impl TransportParts {
    /// The workstation's recipe runtime (its PLC: `.device`).
    pub fn controller(&self) -> &Controller<Plc> {
        self.node.controller()
    }

    /// The node, for the bus's indications and associations.
    pub(crate) fn node_mut(&mut self) -> &mut WorkstationNode<Plc, Ticket> {
        &mut self.node
    }

    fn handle_timeout(&mut self, now: Duration, runs: bool) {
        if self.node.poll_timeout().is_some_and(|t| t <= now) {
            self.node.handle_timeout(now);
        }
        if self.conveyor.poll_timeout().is_some_and(|t| t <= now) {
            self.conveyor.handle_timeout(now);
        }
        if self.next_poll <= now {
            self.poll(now, runs);
        }
    }

    /// The Modbus poll: the inputs as the PLC has them, handed on when
    /// they changed or after a write (as `falc_node::plc_link`).
    fn poll(&mut self, now: Duration, runs: bool) {
        self.next_poll = now
            + match self.pace {
                Pace::Busy => POLL_BUSY,
                Pace::Idle => POLL_IDLE,
            };
        if !runs {
            return;
        }
        self.conveyor.handle_timeout(now);
        let inputs = self.conveyor.inputs();
        if self.wrote || self.last.as_ref() != Some(&inputs) {
            self.wrote = false;
            self.last = Some(inputs.clone());
            let commands_done = self.done;
            self.node.handle_link(
                now,
                PlcEvent::Inputs {
                    inputs,
                    commands_done,
                },
            );
        }
    }

    /// Carries what the node decided: its commands to the conveyor's twin
    /// (as `falc_node::plc_link`'s task writes coils and sets its pace).
    /// What goes on the bus is returned in order, with the twin's notes
    /// for the trace; `any`: the node did something.
    pub(crate) fn settle(&mut self, now: Duration) -> Settled<PlcCommand> {
        let mut out = Settled::default();
        while let Some(a) = self.node.poll(now) {
            out.any = true;
            match a {
                WorkstationAction::Command(PlcCommand::Write(coil, v)) => {
                    self.conveyor.write_coil(now, coil, v);
                    self.done += 1;
                    self.wrote = true;
                }
                WorkstationAction::Command(PlcCommand::WriteAll(values)) => {
                    for (coil, v) in values {
                        self.conveyor.write_coil(now, coil, v);
                    }
                    self.done += 1;
                    self.wrote = true;
                }
                WorkstationAction::Command(PlcCommand::Read) => {
                    // Read at once: the reading after it is emitted.
                    self.done += 1;
                    self.wrote = true;
                }
                WorkstationAction::Command(PlcCommand::Pace(pace)) => {
                    self.pace = pace;
                    if pace == Pace::Busy {
                        self.next_poll = self.next_poll.min(now + POLL_BUSY);
                    }
                }
                other => out.actions.push(other),
            }
        }
        if self.wrote {
            // The link reads right after a write.
            self.next_poll = self.next_poll.min(now + POLL_BUSY);
        }
        while let Some(note) = self.conveyor.poll_note() {
            out.notes.push(format!("plc: {note}"));
        }
        out
    }

    /// The process starts again: a new node that reads the coils back.
    pub(crate) fn restart(&mut self, topology: &Topology, me: &StationName, now: Duration) {
        let equipment = self.conveyor.equipment().clone();
        self.node = transport_node(topology, me, now, equipment, self.conveyor.coils());
        self.pace = Pace::Idle;
        self.next_poll = now;
        self.done = 0;
        self.last = None;
        self.wrote = true;
    }
}

/// What a workstation's node put out for the bus while it settled.
pub(crate) struct Settled<C> {
    /// The node did something.
    pub any: bool,
    /// Answers, publications, lines, in order (commands went to the
    /// link).
    pub actions: Vec<Action<C>>,
    /// The twin's lines for the trace.
    pub notes: Vec<String>,
}

impl<C> Default for Settled<C> {
    fn default() -> Self {
        Self {
            any: false,
            actions: Vec::new(),
            notes: Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CELL: &str = include_str!("../../../launch/cell.toml");

    fn parts(text: &str) -> Result<CellParts, String> {
        let topology = Topology::parse(text, "test.toml").map_err(|e| e.to_string())?;
        CellParts::new(topology, 20.0, Timing::default())
    }

    #[test]
    fn the_workstations_come_from_the_topology_in_its_order() {
        let grown = format!(
            "{CELL}\n[[station]]\nname = \"welding2\"\nkind = \"welding\"\ncommander = \"cell\"\n"
        );
        let p = parts(&grown).expect("a cell the simulation drives");
        assert_eq!(p.weldings(), vec![0, 2]);
        assert_eq!(p.transports(), vec![1]);
        let name = |r| p.name(r).as_str().to_string();
        assert_eq!(name(Role::Workstation(2)), "welding2");
        assert_eq!(name(Role::Cell), "cell");
        let welding2 = StationName::new("welding2").expect("valid");
        assert_eq!(p.role_of(&welding2), Some(Role::Workstation(2)));
        assert_eq!(p.roles().len(), 5);
    }

    #[test]
    fn a_workstation_under_another_workstation_is_refused_naming_it() {
        let odd = format!(
            "{CELL}\n[[station]]\nname = \"belt\"\nkind = \"transport\"\ncommander = \"welding\"\n"
        );
        let e = parts(&odd).err().expect("refused");
        assert!(
            e.contains("cell falc1") && e.contains("belt is not commanded by cell"),
            "{e}"
        );
    }
}
