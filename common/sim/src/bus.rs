//! The in-memory bus: every node reaches the others through its router,
//! as on zenoh, and each node's link to its router has its own latency,
//! loss and cut. In a plant each cell has a router of its own, joined to
//! the factory router (where the operator is) by the cell's uplink: what
//! passes between the operator and a cell's station crosses it, and a cut
//! uplink parts the whole cell from the operator while its stations still
//! reach each other. A message is delivered at the time the latencies on
//! its way add up to, in the order sent between one pair; a cut link drops
//! what crosses it (a confirmed request then runs out of time at its
//! sender, as on the real bus).

use falc_model::mms::error::ServiceError;
use falc_model::mms::journal::{KeptReports, Publication};
use falc_model::mms::pdu::{Request, Response};
use rand::Rng;
use std::cmp::Reverse;
use std::collections::{BTreeMap, BinaryHeap};
use std::fmt;
use std::time::Duration;

/// What a process is in a cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Role {
    /// The operator (order list, records): one process, with a place in
    /// every cell it commands.
    Operator,
    /// The cell controller.
    Cell,
    /// The cell's workstation number `k` (its topology's workstations
    /// counted from 0, in the file's order).
    Workstation(usize),
}

/// A place on the bus: a role in cell number `cell` (the topology's
/// cells counted from 0). The operator's places in the cells are one
/// process and one link to the factory router.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Node {
    /// The cell, counted from 0.
    pub cell: usize,
    /// What it is there.
    pub role: Role,
}

impl Node {
    /// `role` in cell `cell`.
    pub fn new(cell: usize, role: Role) -> Self {
        Self { cell, role }
    }

    /// The operator's place in cell `cell`.
    pub fn operator(cell: usize) -> Self {
        Self::new(cell, Role::Operator)
    }

    /// Cell `cell`'s controller.
    pub fn cell(cell: usize) -> Self {
        Self::new(cell, Role::Cell)
    }

    /// Cell `cell`'s workstation number `k`.
    pub fn workstation(cell: usize, k: usize) -> Self {
        Self::new(cell, Role::Workstation(k))
    }

    /// Whether it is the operator's.
    pub fn is_operator(self) -> bool {
        self.role == Role::Operator
    }

    /// The link it reaches its router by: the operator's is one for all
    /// its places.
    fn link_key(self) -> Node {
        if self.is_operator() {
            Node::operator(0)
        } else {
            self
        }
    }
}

impl fmt::Display for Node {
    /// `cell 2 workstation 0`: the world names nodes by their stations
    /// where it can.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.role {
            Role::Operator => f.write_str("operator"),
            Role::Cell => write!(f, "cell {} controller", self.cell),
            Role::Workstation(k) => write!(f, "cell {} workstation {k}", self.cell),
        }
    }
}

/// What crosses the bus.
#[derive(Debug, Clone)]
pub enum Msg {
    /// A confirmed service's request (indication at the receiver).
    Request {
        /// Names the confirm.
        id: u64,
        /// The request.
        request: Request,
    },
    /// The confirm of request `id`.
    Response {
        /// The request it answers.
        id: u64,
        /// The response or the refusal.
        result: Result<Response, ServiceError>,
    },
    /// An unsolicited status, job event or report (reports and job events
    /// numbered by the station's kept reports).
    Publish(Publication),
    /// The operator reads what a station kept after number `after`.
    ReadKept {
        /// Names the answer.
        id: u64,
        /// The last number the operator filed.
        after: u64,
    },
    /// What the station kept, the answer to [`Msg::ReadKept`] `id`.
    Kept {
        /// The read it answers.
        id: u64,
        /// The reports.
        kept: KeptReports,
    },
}

/// One node's link to the router.
#[derive(Debug, Clone, Copy)]
pub struct Link {
    /// One-way latency to the router.
    pub latency: Duration,
    /// Chance that a message is lost (0 to 1).
    pub loss: f64,
    /// Cut: nothing crosses.
    pub cut: bool,
}

impl Default for Link {
    fn default() -> Self {
        Self {
            latency: Duration::from_micros(250),
            loss: 0.0,
            cut: false,
        }
    }
}

/// A message on its way.
#[derive(Debug, Clone)]
pub struct Arrival {
    /// Sender.
    pub from: Node,
    /// Receiver.
    pub to: Node,
    /// What.
    pub msg: Msg,
}

/// The bus.
#[derive(Debug, Default)]
pub struct Bus {
    /// Every node's link, but those set apart.
    default: Link,
    links: BTreeMap<Node, Link>,
    /// Each cell's uplink, in a plant (a cell of its own has none: its
    /// router is the operator's).
    uplinks: BTreeMap<usize, Link>,
    queue: BinaryHeap<Reverse<(Duration, u64)>>,
    in_flight: BTreeMap<u64, Arrival>,
    /// When the last message between each ordered pair arrives (order
    /// between a pair is kept, as on one zenoh session).
    last: BTreeMap<(Node, Node), Duration>,
    seq: u64,
    /// Messages dropped so far (a cut or loss).
    pub dropped: u64,
}

impl Bus {
    /// A bus with `link` for every node, and for the uplinks of
    /// `uplinks` cells (none: a cell of its own).
    pub fn new(link: Link, uplinks: usize) -> Self {
        Self {
            default: link,
            uplinks: (0..uplinks).map(|c| (c, link)).collect(),
            ..Self::default()
        }
    }

    fn link(&self, n: Node) -> Link {
        self.links
            .get(&n.link_key())
            .copied()
            .unwrap_or(self.default)
    }

    /// The uplink a message between `a` and `b` crosses, if any: the
    /// operator's to a cell of a plant.
    fn uplink(&self, a: Node, b: Node) -> Option<Link> {
        match (a.is_operator(), b.is_operator()) {
            (true, false) => self.uplinks.get(&b.cell).copied(),
            (false, true) => self.uplinks.get(&a.cell).copied(),
            _ => None,
        }
    }

    /// Cuts `node`'s link (or joins it again).
    pub fn set_cut(&mut self, node: Node, cut: bool) {
        let default = self.default;
        self.links.entry(node.link_key()).or_insert(default).cut = cut;
    }

    /// Whether `node`'s link is cut.
    pub fn is_cut(&self, node: Node) -> bool {
        self.link(node).cut
    }

    /// Cuts cell `cell`'s uplink (or joins it again); a cell of its own
    /// has none.
    pub fn set_uplink_cut(&mut self, cell: usize, cut: bool) {
        if let Some(l) = self.uplinks.get_mut(&cell) {
            l.cut = cut;
        }
    }

    /// Whether cell `cell`'s uplink is cut.
    pub fn is_uplink_cut(&self, cell: usize) -> bool {
        self.uplinks.get(&cell).is_some_and(|l| l.cut)
    }

    /// Whether the cells have uplinks (a plant of several).
    pub fn has_uplinks(&self) -> bool {
        !self.uplinks.is_empty()
    }

    /// Whether `a` and `b` reach each other now.
    pub fn reachable(&self, a: Node, b: Node) -> bool {
        !self.link(a).cut && !self.link(b).cut && self.uplink(a, b).map_or(true, |u| !u.cut)
    }

    /// Sends `msg`; false if it is lost at once (a cut link or loss).
    pub fn send(
        &mut self,
        now: Duration,
        from: Node,
        to: Node,
        msg: Msg,
        rng: &mut impl Rng,
    ) -> bool {
        let (lf, lt) = (self.link(from), self.link(to));
        let up = self.uplink(from, to);
        let loss = lf.loss.max(lt.loss).max(up.map_or(0.0, |u| u.loss));
        if !self.reachable(from, to) || (loss > 0.0 && rng.gen_bool(loss.min(1.0))) {
            self.dropped += 1;
            return false;
        }
        let earliest = now + lf.latency + lt.latency + up.map_or(Duration::ZERO, |u| u.latency);
        let at = self
            .last
            .get(&(from, to))
            .map_or(earliest, |l| earliest.max(*l));
        self.last.insert((from, to), at);
        self.seq += 1;
        self.queue.push(Reverse((at, self.seq)));
        self.in_flight.insert(self.seq, Arrival { from, to, msg });
        true
    }

    /// When the next message arrives.
    pub fn poll_timeout(&self) -> Option<Duration> {
        self.queue.peek().map(|Reverse((at, _))| *at)
    }

    /// The next message due at `now`; one that meets a link cut on its way
    /// is dropped.
    pub fn poll_delivery(&mut self, now: Duration) -> Option<Arrival> {
        loop {
            let Reverse((at, seq)) = *self.queue.peek()?;
            if at > now {
                return None;
            }
            self.queue.pop();
            let Some(d) = self.in_flight.remove(&seq) else {
                continue;
            };
            if self.reachable(d.from, d.to) {
                return Some(d);
            }
            self.dropped += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn publish() -> Msg {
        Msg::Response {
            id: 1,
            result: Ok(Response::Done),
        }
    }

    const CELL: Node = Node {
        cell: 0,
        role: Role::Cell,
    };
    const WELDING: Node = Node {
        cell: 0,
        role: Role::Workstation(0),
    };

    #[test]
    fn messages_arrive_after_both_latencies_and_a_cut_drops_them() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(1);
        let mut bus = Bus::new(Link::default(), 0);
        let t0 = Duration::ZERO;
        assert!(bus.send(t0, CELL, WELDING, publish(), &mut rng));
        assert_eq!(bus.poll_timeout(), Some(Duration::from_micros(500)));
        assert!(bus.poll_delivery(Duration::from_micros(499)).is_none());
        let d = bus.poll_delivery(Duration::from_micros(500));
        assert!(matches!(d, Some(Arrival { to: WELDING, .. })));
        // In flight when the link is cut: dropped on arrival.
        assert!(bus.send(t0, CELL, WELDING, publish(), &mut rng));
        bus.set_cut(WELDING, true);
        assert!(bus.poll_delivery(Duration::from_secs(1)).is_none());
        assert!(!bus.send(t0, CELL, WELDING, publish(), &mut rng));
        assert!(!bus.reachable(Node::operator(0), WELDING));
        assert!(bus.reachable(Node::operator(0), CELL));
        assert_eq!(bus.dropped, 2);
    }

    #[test]
    fn a_cut_uplink_parts_its_cell_from_the_operator_only() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(1);
        let mut bus = Bus::new(Link::default(), 2);
        let (op, cell1, ws1) = (Node::operator(1), Node::cell(1), Node::workstation(1, 0));
        // Across the uplink: three latencies.
        assert!(bus.send(Duration::ZERO, op, cell1, publish(), &mut rng));
        assert_eq!(bus.poll_timeout(), Some(Duration::from_micros(750)));
        bus.set_uplink_cut(1, true);
        assert!(bus.is_uplink_cut(1) && !bus.is_uplink_cut(0));
        assert!(bus.poll_delivery(Duration::from_secs(1)).is_none());
        assert!(!bus.reachable(op, cell1));
        assert!(!bus.reachable(Node::operator(0), ws1));
        // Inside the cell, and to the other cell, all still goes.
        assert!(bus.reachable(cell1, ws1));
        assert!(bus.reachable(Node::operator(0), Node::cell(0)));
        // The operator's places are one link: cut once, cut in every cell.
        bus.set_uplink_cut(1, false);
        bus.set_cut(Node::operator(0), true);
        assert!(!bus.reachable(op, cell1));
        assert!(bus.reachable(cell1, ws1));
    }
}
