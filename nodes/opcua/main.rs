//! `falc-opcua`: the cell, or the plant and each of its cells, on OPC UA
//! (IEC 62541) for a plant's SCADA, MES and historians. A client of the
//! operator API like the console, as its own console user (`opcua`, role
//! operator in `launch/cell.toml` and `launch/factory.toml`, so the
//! router's ACL bounds everything it does); it looks as soon as the
//! operator says something changed, after a method call, and every
//! `--poll-ms`, and serves what it saw as an address space whose
//! subscribers are notified of each change (`space` computes it, `server`
//! serves it, `front` admits clients by their address, `users` says who
//! may do what and `throttle` slows and locks failed logins, `packml` maps
//! a cell onto PackML states).

mod condition_methods;
mod conditions;
mod front;
mod job_management;
mod jobs;
mod machinery;
mod packml;
mod result_management;
mod server;
mod space;
mod structures;
mod throttle;
mod users;

use clap::Parser;
use falc_bus::operator_service::CallError;
use falc_bus::Bus;
use falc_equipment::Equipment;
use falc_model::api::{ApiReply, ApiRequest, CellStatus};
use falc_model::figures::{FigureQuery, Figures};
use falc_model::ids::StationName;
use falc_model::plant::Layout;
use falc_model::records::{Entry, Order};
use falc_model::topology::Topology;
use falc_node::{say, NodeArgs, Shutdown};
use space::{Part, Scope};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

/// How old the figures behind the PackML Admin values may grow while the
/// journal does not move (time in a state grows all the same).
const FIGURES_AGE: Duration = Duration::from_secs(10);

/// How often the gateway prunes its rejected client certificates.
const PRUNE_EVERY: Duration = Duration::from_secs(10);

/// The window of the PackML Admin state times: the last day (the
/// operator computes them from its records; a window keeps that cost
/// the same however long the records grow).
const FIGURES_WINDOW_MS: i64 = 86_400_000;

#[derive(Parser, Debug)]
#[command(
    name = "falc-opcua",
    version,
    about = "FALC OPC UA gateway: the cell's (or each cell of a plant's) state, stations, orders, journal and alarms, and its methods, for any OPC UA client"
)]
struct Cli {
    #[command(flatten)]
    node: NodeArgs,
    /// The gateway's console user (a `[[console]]` of the topology).
    #[arg(long, default_value = "opcua")]
    user: StationName,
    /// Where OPC UA clients connect: host (named in the endpoint URL) and
    /// port.
    #[arg(long, default_value = "127.0.0.1:4840")]
    listen: String,
    /// The server's certificate and key (made on first start), trusted and
    /// rejected client certificates; default `<credentials-dir>/opcua-pki`.
    #[arg(long)]
    pki_dir: Option<PathBuf>,
    /// The OPC UA users (name, role, password; private); made from the
    /// topology's console users on first start. Default
    /// `<credentials-dir>/opcua-users.toml`.
    #[arg(long)]
    users: Option<PathBuf>,
    /// How often to look at the cell when the operator has said nothing,
    /// in ms. A change is looked at as soon as the operator publishes it
    /// (`falc/<cell>/<operator>/changed`); this look is for what that
    /// publication cannot tell (the operator gone, a change while this
    /// gateway was away).
    #[arg(long, default_value_t = 1000)]
    poll_ms: u64,
    /// How many of the newest journal entries to serve (of each cell's
    /// and the plant's in a plant), 1 to 500.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u16).range(1..=500))]
    journal_entries: u16,
    /// How long a client address stays locked after 10 failed logins, in
    /// seconds (failures 4 to 9 are answered after a growing delay; a
    /// locked address's connections are refused).
    #[arg(long, default_value_t = 60)]
    login_lockout_s: u64,
    /// Connections one client address may hold open at once.
    #[arg(long, default_value_t = front::PER_ADDRESS, value_parser = clap::value_parser!(u32).range(1..))]
    connections_per_address: u32,
    /// New connections one client address may open in a minute.
    #[arg(long, default_value_t = front::PER_MINUTE, value_parser = clap::value_parser!(u32).range(1..))]
    connections_per_minute: u32,
    /// Also offer an endpoint without signing and encryption (commissioning
    /// only; passwords still cross encrypted with the server's key).
    #[arg(long)]
    insecure: bool,
}

fn main() -> ExitCode {
    let (connection_tasks, tasks) = front::ConnectionTasks::new();
    falc_node::init_tracing_with(connection_tasks, front::ConnectionTasks::filter);
    let cli = Cli::parse();
    match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
    {
        Ok(rt) => match rt.block_on(run(cli, tasks)) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                tracing::error!("falc-opcua stops: {e}");
                eprintln!("falc-opcua: {e}");
                ExitCode::from(2)
            }
        },
        Err(e) => {
            eprintln!("falc-opcua: cannot start the async runtime: {e}");
            ExitCode::from(2)
        }
    }
}

/// `host:port`, the port a number.
fn host_port(listen: &str) -> Result<(String, u16), String> {
    let (host, port) = listen
        .rsplit_once(':')
        .ok_or_else(|| format!("--listen {listen}: give host:port (127.0.0.1:4840)"))?;
    let port = port
        .parse::<u16>()
        .map_err(|e| format!("--listen {listen}: port: {e}"))?;
    if host.is_empty() || port == 0 {
        return Err(format!(
            "--listen {listen}: give a host and a port other than 0 (clients must know it)"
        ));
    }
    Ok((host.trim_matches(['[', ']']).to_string(), port))
}

/// What the gateway does after waiting.
#[derive(PartialEq)]
enum Next {
    Look,
    Stop,
}

/// A topology's stations, as the address space lays them out.
fn stations_of(t: &Topology) -> Vec<(StationName, falc_model::topology::StationKind)> {
    t.stations()
        .iter()
        .map(|s| (s.name.clone(), s.kind))
        .collect()
}

/// A cell's topology as a machine of OPC UA Machinery.
fn machine_of(t: &Topology) -> machinery::Machine {
    machinery::Machine {
        name: t.cell().to_string(),
        identification: t.identification().clone(),
    }
}

async fn run(
    cli: Cli,
    tasks: tokio::sync::mpsc::UnboundedReceiver<tokio::task::Id>,
) -> Result<(), String> {
    // A cell's topology, or a plant's: the gateway logs in where a console
    // does, and serves the one cell or the plant with each of its cells.
    let layout = Layout::load(&cli.node.topology).map_err(|e| e.to_string())?;
    let topology = cli.node.console_topology().map_err(|e| e.to_string())?;
    let (what, scopes) = match &layout {
        Layout::Cell(t) => {
            let equipment = Equipment::of_topology(t)?;
            let scopes = Scope::one_cell(stations_of(t))
                .into_iter()
                .map(|s| {
                    s.with_equipment(equipment.clone())
                        .with_machine(machine_of(t))
                })
                .collect();
            ("cell", scopes)
        }
        Layout::Plant(p) => {
            let mut scopes = Scope::plant(
                p.cells()
                    .iter()
                    .map(|c| (c.id().clone(), stations_of(c.topology())))
                    .collect(),
            );
            // The plant's own scope first, then one per cell in order.
            for (scope, cell) in scopes.iter_mut().skip(1).zip(p.cells()) {
                let equipment = Equipment::of_topology(cell.topology())?;
                *scope = scope
                    .clone()
                    .with_equipment(equipment)
                    .with_machine(machine_of(cell.topology()));
            }
            ("plant", scopes)
        }
    };
    let me = topology.console(&cli.user).ok_or_else(|| {
        format!(
            "`{}` is not a console user of {}: add a [[console]] stanza for the gateway (role operator)",
            cli.user,
            cli.node.topology.display()
        )
    })?;
    let ceiling = me.role;
    let (host, port) = host_port(&cli.listen)?;
    let users_path = cli
        .users
        .clone()
        .unwrap_or_else(|| cli.node.credentials_dir.join("opcua-users.toml"));
    let clients = Arc::new(front::Clients::new(
        front::Limits {
            per_address: cli.connections_per_address,
            per_minute: cli.connections_per_minute,
        },
        Duration::from_secs(cli.login_lockout_s),
    ));
    let users = users::Users::ensure(&users_path, &topology, cli.user.as_str(), ceiling)
        .map_err(|e| e.to_string())?
        .with_clients(clients.clone());
    // Clients reach the front on the public address; the server listens
    // on loopback, for the front alone.
    let public = tokio::net::TcpListener::bind((host.as_str(), port))
        .await
        .map_err(|e| format!("cannot listen on {host}:{port}: {e}"))?;
    let inner = tokio::net::TcpListener::bind((std::net::Ipv4Addr::LOCALHOST, 0))
        .await
        .map_err(|e| format!("cannot listen on a loopback port for the OPC UA server: {e}"))?;
    let inner_addr = inner
        .local_addr()
        .map_err(|e| format!("the OPC UA server's loopback port: {e}"))?;
    let settings = cli
        .node
        .settings(&topology, &cli.user)
        .map_err(|e| e.to_string())?;
    let bus = Bus::open(settings).await.map_err(|e| e.to_string())?;
    let operator = topology.root().name.clone();
    let endpoint = server::Endpoint {
        host: host.clone(),
        port,
        pki_dir: cli
            .pki_dir
            .clone()
            .unwrap_or_else(|| cli.node.credentials_dir.join("opcua-pki")),
        insecure: cli.insecure,
    };
    let (opcua_server, running) = server::build(
        &endpoint,
        (what, topology.cell().as_str()),
        scopes.clone(),
        Arc::new(users),
        bus.clone(),
        operator.clone(),
    )?;
    let mut serving = tokio::spawn(opcua_server.run_with(inner));
    // The server lays out the address space once it runs, then takes the
    // loopback port for its own: its endpoint URLs (and the URL a client
    // names, matched but for the host) must carry the public one.
    let laid_out = tokio::time::Instant::now() + Duration::from_secs(10);
    let server_port = &running.handle.info().port;
    while !running.laid_out()
        || server_port.load(std::sync::atomic::Ordering::Relaxed) != inner_addr.port()
    {
        if tokio::time::Instant::now() > laid_out || serving.is_finished() {
            return Err(format!(
                "the OPC UA server did not start at {}:{port} (see the log above)",
                host
            ));
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    server_port.store(port, std::sync::atomic::Ordering::Relaxed);
    let front = tokio::spawn(front::serve(public, inner_addr, clients, tasks));
    // The operator's word that its status changed: look at once.
    let poked = running.poked.clone();
    let _changed = bus
        .on_changed(&operator, move || poked.notify_one())
        .await
        .map_err(|e| e.to_string())?;
    let mut shutdown = Shutdown::new();
    let mut mirrors: Vec<space::Mirror> = scopes.iter().map(|_| space::Mirror::default()).collect();
    let mut ended: Vec<result_management::Ended> =
        scopes.iter().map(|_| Default::default()).collect();
    let mut poller = Poller::new(scopes.clone(), cli.journal_entries);
    let mut ready = false;
    let mut next_prune = std::time::Instant::now();
    let period = Duration::from_millis(cli.poll_ms.max(10));
    loop {
        // A look waits for the operator (up to 2 s a call when it is gone):
        // a stop is heard meanwhile too. What the status says is written
        // at once (the orders and journal it held before), the order list
        // and journals after, when the journal moved: a change of state is
        // not held back by more calls.
        let moved = tokio::select! {
            moved = poller.status(&bus, &operator) => moved,
            _ = shutdown.requested() => break,
        };
        let mut write = |poller: &Poller| {
            let refusals = running
                .last_refusals
                .lock()
                .map(|s| s.clone())
                .unwrap_or_default();
            let cleared = running
                .cleared_jobs
                .lock()
                .map(|c| c.clone())
                .unwrap_or_default();
            for (at, (scope, mirror)) in scopes.iter().zip(mirrors.iter_mut()).enumerate() {
                let look = space::Look {
                    cleared_jobs: cleared.clone(),
                    ..poller.look(at, refusals.get(at).cloned().unwrap_or_default())
                };
                let alarms = look
                    .status
                    .as_ref()
                    .map(|s| s.alarms.clone())
                    .unwrap_or_default();
                let changes = mirror.update(space::values(scope, &look), &alarms);
                if !running.set(&changes.values) {
                    mirror.forget_values();
                }
                // Conditions follow the alarm list the operator gave (none
                // while it does not answer: nothing is known to change);
                // then the plain alarm events, last on the Server object
                // for a client that keeps one event an interval.
                if look.status.is_some() {
                    running.conditions(at, scope, &alarms);
                }
                running.raise(&scope.root, &changes.events);
                mirror.written(std::time::Instant::now(), &changes.values);
            }
        };
        write(&poller);
        if !moved && poller.figures_stale() {
            tokio::select! {
                _ = poller.fetch_figures(&bus, &operator) => {}
                _ = shutdown.requested() => break,
            }
            write(&poller);
        }
        if moved {
            let lists = tokio::select! {
                lists = poller.lists(&bus, &operator) => lists,
                _ = shutdown.requested() => break,
            };
            if lists {
                write(&poller);
                // Each order that ended since is a result that is ready.
                let ready = tokio::select! {
                    _ = poller.results_ready(&bus, &operator, &mut ended, &running) => true,
                    _ = shutdown.requested() => false,
                };
                if !ready {
                    break;
                }
            }
        }
        // A stranger's every attempt leaves a rejected certificate: the
        // folder keeps the newest only (looked at every PRUNE_EVERY, not
        // on every look).
        let pruning = if std::time::Instant::now() >= next_prune {
            next_prune = std::time::Instant::now() + PRUNE_EVERY;
            server::prune_rejected(&endpoint.pki_dir.join("rejected"), server::KEEP_REJECTED)
        } else {
            Ok(0)
        };
        match pruning {
            Ok(0) => {}
            Ok(n) => tracing::info!(
                "{n} rejected client certificates removed: {} keeps the newest {}",
                endpoint.pki_dir.join("rejected").display(),
                server::KEEP_REJECTED
            ),
            Err(e) => tracing::warn!("the rejected client certificates cannot be pruned: {e}"),
        }
        if !ready {
            ready = true;
            say(&format!(
                "EVENT ready opc.tcp://{host}:{port}/ (falc-opcua, {what} {}, console user {})",
                topology.cell(),
                cli.user
            ));
        }
        // Until the next look: write again what was written when it is due
        // (space::REFRESH).
        let next = loop {
            let due = async {
                match mirrors.iter().filter_map(space::Mirror::next_refresh).min() {
                    Some(at) => tokio::time::sleep_until(at.into()).await,
                    None => std::future::pending().await,
                }
            };
            tokio::select! {
                _ = tokio::time::sleep(period) => break Next::Look,
                _ = running.poked.notified() => break Next::Look,
                _ = due => {
                    let now = std::time::Instant::now();
                    for mirror in &mut mirrors {
                        running.set(&mirror.refresh(now));
                    }
                }
                _ = shutdown.requested() => break Next::Stop,
                ended = &mut serving => {
                    return Err(match ended {
                        Ok(Ok(())) => "the OPC UA server ended".to_string(),
                        Ok(Err(e)) => format!("the OPC UA server failed: {e}"),
                        Err(e) => format!("the OPC UA server task failed: {e}"),
                    });
                }
            }
        };
        if next == Next::Stop {
            break;
        }
    }
    tracing::info!("falc-opcua stopping");
    front.abort();
    running.handle.cancel();
    let _ = tokio::time::timeout(Duration::from_secs(5), serving).await;
    Ok(())
}

/// Looks at the cell, or the plant, through the operator API: the status
/// every time, the order list and each object's newest journal entries
/// when the journal moved.
struct Poller {
    scopes: Vec<Scope>,
    /// Each scope's status (None: the operator did not answer; the
    /// plant's object has none).
    statuses: Option<Vec<Option<CellStatus>>>,
    /// The journal's head as the last status said.
    head: Option<i64>,
    /// The journal's head when the lists were last fetched.
    journal_head: Option<i64>,
    orders: Vec<Order>,
    /// Each scope's newest journal entries.
    journals: Vec<Vec<Entry>>,
    /// Every cell's figures of the last day (the PackML Admin values), when
    /// last fetched.
    figures: Option<(Figures, std::time::Instant)>,
    keep: u16,
    unreachable_said: bool,
}

impl Poller {
    /// Sends a ResultReadyEvent for each order of a machine's cell that
    /// ended since the order list was last fetched (`ended`: what each
    /// scope saw), with its product record.
    async fn results_ready(
        &self,
        bus: &Bus,
        operator: &StationName,
        ended: &mut [result_management::Ended],
        running: &server::Running,
    ) {
        for (at, (scope, seen)) in self.scopes.iter().zip(ended.iter_mut()).enumerate() {
            if scope.machine.is_none() {
                continue;
            }
            let mine = space::cell_orders(scope.cell(), &self.orders);
            for id in seen.update(&mine) {
                let Some(order) = mine.iter().find(|o| o.id == id) else {
                    continue;
                };
                let record = match bus
                    .clone()
                    .for_cell(scope.cell().cloned())
                    .api(
                        operator,
                        ApiRequest::OrderShow { id },
                        Duration::from_secs(2),
                    )
                    .await
                {
                    Ok(ApiReply::OrderRecord(r)) => Some(*r),
                    _ => None,
                };
                if let Some(result) = result_management::of(order, record.as_ref()) {
                    running.result_ready(at, &result);
                }
            }
        }
    }

    fn new(scopes: Vec<Scope>, keep: u16) -> Self {
        Self {
            journals: vec![Vec::new(); scopes.len()],
            figures: None,
            scopes,
            statuses: None,
            head: None,
            journal_head: None,
            orders: Vec::new(),
            keep: keep.max(1),
            unreachable_said: false,
        }
    }

    async fn call(&mut self, bus: &Bus, operator: &StationName, r: ApiRequest) -> Option<ApiReply> {
        match bus.api(operator, r, Duration::from_secs(2)).await {
            Ok(reply) => {
                if self.unreachable_said {
                    tracing::info!("the operator answers again");
                    self.unreachable_said = false;
                }
                Some(reply)
            }
            Err(e) => {
                if !self.unreachable_said {
                    let what = match &e {
                        CallError::NoReply(_) => "no reply",
                        CallError::Refused(_) => "refused",
                    };
                    tracing::warn!("the operator API gave {what}: {e}");
                    self.unreachable_said = true;
                }
                None
            }
        }
    }

    /// Asks for the status (of the one cell, or every cell of the plant
    /// in one call); whether the journal moved since the order list and
    /// journals were last fetched ([`Self::lists`]).
    async fn status(&mut self, bus: &Bus, operator: &StationName) -> bool {
        let reply = self.call(bus, operator, ApiRequest::Status).await;
        let head = match &reply {
            Some(ApiReply::Status(s)) => s.journal_head,
            Some(ApiReply::Plant(p)) => p
                .cells
                .iter()
                .map(|(_, s)| s.journal_head)
                .max()
                .unwrap_or(0),
            _ => {
                self.statuses = None;
                self.head = None;
                self.journal_head = None;
                return false;
            }
        };
        let statuses = self
            .scopes
            .iter()
            .map(|scope| space::status_of(scope, reply.as_ref()))
            .collect();
        let moved = self.journal_head != Some(head);
        self.head = Some(head);
        self.statuses = Some(statuses);
        moved
    }
    /// Asks for the order list and each object's newest journal entries;
    /// whether all came.
    async fn lists(&mut self, bus: &Bus, operator: &StationName) -> bool {
        let Some(head) = self.head else {
            return false;
        };
        let Some(ApiReply::Orders(orders)) = self.call(bus, operator, ApiRequest::OrderList).await
        else {
            return false;
        };
        // Each object's newest entries (a cell's own, the plant's or the
        // one cell's all).
        let mut journals = Vec::with_capacity(self.scopes.len());
        for at in 0..self.scopes.len() {
            let of = bus.clone().for_cell(self.scopes[at].cell().cloned());
            let request = ApiRequest::Journal {
                order: None,
                after: 0,
                last: Some(self.keep),
            };
            let Some(ApiReply::Entries(j)) = self.call(&of, operator, request).await else {
                return false;
            };
            journals.push(j);
        }
        self.orders = orders;
        self.journals = journals;
        self.journal_head = Some(head);
        self.fetch_figures(bus, operator).await;
        true
    }

    /// Asks for every cell's figures of the last day (the Admin values): after
    /// the journal moved, or [`FIGURES_AGE`] after the last time.
    async fn fetch_figures(&mut self, bus: &Bus, operator: &StationName) {
        let now_ms = falc_node::now_ms();
        let request = ApiRequest::Figures(FigureQuery {
            since_ms: (now_ms - FIGURES_WINDOW_MS).max(0),
            until_ms: None,
            planned: Vec::new(),
        });
        if let Some(ApiReply::Figures(f)) = self.call(bus, operator, request).await {
            self.figures = Some((*f, std::time::Instant::now()));
        }
    }

    /// Whether the figures are older than [`FIGURES_AGE`].
    fn figures_stale(&self) -> bool {
        self.figures
            .as_ref()
            .map_or(true, |(_, at)| at.elapsed() > FIGURES_AGE)
    }

    /// What the gateway serves now on scope `at`'s object: the last status
    /// with the order list and journal last fetched (none while the
    /// operator is away).
    fn look(&self, at: usize, last_refusal: String) -> space::Look {
        match &self.statuses {
            Some(statuses) => space::Look {
                reachable: true,
                status: statuses.get(at).cloned().flatten(),
                orders: self.orders.clone(),
                journal: self.journals.get(at).cloned().unwrap_or_default(),
                last_refusal,
                cleared_jobs: Vec::new(),
                figures: self.figures.as_ref().and_then(|(f, _)| {
                    let scope = self.scopes.get(at)?;
                    let Part::Cell { id, .. } = &scope.part else {
                        return None;
                    };
                    f.cells
                        .iter()
                        .find(|c| id.as_ref().map_or(true, |id| c.cell == id.as_str()))
                        .cloned()
                }),
            },
            None => space::Look {
                last_refusal,
                ..space::Look::default()
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn listen_addresses_are_checked() {
        assert_eq!(host_port("127.0.0.1:4840"), Ok(("127.0.0.1".into(), 4840)));
        assert_eq!(host_port("[::1]:4841"), Ok(("::1".into(), 4841)));
        for bad in ["4840", "host:x", ":4840", "h:0"] {
            assert!(host_port(bad).is_err(), "{bad}");
        }
    }
}
