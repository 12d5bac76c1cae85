//! `falc-operator`: the factory controller at the root of the cell, or of
//! every cell of a plant (`--topology launch/factory.toml`). At start it
//! checks every recipe of the recipe directory for each cell (the PPS,
//! `recipe_store`) and refuses to start with every problem as
//! `file:line: reason`; it opens the order list and journal (`database`,
//! SQLite WAL, a connection per cell), marks an order a crash interrupted,
//! associates each cell (retrying every second while it cannot) and
//! delivers the recipes; then it serves the operator API to consoles and
//! operator communication (`input`, `output`) to each cell, and, with
//! `--metrics`, OpenMetrics to the plant's monitoring (`metrics`).
//!
//! A thin driver: the behaviour is `falc_factory::plant` over one
//! `falc_factory::order_list` per cell (sans-I/O); here are start-up, the
//! event loop and the cell lanes, one task per cell that sends its list's
//! requests to its cell, one at a time. In a plant one session carries
//! every cell's key space (`Bus::alongside`). Nothing in the loop waits on
//! a cell: a console's `status` is answered while a start or a delivery is
//! under way.

mod database;
mod metrics;
mod recipe_store;

use anyhow::{Context, Result};
use clap::Parser;
use database::Database;
use falc_bus::operator_service::ApiResponder;
use falc_bus::station::{self, Station, StationEvent};
use falc_bus::{Bus, BusEvent, Declaration, Presence, Responder, DEFAULT_DEADLINE};
use falc_factory::order_list::{CellCall, OrderList, Output, Ticket, CELL_LIMIT};
use falc_factory::plant::{Plant, PlantOutput};
use falc_factory::recipe_source::{Delivery, RecipeSet, RecipeSource};
use falc_factory::records::Records;
use falc_model::ids::StationName;
use falc_model::keys::KeySpace;
use falc_model::mms::error::ServiceError;
use falc_model::mms::journal::{KeptReports, Publication};
use falc_model::mms::pdu::{Request, Response};
use falc_model::plant::Layout;
use falc_model::records::EntryKind;
use falc_model::topology::{StationKind, Topology};
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
    #[arg(long, default_value_t = falc_model::api::MAX_QUEUED_ORDERS)]
    max_queued_orders: usize,
    /// Serve OpenMetrics for the plant's monitoring at
    /// `http://HOST:PORT/metrics` (orders, cycle times, alarms, seconds
    /// in each PackML state).
    #[arg(long, value_name = "HOST:PORT")]
    metrics: Option<std::net::SocketAddr>,
    #[command(flatten)]
    node: NodeArgs,
}

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
    Initiates(Vec<(StationName, Result<Response, ServiceError>)>),
    /// A request's or delivery's outcome.
    Done(Result<Response, ServiceError>),
}

/// Starts cell `index`'s lane: its jobs go to `cell` one at a time, each
/// outcome comes back on `done` with the cell's index.
fn cell_lane(
    bus: Bus,
    cell: StationName,
    index: usize,
    done: UnboundedSender<(usize, LaneDone)>,
) -> UnboundedSender<LaneJob> {
    let (done_tx, mut outcomes) = unbounded_channel();
    tokio::spawn(async move {
        while let Some(d) = outcomes.recv().await {
            if done.send((index, d)).is_err() {
                break;
            }
        }
    });
    lane::spawn(done_tx, move |job: LaneJob| {
        let (bus, cell) = (bus.clone(), cell.clone());
        async move {
            match job {
                LaneJob::Initiates(subs) => {
                    LaneDone::Initiates(station::initiate_all(&bus, subs).await)
                }
                LaneJob::Request(req) => LaneDone::Done(bus.request(&cell, &req, CELL_LIMIT).await),
                LaneJob::Deliver(d) if d.is_cell => LaneDone::Done(
                    bus.deliver(&cell, &d.domain, &d.content)
                        .await
                        .map(|()| Response::Done),
                ),
                LaneJob::Deliver(d) => LaneDone::Done(
                    bus.deliver_domain(&cell, &d.domain, &d.content)
                        .await
                        .map(|()| Response::Done),
                ),
            }
        }
    })
}

/// One cell as the operator drives it: its station (the operator's place
/// in the cell), the lane to its cell controller, its subscriptions.
struct CellDriver {
    station: Station,
    lane: UnboundedSender<LaneJob>,
    _subscriptions: Vec<Declaration>,
}

/// The operator node: the plant core (one order list per cell) and what
/// carries out its outputs.
struct Operator {
    plant: Plant<Database, RecipeDir>,
    cells: Vec<CellDriver>,
    /// The session the consoles ask (the plant's key space, or the one
    /// cell's).
    api_bus: Bus,
    started: Instant,
    next_ticket: u64,
    /// Console requests waiting for their answer.
    consoles: HashMap<Ticket, ApiResponder>,
    /// The cells' indications waiting for their answer.
    indications: HashMap<Ticket, Responder>,
    /// Where the stations' kept reports come back, read after a cut.
    kept: UnboundedSender<(usize, StationName, Result<KeptReports, String>)>,
}

impl Operator {
    fn now(&self) -> Duration {
        self.started.elapsed()
    }

    fn ticket(&mut self) -> Ticket {
        self.next_ticket += 1;
        Ticket(self.next_ticket)
    }

    /// Carries out what the plant put out.
    async fn drain(&mut self) {
        while let Some(out) = self.plant.poll_output() {
            match out {
                PlantOutput::Reply { ticket, result } => match self.consoles.remove(&ticket) {
                    Some(r) => r.respond(*result).await,
                    None => tracing::warn!("no console waits for answer {ticket:?}"),
                },
                PlantOutput::Cell(i, out) => self.carry_out(i, out).await,
            }
        }
    }

    /// Carries out cell `i`'s list's output.
    async fn carry_out(&mut self, i: usize, out: Output) {
        let Some(cell) = self.cells.get(i) else {
            return tracing::error!("no cell {i}");
        };
        match out {
            Output::Cell(call) => {
                let job = match call {
                    // The root's Initiate: of the cell and what it needs.
                    CellCall::Associate => LaneJob::Initiates(cell.station.initiates()),
                    call => match call.request(cell.station.bus().me()) {
                        Ok(request) => LaneJob::Request(request),
                        Err(delivery) => LaneJob::Deliver(*delivery),
                    },
                };
                if cell.lane.send(job).is_err() {
                    tracing::error!("the cell lane stopped");
                }
            }
            Output::Respond { ticket, result } => match self.indications.remove(&ticket) {
                Some(r) => r.respond(result).await,
                None => tracing::warn!("no indication waits for answer {ticket:?}"),
            },
            Output::Forget(ticket) => {
                self.indications.remove(&ticket);
            }
            Output::Say(line) => say(&line),
            Output::Changed => self.api_bus.publish_changed().await,
            Output::ReadReports { station, after } => {
                let bus = cell.station.bus().clone();
                let tx = self.kept.clone();
                tokio::spawn(async move {
                    let answer = bus
                        .read_reports(&station, after, DEFAULT_DEADLINE)
                        .await
                        .map_err(|e| e.to_string());
                    let _ = tx.send((i, station, answer));
                });
            }
        }
    }

    /// An outcome of cell `i`'s lane.
    async fn lane_done(&mut self, i: usize, done: LaneDone) {
        let Some(cell) = self.cells.get_mut(i) else {
            return;
        };
        let result = match done {
            LaneDone::Initiates(results) => cell
                .station
                .record_initiates(results)
                .await
                .map(|_| Response::Done),
            LaneDone::Done(result) => result,
        };
        let now = self.now();
        if let Some(list) = self.plant.list(i) {
            list.handle_cell_answer(now, result);
        }
    }

    async fn on_station(&mut self, i: usize, ev: StationEvent) {
        let now = self.now();
        match ev {
            StationEvent::Indication(ind) => {
                let ticket = self.ticket();
                self.indications.insert(ticket, ind.responder);
                if let Some(list) = self.plant.list(i) {
                    list.handle_cell_request(now, ticket, ind.request);
                }
            }
            StationEvent::Abort(a) => {
                if let Some(list) = self.plant.list(i) {
                    list.handle_abort(now, &a.reason);
                }
            }
            StationEvent::Associated(_) | StationEvent::Concluded(_) => {}
        }
    }

    /// The next event of any cell's station.
    async fn next_station_event(&mut self) -> Option<(usize, BusEvent)> {
        if self.cells.is_empty() {
            return std::future::pending().await;
        }
        let waits = self.cells.iter_mut().map(|c| Box::pin(c.station.recv()));
        let (ev, i, _) = futures::future::select_all(waits).await;
        ev.map(|ev| (i, ev))
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

/// One cell of the operator's: its topology and the cell controller it
/// commands.
struct CellPlan {
    topology: Topology,
    cell: StationName,
}

async fn run(cli: Cli) -> Result<ExitCode> {
    let me = &cli.station;
    // One cell (`launch/cell.toml`) or a plant (`launch/factory.toml`).
    let (plans, api_settings) = match Layout::load(&cli.node.topology)? {
        Layout::Cell(_) => {
            let topology = cli.node.topology()?;
            let settings = cli.node.settings(&topology, me)?;
            (vec![plan(&topology, me, &cli)?], settings)
        }
        Layout::Plant(mut plant) => {
            if let Some(r) = &cli.node.router {
                plant.set_router(r.clone());
            }
            if &plant.operator().name != me {
                anyhow::bail!(
                    "the plant's operator is {}, not {me}",
                    plant.operator().name
                );
            }
            let factory = plant.factory().clone();
            let settings = cli.node.settings(&factory, me)?;
            let plans = plant
                .cells()
                .iter()
                .map(|c| plan(c.topology(), me, &cli))
                .collect::<Result<Vec<_>>>()?;
            (plans, settings)
        }
    };
    // The PPS first: a defective recipe set never reaches a cell. Cells
    // of one layout (the same stations, kinds and commanders) have the
    // same set: checked and verified once.
    let mut sets = Vec::new();
    let mut checked: Vec<(Vec<LayoutKey>, RecipeSet)> = Vec::new();
    for p in &plans {
        let source = RecipeDir::new(cli.recipes.clone(), p.topology.clone(), p.cell.clone());
        let key = layout_key(&p.topology);
        if let Some((_, set)) = checked.iter().find(|(k, _)| *k == key) {
            sets.push((source, set.clone()));
            continue;
        }
        match source.load() {
            Ok(set) => {
                checked.push((key, set.clone()));
                sets.push((source, set));
            }
            Err(problems) => {
                for problem in &problems {
                    say(problem);
                }
                say(&format!(
                    "EVENT refused {} recipe problem(s) in {} for cell {}: nothing started, nothing downloaded",
                    problems.len(),
                    cli.recipes.display(),
                    p.topology.cell()
                ));
                return Ok(ExitCode::from(2));
            }
        }
    }
    // The order list and journal: one file, a connection per cell.
    let mut recovered = None;
    let mut dbs = Vec::new();
    let cell_ids: Vec<&str> = plans.iter().map(|p| p.topology.cell().as_str()).collect();
    for p in &plans {
        let mut db = Database::open(&cli.db, p.topology.cell().as_str())?;
        if recovered.is_none() {
            let r = db.recover(&cell_ids)?;
            for o in &r.interrupted {
                say(&format!(
                    "EVENT interrupted order={} recipe={}",
                    o.id, o.recipe
                ));
            }
            for o in &r.adopted {
                say(&format!("EVENT adopted order={} recipe={}", o.id, o.recipe));
            }
            recovered = Some(r);
        }
        dbs.push(db);
    }
    let mut adopted = recovered.map(|r| r.adopted).unwrap_or_default();
    if let Some(addr) = cli.metrics {
        let calendar = plans
            .first()
            .map(|p| p.topology.calendar().clone())
            .unwrap_or_default();
        let cells = cell_ids.iter().map(|c| c.to_string()).collect();
        let source = metrics::Source::open(&cli.db, calendar, cells)?;
        let listener = tokio::net::TcpListener::bind(addr)
            .await
            .with_context(|| format!("cannot serve the metrics at {addr}"))?;
        tracing::info!("OpenMetrics at http://{addr}/metrics");
        tokio::spawn(metrics::serve(listener, std::sync::Arc::new(source)));
    }
    let plant_of_one = plans.len() == 1;
    let api_bus = Bus::open(api_settings)
        .await
        .context("cannot join the network")?;
    let (utx, mut publications) = unbounded_channel::<(usize, Publication)>();
    let (kept, mut kept_reports) = unbounded_channel();
    let (ptx, mut presence) = unbounded_channel::<(usize, Presence)>();
    let (ltx, mut lane_done) = unbounded_channel::<(usize, LaneDone)>();
    let mut cells = Vec::new();
    let mut lists = Vec::new();
    // The one clock: the lists run on the time since this instant and
    // stamp their records with the system's time at it plus that.
    let started = Instant::now();
    let origin_ms = database::now_ms();
    for (i, ((p, (source, set)), db)) in plans.iter().zip(sets).zip(dbs).enumerate() {
        let keys = KeySpace::new(p.topology.cell().clone());
        // In a cell of its own the operator's API and its place in the
        // cell share the key space: one bus.
        let bus = if plant_of_one && api_bus.keys() == &keys {
            api_bus.clone()
        } else {
            api_bus.alongside(keys).await?
        };
        let station = Station::on(bus.clone(), &p.topology)
            .await
            .context("cannot join the cell network")?;
        let mut subscriptions = Vec::new();
        let (cell_utx, cell_urx) = unbounded_channel();
        let (cell_ptx, cell_prx) = unbounded_channel();
        forward(i, cell_urx, utx.clone());
        forward(i, cell_prx, ptx.clone());
        for st in p.topology.stations().iter().filter(|s| &s.name != me) {
            subscriptions.extend(bus.subscribe(&st.name, cell_utx.clone()).await?);
            subscriptions.push(bus.presence(&st.name, cell_ptx.clone()).await?);
        }
        bus.sync_with_router().await?;
        let lane = cell_lane(bus.clone(), p.cell.clone(), i, ltx.clone());
        let mut list = OrderList::new(
            me.clone(),
            p.cell.clone(),
            p.topology.clone(),
            db,
            source,
            set,
        )
        .with_max_queued(cli.max_queued_orders)
        .clocked_from(origin_ms);
        let cell_id = p.topology.cell().as_str();
        if let Some(k) = adopted
            .iter()
            .position(|o| o.cell.as_deref() == Some(cell_id))
        {
            list = list.adopting(adopted.swap_remove(k));
        }
        lists.push(list);
        cells.push(CellDriver {
            station,
            lane,
            _subscriptions: subscriptions,
        });
    }
    let (api_tx, mut api) = unbounded_channel();
    let _api = api_bus.serve_api(api_tx).await?;
    api_bus.sync_with_router().await?;
    let mut op = Operator {
        plant: Plant::new(lists),
        cells,
        api_bus,
        started,
        next_ticket: 0,
        consoles: HashMap::new(),
        indications: HashMap::new(),
        kept,
    };
    let who = me.to_string();
    if let Some(list) = op.plant.list(0) {
        list.journal(EntryKind::System, None, &who, "operator node started");
    }
    op.drain().await;
    say(&format!("EVENT ready station={me} db={}", cli.db.display()));
    let mut shutdown = falc_node::Shutdown::new();
    loop {
        let wake = op.plant.poll_timeout().map(|t| op.started + t);
        let timer = async {
            match wake {
                Some(at) => tokio::time::sleep_until(at).await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            ev = op.next_station_event() => {
                let Some((i, ev)) = ev else { anyhow::bail!("the cell network session ended") };
                let handled = match op.cells.get_mut(i) {
                    Some(c) => c.station.handle(ev).await,
                    None => None,
                };
                if let Some(ev) = handled {
                    op.on_station(i, ev).await;
                }
            }
            Some(ind) = api.recv() => {
                let ticket = op.ticket();
                op.consoles.insert(ticket, ind.responder);
                let now = op.now();
                op.plant.handle_api(now, ticket, &ind.user, ind.cell.as_ref(), ind.request);
            }
            Some((i, p)) = publications.recv() => {
                let now = op.now();
                if let Some(list) = op.plant.list(i) {
                    list.handle_heard(now, p.stamp, p.message);
                }
            }
            Some((i, station, answer)) = kept_reports.recv() => {
                let now = op.now();
                if let Some(list) = op.plant.list(i) {
                    list.handle_kept_reports(now, station, answer);
                }
            }
            Some((i, p)) = presence.recv() => {
                let now = op.now();
                if let Some(list) = op.plant.list(i) {
                    list.handle_presence(now, p.station, p.present);
                }
            }
            Some((i, done)) = lane_done.recv() => op.lane_done(i, done).await,
            _ = timer => {
                let now = op.now();
                op.plant.handle_timeout(now);
            }
            _ = shutdown.requested() => break,
        }
        op.drain().await;
        if op.plant.should_stop() {
            break;
        }
    }
    if let Some(list) = op.plant.list(0) {
        list.journal(EntryKind::System, None, &who, "operator node stopped");
    }
    op.drain().await;
    for c in &mut op.cells {
        c.station.conclude_subordinates().await;
    }
    say("EVENT stopped");
    Ok(ExitCode::SUCCESS)
}

/// What a cell's recipe set depends on: each station's name, kind and
/// commander (not its device or host, nor the cell's id).
type LayoutKey = (StationName, StationKind, Option<StationName>);

fn layout_key(topology: &Topology) -> Vec<LayoutKey> {
    topology
        .stations()
        .iter()
        .map(|s| (s.name.clone(), s.kind, s.commander.clone()))
        .collect()
}

/// The cell of `topology` the operator `me` commands.
fn plan(topology: &Topology, me: &StationName, cli: &Cli) -> Result<CellPlan> {
    match topology.subordinates_of(me).as_slice() {
        [cell] => Ok(CellPlan {
            topology: topology.clone(),
            cell: (*cell).clone(),
        }),
        other => anyhow::bail!(
            "station {me} must command exactly one cell controller in cell {} of {}, it commands {}",
            topology.cell(),
            cli.node.topology.display(),
            other.len()
        ),
    }
}

/// Forwards what `rx` receives to `tx`, tagged with cell `index`.
fn forward<T: Send + 'static>(
    index: usize,
    mut rx: UnboundedReceiver<T>,
    tx: UnboundedSender<(usize, T)>,
) {
    tokio::spawn(async move {
        while let Some(x) = rx.recv().await {
            if tx.send((index, x)).is_err() {
                break;
            }
        }
    });
}
