//! `falc-operator`: the factory controller at the root of the cell. At start
//! it checks every recipe of the recipe directory (the PPS, `recipe_store`) and
//! refuses to start with every problem as `file:line: reason`; it opens the
//! order list and journal (`database`, SQLite WAL), marks an order a crash
//! interrupted, associates the cell (retrying every second while it cannot)
//! and delivers the recipes; then it serves the operator API to consoles
//! and operator communication (`input`, `output`) to the cell.
//!
//! A thin driver: the order list is `falc_control::order_list` (sans-I/O);
//! here are start-up, the event loop and the cell lane, the one task that
//! sends the order list's requests to the cell, one at a time. Nothing in
//! the loop waits on the cell: a console's `status` is answered while a
//! start or a delivery is under way.

mod database;
mod recipe_store;

use anyhow::{Context, Result};
use clap::Parser;
use database::Database;
use falc_bus::operator_service::ApiResponder;
use falc_bus::station::{self, Station, StationEvent};
use falc_bus::{Bus, Responder};
use falc_control::order_list::{CellCall, OrderList, Output, Ticket};
use falc_control::recipe_source::{Delivery, RecipeSource};
use falc_model::console::EntryKind;
use falc_model::ids::StationName;
use falc_model::mms::error::ServiceError;
use falc_model::mms::pdu::{Peer, Request};
use falc_node::{init_tracing, lane, say, NodeArgs};
use recipe_store::RecipeDir;
use std::collections::HashMap;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;
use tokio::sync::mpsc::{unbounded_channel, UnboundedReceiver, UnboundedSender};
use tokio::time::Instant;

#[derive(Parser, Debug)]
#[command(
    version,
    about = "FALC operator node: order list, recipe store, journal, operator API"
)]
struct Cli {
    /// The station this process is (the root of the topology).
    #[arg(long, default_value = "operator")]
    station: StationName,
    /// The recipe tree (`cell/`, `welding/`, `transport/`).
    #[arg(long, default_value = "recipes")]
    recipes: PathBuf,
    /// The order list and journal (SQLite).
    #[arg(long, default_value = "var/falc.db")]
    db: PathBuf,
    /// How many orders may wait in the order list; one more is refused.
    #[arg(long, default_value_t = falc_model::console::MAX_QUEUED_ORDERS)]
    max_queued_orders: usize,
    #[command(flatten)]
    node: NodeArgs,
}

/// How long a Start, Stop or Initiate of the cell may take.
const CELL_LIMIT: Duration = Duration::from_secs(10);

/// What the cell lane sends.
enum LaneJob {
    /// The root's Initiates (the subordinates and their time limits).
    Initiates(Vec<(StationName, Duration)>),
    /// One request.
    Request(Request),
    /// One recipe delivery.
    Deliver(Delivery),
}

/// What came back of a [`LaneJob`].
enum LaneDone {
    /// The Initiates' outcomes, for the station to record.
    Initiates(Vec<(StationName, Result<Peer, ServiceError>)>),
    /// A request's or delivery's outcome.
    Done(Result<(), ServiceError>),
}

/// Starts the cell lane: its jobs go to `cell` one at a time, each outcome
/// comes back on the returned receiver.
fn cell_lane(
    bus: Bus,
    cell: StationName,
) -> (UnboundedSender<LaneJob>, UnboundedReceiver<LaneDone>) {
    let (done_tx, done) = unbounded_channel();
    let jobs = lane::spawn(done_tx, move |job: LaneJob| {
        let (bus, cell) = (bus.clone(), cell.clone());
        async move {
            match job {
                LaneJob::Initiates(subs) => {
                    LaneDone::Initiates(station::initiate_all(&bus, subs).await)
                }
                LaneJob::Request(req) => {
                    LaneDone::Done(bus.request(&cell, &req, CELL_LIMIT).await.map(|_| ()))
                }
                LaneJob::Deliver(d) if d.is_cell => {
                    LaneDone::Done(bus.deliver(&cell, &d.domain, &d.content).await)
                }
                LaneJob::Deliver(d) => {
                    LaneDone::Done(bus.deliver_domain(&cell, &d.domain, &d.content).await)
                }
            }
        }
    });
    (jobs, done)
}

/// The operator node: the order list core and what carries out its outputs.
struct Operator {
    list: OrderList<Database, RecipeDir>,
    station: Station,
    started: Instant,
    lane: UnboundedSender<LaneJob>,
    next_ticket: u64,
    /// Console requests waiting for their answer.
    consoles: HashMap<Ticket, ApiResponder>,
    /// The cell's indications waiting for their answer.
    indications: HashMap<Ticket, Responder>,
}

impl Operator {
    fn now(&self) -> Duration {
        self.started.elapsed()
    }

    fn ticket(&mut self) -> Ticket {
        self.next_ticket += 1;
        Ticket(self.next_ticket)
    }

    /// Carries out what the order list put out.
    async fn drain(&mut self) {
        while let Some(out) = self.list.poll_output() {
            match out {
                Output::Cell(call) => {
                    let job = match call {
                        CellCall::Associate => LaneJob::Initiates(self.station.initiates_due()),
                        CellCall::Initiate => LaneJob::Request(Request::Initiate {
                            calling: self.station.bus().me().clone(),
                        }),
                        CellCall::Deliver(d) => LaneJob::Deliver(d),
                        CellCall::Start { name, argument } => {
                            LaneJob::Request(Request::Start { name, argument })
                        }
                        CellCall::Stop { name } => LaneJob::Request(Request::Stop { name }),
                        CellCall::Pass(request) => LaneJob::Request(request),
                    };
                    if self.lane.send(job).is_err() {
                        tracing::error!("the cell lane stopped");
                    }
                }
                Output::Reply { ticket, result } => match self.consoles.remove(&ticket) {
                    Some(r) => r.respond(*result).await,
                    None => tracing::warn!("no console waits for answer {ticket:?}"),
                },
                Output::Respond { ticket, result } => match self.indications.remove(&ticket) {
                    Some(r) => r.respond(result).await,
                    None => tracing::warn!("no indication waits for answer {ticket:?}"),
                },
                Output::Forget(ticket) => {
                    self.indications.remove(&ticket);
                }
                Output::Say(line) => say(&line),
                Output::Changed => self.station.bus().publish_changed().await,
            }
        }
    }

    /// An outcome of the cell lane.
    async fn lane_done(&mut self, done: LaneDone) {
        let result = match done {
            LaneDone::Initiates(results) => {
                self.station.record_initiates(results).await.map(|_| ())
            }
            LaneDone::Done(result) => result,
        };
        let now = self.now();
        self.list.handle_cell_reply(now, result);
    }

    async fn on_station(&mut self, ev: StationEvent) {
        let now = self.now();
        match ev {
            StationEvent::Indication(ind) => {
                let ticket = self.ticket();
                self.indications.insert(ticket, ind.responder);
                self.list.handle_cell_request(now, ticket, ind.request);
            }
            StationEvent::Abort(a) => self.list.handle_abort(now, &a.reason),
            StationEvent::Associated(_) | StationEvent::Concluded(_) => {}
        }
    }
}

#[tokio::main]
async fn main() -> ExitCode {
    init_tracing();
    let cli = Cli::parse();
    match run(cli).await {
        Ok(code) => code,
        Err(e) => {
            tracing::error!("{e:#}");
            say(&format!("EVENT failed {e:#}"));
            ExitCode::FAILURE
        }
    }
}

async fn run(cli: Cli) -> Result<ExitCode> {
    let topology = cli.node.topology()?;
    let me = &cli.station;
    let cell = match topology.subordinates_of(me).as_slice() {
        [cell] => (*cell).clone(),
        other => anyhow::bail!(
            "station {me} must command exactly one cell in {}, it commands {}",
            cli.node.topology.display(),
            other.len()
        ),
    };
    // The PPS first: a defective recipe set never reaches the cell.
    let source = RecipeDir {
        dir: cli.recipes.clone(),
        topology: topology.clone(),
        cell: cell.clone(),
    };
    let recipes = match source.load() {
        Ok(set) => set,
        Err(problems) => {
            for p in &problems {
                say(p);
            }
            say(&format!(
                "EVENT refused {} recipe problem(s) in {}: nothing started, nothing downloaded",
                problems.len(),
                cli.recipes.display()
            ));
            return Ok(ExitCode::from(2));
        }
    };
    let mut db = Database::open(&cli.db)?;
    for o in db.recover()? {
        say(&format!(
            "EVENT interrupted order={} recipe={}",
            o.id, o.recipe
        ));
    }
    let settings = cli.node.settings(&topology, me)?;
    let station = Station::open(settings, &topology)
        .await
        .context("cannot join the cell network")?;
    let bus = station.bus().clone();
    let (api_tx, mut api) = unbounded_channel();
    let _api = bus.serve_api(api_tx).await?;
    let (utx, mut publications) = unbounded_channel();
    let (ptx, mut presence) = unbounded_channel();
    let mut subscriptions = Vec::new();
    for st in topology.stations().iter().filter(|s| &s.name != me) {
        subscriptions.extend(bus.subscribe(&st.name, utx.clone()).await?);
        subscriptions.push(bus.presence(&st.name, ptx.clone()).await?);
    }
    bus.sync_with_router().await?;
    let (lane, mut lane_done) = cell_lane(bus.clone(), cell.clone());
    let list = OrderList::new(me.clone(), cell, topology, db, source, recipes)
        .with_max_queued(cli.max_queued_orders);
    let mut op = Operator {
        list,
        station,
        started: Instant::now(),
        lane,
        next_ticket: 0,
        consoles: HashMap::new(),
        indications: HashMap::new(),
    };
    let who = me.to_string();
    op.list
        .journal(EntryKind::System, None, &who, "operator node started");
    op.drain().await;
    say(&format!("EVENT ready station={me} db={}", cli.db.display()));
    let mut shutdown = falc_node::Shutdown::new();
    loop {
        let wake = op.list.poll_timeout().map(|t| op.started + t);
        let timer = async {
            match wake {
                Some(at) => tokio::time::sleep_until(at).await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            ev = op.station.recv() => {
                let Some(ev) = ev else { anyhow::bail!("the cell network session ended") };
                if let Some(ev) = op.station.handle(ev).await {
                    op.on_station(ev).await;
                }
            }
            Some(ind) = api.recv() => {
                let ticket = op.ticket();
                op.consoles.insert(ticket, ind.responder);
                let now = op.now();
                op.list.handle_api(now, ticket, &ind.user, ind.request);
            }
            Some(u) = publications.recv() => {
                let now = op.now();
                op.list.handle_publication(now, u);
            }
            Some(p) = presence.recv() => {
                let now = op.now();
                op.list.handle_presence(now, p.station, p.present);
            }
            Some(done) = lane_done.recv() => op.lane_done(done).await,
            _ = timer => {
                let now = op.now();
                op.list.handle_timeout(now);
            }
            _ = shutdown.requested() => break,
        }
        op.drain().await;
        if op.list.should_stop() {
            break;
        }
    }
    op.list
        .journal(EntryKind::System, None, &who, "operator node stopped");
    op.drain().await;
    op.station.conclude_subordinates().await;
    drop(subscriptions);
    say("EVENT stopped");
    Ok(ExitCode::SUCCESS)
}
