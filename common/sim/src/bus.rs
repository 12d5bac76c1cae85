//! The in-memory bus: every node reaches the others through the router, as
//! on zenoh, and each node's link to the router has its own latency, loss
//! and cut. A message is delivered at the time its sender's and its
//! receiver's latencies add up to, in the order sent between one pair; a
//! cut link drops what crosses it (a confirmed request then runs out of
//! time at its sender, as on the real bus).

use falc_model::mms::error::ServiceError;
use falc_model::mms::journal::{KeptReports, Publication};
use falc_model::mms::pdu::{Request, Response};
use rand::Rng;
use std::cmp::Reverse;
use std::collections::{BTreeMap, BinaryHeap};
use std::fmt;
use std::time::Duration;

/// A process of the cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Node {
    /// The operator (order list, records).
    Operator,
    /// The cell controller.
    Cell,
    /// The welding workstation.
    Welding,
    /// The transport workstation.
    Transport,
}

impl Node {
    /// Every node.
    pub const ALL: [Node; 4] = [Node::Operator, Node::Cell, Node::Welding, Node::Transport];

    /// The node that is station `name` of the shipped topology.
    pub fn of(name: &falc_model::ids::StationName) -> Option<Node> {
        Node::ALL.into_iter().find(|n| n.station() == name.as_str())
    }

    /// Its station name in the shipped topology.
    pub fn station(self) -> &'static str {
        match self {
            Node::Operator => "operator",
            Node::Cell => "cell",
            Node::Welding => "welding",
            Node::Transport => "transport",
        }
    }
}

impl fmt::Display for Node {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.station())
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
    links: BTreeMap<Node, Link>,
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
    /// A bus with `link` for every node.
    pub fn new(link: Link) -> Self {
        Self {
            links: Node::ALL.iter().map(|n| (*n, link)).collect(),
            ..Self::default()
        }
    }

    fn link(&self, n: Node) -> Link {
        self.links.get(&n).copied().unwrap_or_default()
    }

    /// Cuts `node`'s link (or joins it again).
    pub fn set_cut(&mut self, node: Node, cut: bool) {
        self.links.entry(node).or_default().cut = cut;
    }

    /// Whether `node`'s link is cut.
    pub fn is_cut(&self, node: Node) -> bool {
        self.link(node).cut
    }

    /// Whether `a` and `b` reach each other now.
    pub fn reachable(&self, a: Node, b: Node) -> bool {
        !self.link(a).cut && !self.link(b).cut
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
        let loss = lf.loss.max(lt.loss);
        if lf.cut || lt.cut || (loss > 0.0 && rng.gen_bool(loss.min(1.0))) {
            self.dropped += 1;
            return false;
        }
        let earliest = now + lf.latency + lt.latency;
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

    #[test]
    fn messages_arrive_after_both_latencies_and_a_cut_drops_them() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(1);
        let mut bus = Bus::new(Link::default());
        let t0 = Duration::ZERO;
        assert!(bus.send(t0, Node::Cell, Node::Welding, publish(), &mut rng));
        assert_eq!(bus.poll_timeout(), Some(Duration::from_micros(500)));
        assert!(bus.poll_delivery(Duration::from_micros(499)).is_none());
        let d = bus.poll_delivery(Duration::from_micros(500));
        assert!(matches!(
            d,
            Some(Arrival {
                to: Node::Welding,
                ..
            })
        ));
        // In flight when the link is cut: dropped on arrival.
        assert!(bus.send(t0, Node::Cell, Node::Welding, publish(), &mut rng));
        bus.set_cut(Node::Welding, true);
        assert!(bus.poll_delivery(Duration::from_secs(1)).is_none());
        assert!(!bus.send(t0, Node::Cell, Node::Welding, publish(), &mut rng));
        assert!(!bus.reachable(Node::Operator, Node::Welding));
        assert!(bus.reachable(Node::Operator, Node::Cell));
        assert_eq!(bus.dropped, 2);
    }
}
