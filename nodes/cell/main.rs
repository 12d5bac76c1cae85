//! `falc-cell`: the cell controller. Accepts the operator as commander and,
//! on its Initiate, associates its workstations first (the 1992 recursive
//! scheme, in `Station`); runs cell recipes (`start`, `wait`, `output`,
//! `input`) through the workstations' services; an abort indication or an
//! alarm from a workstation ends the running recipe in alarm, stops the
//! other workstations' program invocations and reports the cause up.
//!
//! A transport: every decision is the sans-I/O
//! `falc_control::cell_node::CellNode` (the recipe runtime, the pass-on of
//! modes, steps, manual operations and recipe deliveries, one request lane
//! per station), which `falc-sim` runs too. Here its actions are carried
//! over zenoh: each request a task of its own whose confirm comes back
//! to the loop; nothing in the loop waits on another station.

use anyhow::Result;
use clap::Parser;
use falc_bus::station::{Station, StationEvent};
use falc_bus::Responder;
use falc_control::cell_node::{CellAction, CellNode};
use falc_control::coordination::Reply;
use falc_control::pass_on::PASS_LIMIT;
use falc_model::ids::StationName;
use falc_model::mms::error::ServiceError;
use falc_model::mms::pdu::Response;
use falc_node::controller_node;
use falc_node::{init_tracing, say, NodeArgs};
use std::time::Duration;
use tokio::sync::mpsc::{unbounded_channel, UnboundedSender};
use tokio::time::Instant;

#[derive(Parser, Debug)]
#[command(
    version,
    about = "FALC cell controller: cell recipes over the workstations"
)]
struct Cli {
    /// The station this process is (a station of kind cell).
    #[arg(long, default_value = "cell")]
    station: StationName,
    #[command(flatten)]
    node: NodeArgs,
}

/// What came back from a workstation or the operator.
enum Came {
    /// The confirm of a [`CellAction::Request`] to this station.
    Reply(StationName, Reply),
    /// The confirm of a [`CellAction::Ask`].
    Confirm(u64, Result<Response, ServiceError>),
    /// The outcome of a [`CellAction::Deliver`].
    Delivered(u64, Result<(), ServiceError>),
}

/// The cell: its node, carried over its station on the bus.
struct Cell {
    node: CellNode<Responder>,
    station: Station,
    origin: Instant,
    came: UnboundedSender<Came>,
}

impl Cell {
    /// Time since start (the node's clock).
    fn now(&self) -> Duration {
        Instant::now().duration_since(self.origin)
    }

    /// Carries out what the node has to do, in order.
    async fn settle(&mut self) {
        let now = self.now();
        while let Some(action) = self.node.poll(now) {
            match action {
                CellAction::Request(cmd) => {
                    let (bus, came) = (self.station.bus().clone(), self.came.clone());
                    tokio::spawn(async move {
                        let result = bus.request(&cmd.to, &cmd.request, cmd.limit).await;
                        let reply = Reply {
                            awaiting: cmd.awaiting,
                            result,
                        };
                        let _ = came.send(Came::Reply(cmd.to, reply));
                    });
                }
                CellAction::Answer { ticket, result } => ticket.respond(result).await,
                CellAction::Ask { id, to, request } => {
                    let (bus, came) = (self.station.bus().clone(), self.came.clone());
                    tokio::spawn(async move {
                        let result = bus.request(&to, &request, PASS_LIMIT).await;
                        let _ = came.send(Came::Confirm(id, result));
                    });
                }
                CellAction::Deliver { id, delivery } => {
                    let (bus, came) = (self.station.bus().clone(), self.came.clone());
                    tokio::spawn(async move {
                        let result = bus.carry(delivery).await;
                        let _ = came.send(Came::Delivered(id, result));
                    });
                }
                CellAction::Delivered { to, name } => {
                    say(&format!("EVENT delivered station={to} recipe={name}"));
                }
                CellAction::Warn(text) => tracing::warn!("{text}"),
                CellAction::Publish(u) => controller_node::publish(&self.station, u).await,
            }
        }
    }

    /// Acts on what the station hands the cell.
    async fn on_station(&mut self, ev: StationEvent) {
        let now = self.now();
        match ev {
            StationEvent::Indication(ind) => {
                self.node.handle_indication(ind.responder, ind.request)
            }
            StationEvent::Associated(p) => {
                say(&format!("EVENT associated commander={}", p.station));
                // A new commander sees the status at once, changed or not
                // (the node publishes it again).
                self.node.handle_associated(now);
                self.settle().await;
            }
            StationEvent::Abort(a) => {
                say(&format!("EVENT abort-indication peer={}", a.peer.station));
                self.node.handle_abort(now, &a.peer.station, a.role);
            }
            StationEvent::Concluded(_) => {}
        }
    }

    fn deadline(&self) -> Instant {
        self.node
            .poll_timeout()
            .map_or(Instant::now() + Duration::from_secs(3600), |t| {
                self.origin + t
            })
    }
}

#[tokio::main]
async fn main() -> Result<()> {
    init_tracing();
    let cli = Cli::parse();
    let topology = cli.node.topology()?;
    let settings = cli.node.settings(&topology, &cli.station)?;
    let station = Station::open(settings, &topology).await?;
    let bus = station.bus().clone();
    let subordinates: Vec<StationName> = topology
        .subordinates_of(&cli.station)
        .into_iter()
        .cloned()
        .collect();
    let (utx, mut publications) = unbounded_channel();
    let mut subscriptions = Vec::new();
    for st in &subordinates {
        subscriptions.extend(bus.subscribe(st, utx.clone()).await?);
    }
    let alone = station.associations().runs_alone();
    let node = CellNode::new(
        cli.station.clone(),
        topology.commander_of(&cli.station).cloned(),
        subordinates,
        alone,
    );
    let (came, mut answers) = unbounded_channel();
    let mut cell = Cell {
        node,
        station,
        origin: Instant::now(),
        came,
    };
    cell.settle().await;
    say(&format!("EVENT ready station={}", cli.station));
    let mut shutdown = falc_node::Shutdown::new();
    loop {
        let deadline = cell.deadline();
        tokio::select! {
            ev = cell.station.recv() => {
                let Some(ev) = ev else { break };
                if let Some(ev) = cell.station.handle(ev).await {
                    cell.on_station(ev).await;
                }
            }
            c = answers.recv() => match c {
                Some(Came::Reply(to, reply)) => {
                    let now = cell.now();
                    cell.node.handle_reply(now, &to, reply);
                }
                Some(Came::Confirm(id, result)) => cell.node.handle_confirm(id, result),
                Some(Came::Delivered(id, result)) => cell.node.handle_delivered(id, result),
                None => break,
            },
            u = publications.recv() => match u {
                Some(u) => {
                    // A workstation's reports reach the operator directly
                    // (it reads every station's reports), under its name.
                    let now = cell.now();
                    cell.node.handle_publication(now, &u.message);
                }
                None => break,
            },
            _ = tokio::time::sleep_until(deadline) => {
                let now = cell.now();
                cell.node.handle_timeout(now);
            }
            _ = shutdown.requested() => break,
        }
        cell.settle().await;
    }
    drop(subscriptions);
    say("EVENT stopped");
    Ok(())
}
