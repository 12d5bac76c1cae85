//! What every node binary does at start: the common command-line arguments
//! (topology, router, credentials), logging setup, and turning them into
//! [`BusSettings`]; and what node binaries share beyond that:
//!
//! - [`controller_node`]: drives a `falc_control` controller core on the bus;
//! - [`dnc_link`]: the serial port under the DNC procedure (tokio-serial);
//! - [`lane`]: a task that sends a node's requests one at a time;
//! - [`plc_link`]: the Modbus TCP link to the conveyor PLC (tokio-modbus);
//! - [`library_log`]: zenoh's and async-opcua's own warnings and errors,
//!   rate-limited.

pub mod controller_node;
pub mod dnc_link;
pub mod lane;
pub mod library_log;
pub mod plc_link;

use falc_bus::certificates;
use falc_bus::credentials::{self, CredentialsError};
use falc_bus::BusSettings;
use falc_model::ids::{CellId, StationName};
use falc_model::keys::KeySpace;
use falc_model::plant::{Layout, Plant};
use falc_model::topology::{Topology, TopologyError};
use std::path::PathBuf;
use std::time::Duration;

/// Arguments every node takes.
#[derive(Debug, Clone, clap::Args)]
pub struct NodeArgs {
    /// The cell topology file.
    #[arg(long, default_value = "launch/cell.toml")]
    pub topology: PathBuf,
    /// The router endpoint; overrides the topology's `router`.
    #[arg(long)]
    pub router: Option<String>,
    /// Directory of credential files (`<user>.toml`, mode 0600; on a TLS
    /// router also `<user>.crt`, `<user>.key` and the cell CA `ca.crt`).
    #[arg(long, default_value = "launch/credentials")]
    pub credentials_dir: PathBuf,
    /// This node's credentials file; default `<credentials-dir>/<station>.toml`.
    #[arg(long)]
    pub credentials: Option<PathBuf>,
    /// How long to keep trying to reach the router at start, in ms.
    #[arg(long, default_value_t = 10_000)]
    pub connect_timeout_ms: u64,
    /// In a plant: the topology file is the plant's (`launch/factory.toml`)
    /// and this node is a station of cell CELL, reaching that cell's
    /// router with its credentials from `<credentials-dir>/<CELL>/`.
    #[arg(long)]
    pub cell: Option<CellId>,
}

/// Why a node could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    /// The topology is missing or invalid.
    #[error(transparent)]
    Topology(#[from] TopologyError),
    /// The credentials are missing, unreadable or too open.
    #[error(transparent)]
    Credentials(#[from] CredentialsError),
    /// The plant has no such cell.
    #[error("the plant {topology} has no cell `{cell}`")]
    UnknownCell {
        /// The cell asked for.
        cell: CellId,
        /// The plant file.
        topology: String,
    },
    /// The station (or console user) is not in the topology.
    #[error("station or console `{station}` is not defined in {topology}")]
    UnknownStation {
        /// The station.
        station: StationName,
        /// The topology file.
        topology: String,
    },
}

impl NodeArgs {
    /// Loads the topology (with the router override applied).
    pub fn topology(&self) -> Result<Topology, SetupError> {
        let mut t = match &self.cell {
            None => Topology::load(&self.topology)?,
            Some(id) => {
                let plant = Plant::load(&self.topology)?;
                plant
                    .cell(id)
                    .map(|c| c.topology().clone())
                    .ok_or_else(|| SetupError::UnknownCell {
                        cell: id.clone(),
                        topology: self.topology.display().to_string(),
                    })?
            }
        };
        if let Some(r) = &self.router {
            t.set_router(r.clone());
        }
        Ok(t)
    }

    /// The topology a console logs in to: the cell's, or in a plant the
    /// factory level's (the operator and the console users, the factory
    /// router); `--cell` then names the cell its calls are for.
    pub fn console_topology(&self) -> Result<Topology, SetupError> {
        let mut t = match Layout::load(&self.topology)? {
            Layout::Cell(t) => t,
            Layout::Plant(p) => p.factory().clone(),
        };
        if let Some(r) = &self.router {
            t.set_router(r.clone());
        }
        Ok(t)
    }

    /// A console user's bus settings in `topology` (from
    /// [`Self::console_topology`]): its credentials from the credentials
    /// directory itself, a plant's cell or not.
    pub fn console_settings(
        &self,
        topology: &Topology,
        user: &StationName,
    ) -> Result<BusSettings, SetupError> {
        Self {
            cell: None,
            ..self.clone()
        }
        .settings(topology, user)
    }

    /// The bus settings of `station` (or of a console user).
    pub fn settings(
        &self,
        topology: &Topology,
        station: &StationName,
    ) -> Result<BusSettings, SetupError> {
        if topology.station(station).is_none() && topology.console(station).is_none() {
            return Err(SetupError::UnknownStation {
                station: station.clone(),
                topology: self.topology.display().to_string(),
            });
        }
        let dir = match &self.cell {
            Some(cell) => self.credentials_dir.join(cell.as_str()),
            None => self.credentials_dir.clone(),
        };
        let path = self
            .credentials
            .clone()
            .unwrap_or_else(|| dir.join(format!("{station}.toml")));
        let credentials = credentials::load(&path)?;
        // On a secure (QUIC) router the certificate and key sit beside the
        // credentials file (`<user>.crt`, `<user>.key`, `ca.crt`).
        let tls = if certificates::is_secure(topology.router()) {
            let files = certificates::TlsFiles::beside(&path);
            files.check()?;
            Some(files)
        } else {
            None
        };
        Ok(BusSettings {
            keys: KeySpace::new(topology.cell().clone()),
            me: station.clone(),
            endpoint: topology.router().to_string(),
            lease: topology.lease(),
            credentials: Some(credentials),
            tls,
            connect_timeout: Duration::from_millis(self.connect_timeout_ms),
        })
    }
}

/// Milliseconds since the Unix epoch, now (0 before it, saturating far
/// after it): the time stamps a node's shell hands its sans-I/O core.
pub fn now_ms() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
}

/// Logs to stderr ([`log_layer`]).
pub fn init_tracing() {
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    let _ = tracing_subscriber::Registry::default()
        .with(log_layer())
        .try_init();
}

/// Logs to stderr ([`log_layer`]), and hands what `filter` lets through
/// to a layer of the node's own (the OPC UA gateway hears of its server's
/// connections so).
pub fn init_tracing_with<L>(own: L, filter: fn(&tracing::Metadata<'_>) -> bool)
where
    L: tracing_subscriber::Layer<tracing_subscriber::Registry> + Send + Sync + 'static,
{
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    let _ = tracing_subscriber::Registry::default()
        .with(own.with_filter(tracing_subscriber::filter::filter_fn(filter)))
        .with(log_layer())
        .try_init();
}

/// The log of every FALC process, as a layer (the router adds its own
/// beside it): to stderr, filtered by `log_filter` and the libraries'
/// own warnings and errors rate-limited ([`library_log`]), colours only on a
/// terminal.
pub fn log_layer<S>() -> impl tracing_subscriber::Layer<S>
where
    S: tracing::Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
{
    use std::io::IsTerminal;
    use tracing_subscriber::Layer;
    tracing_subscriber::fmt::layer()
        .with_ansi(std::io::stderr().is_terminal())
        .with_writer(std::io::stderr)
        .with_filter(log_filter())
        .with_filter(library_log::LibraryLimit::new())
}

/// The log filter of every FALC process: `RUST_LOG`, else `info` with
/// zenoh's and async-opcua's own chatter at `warn`. zenoh's QUIC listener
/// warns once per failed handshake, unthrottled (a stranger's flood would
/// fill the log); the router reports those rate-limited in its own words
/// (`falc-router`'s `logins`), so they are left out here. async-opcua
/// writes INFO lines for every secure channel and session a client opens
/// (about 800 bytes an attempt, unthrottled, no credentials needed): left
/// out too; its warnings and errors are rate-limited ([`library_log`]),
/// and the gateway logs each login in its own words.
fn log_filter() -> tracing_subscriber::EnvFilter {
    use tracing_subscriber::EnvFilter;
    EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(LOG_FILTER))
}

/// [`log_filter`]'s default.
const LOG_FILTER: &str = "info,zenoh=warn,zenoh_transport=warn,zenoh_link_tcp=warn,\
     zenoh_link_commons::quic::unicast=error,opcua_server=warn,opcua_core=warn,\
     opcua_crypto=warn,opcua_types=warn,opcua_nodes=warn,opcua=warn";

/// Prints one line on stdout and flushes it: the events a node announces
/// for tests, launchers and people (`EVENT ready …`, a twin's port).
pub fn say(line: &str) {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    // Lines carry others' texts (a station's report, the cell's output, a
    // question): one line each, no escape reaching a terminal or journald.
    let _ = writeln!(out, "{}", falc_model::ids::printable(line));
    let _ = out.flush();
}

/// Ctrl-C (SIGINT) or SIGTERM (systemd, the launcher): a node's request to
/// stop, after which it concludes its associations and releases its device.
/// Both are listened for from creation on, so a signal that arrives while
/// the node's loop is busy elsewhere is not lost (a fresh
/// `tokio::signal::ctrl_c()` per loop turn would miss it).
pub struct Shutdown {
    signals: Vec<tokio::signal::unix::Signal>,
}

impl Default for Shutdown {
    fn default() -> Self {
        Self::new()
    }
}

impl Shutdown {
    /// Listens for SIGINT and SIGTERM from now on.
    pub fn new() -> Self {
        use tokio::signal::unix::{signal, SignalKind};
        let mut signals = Vec::new();
        for kind in [SignalKind::interrupt(), SignalKind::terminate()] {
            match signal(kind) {
                Ok(s) => signals.push(s),
                Err(e) => tracing::warn!("cannot listen for signal {kind:?}: {e}"),
            }
        }
        Self { signals }
    }

    /// Returns when a stop was asked for.
    pub async fn requested(&mut self) {
        if self.signals.is_empty() {
            return std::future::pending().await;
        }
        let waits = self.signals.iter_mut().map(|s| Box::pin(s.recv()));
        futures::future::select_all(waits).await;
    }
}
