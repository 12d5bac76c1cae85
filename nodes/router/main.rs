//! `falc-router`: the cell's network. Runs a zenoh router that authenticates
//! every node (usrpwd against a generated dictionary) and enforces the
//! access control generated from `launch/cell.toml` (default deny; the
//! hierarchy of docs/architecture.md). Creates missing per-node credential files
//! (mode 0600) and the cell's certificates (a CA, a certificate per node and
//! console user, the router's own), in a directory only its owner may
//! enter (0700); `bundle` copies what one PC needs. On a `quic/…` endpoint
//! every link is QUIC with mutual TLS. Refused logins are logged at WARN,
//! rate-limited (`logins`); `firewall` prints the nftables rules that keep
//! strangers off the router's port (`firewall`). A session in router or
//! peer mode is refused or closed as it opens (`modes`). With `--trace-acl` it logs ACL denials, which
//! zenoh itself only traces (see `denials` for what that count can and
//! cannot tell).

mod denials;
mod firewall;
mod logins;
mod modes;
mod plant;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use falc_bus::{acl, certificates, config, credentials};
use falc_model::ids::CellId;
use falc_model::plant::Plant;
use falc_model::topology::Topology;
use std::path::{Path, PathBuf};

#[derive(Parser, Debug)]
#[command(
    version,
    about = "FALC zenoh router with authentication and the hierarchy ACL"
)]
struct Cli {
    /// The cell topology file.
    #[arg(long, default_value = "launch/cell.toml", global = true)]
    topology: PathBuf,
    /// Directory of credential files (created if missing).
    #[arg(long, default_value = "launch/credentials", global = true)]
    credentials_dir: PathBuf,
    /// A plant topology (`launch/factory.toml`) instead of one cell's:
    /// `run` is then the factory router, `run --cell ID` that cell's router.
    #[arg(long, global = true)]
    plant: Option<PathBuf>,
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run the router (the default).
    Run {
        /// Endpoint to listen on; default the topology's `router`.
        #[arg(long)]
        listen: Option<String>,
        /// Log each distinct ACL denial once (a diagnostic; see the docs).
        #[arg(long)]
        trace_acl: bool,
        /// With `--plant`: run this cell's router (default: the factory router).
        #[arg(long)]
        cell: Option<CellId>,
    },
    /// Create missing credential files and certificates (the cell CA, one
    /// per node and console user, the router's) and list them.
    Credentials,
    /// Copy what one PC needs into a new directory: the user's credentials,
    /// certificate and key, the cell CA's certificate (never its key) and
    /// the topology. With `--plant`: a factory user's (the operator, a
    /// console, a cell router `router-<cell>` with its cell's files), or
    /// with `--cell` a station's of that cell.
    Bundle {
        /// The station or console user the PC runs as.
        user: String,
        /// With `--plant`: the cell of the station.
        #[arg(long)]
        cell: Option<CellId>,
        /// The directory to create (it must not exist yet).
        #[arg(long)]
        out: PathBuf,
    },
    /// Print the nftables rules that admit only the cell's hosts (the
    /// `host` of each station and console) to the router's port, each
    /// rate-limited; apply with `falc-router firewall | nft -f -`. With
    /// `--plant`: the factory router's (the operator's, the consoles' and
    /// each cell router's hosts), or with `--cell` that cell router's.
    Firewall {
        /// The endpoint the router listens on; default the topology's `router`.
        #[arg(long)]
        listen: Option<String>,
        /// With `--plant`: the rules of this cell's router.
        #[arg(long)]
        cell: Option<CellId>,
    },
    /// Print the generated access control (zenoh JSON).
    Acl {
        /// Print the hierarchy matrix (Markdown) instead.
        #[arg(long)]
        matrix: bool,
    },
}

/// Creates what is missing in the credentials directory (made private,
/// 0700): each user's usrpwd file, the cell CA, each user's certificate,
/// and the router's certificate for the topology's router host.
fn ensure_credentials(topology: &Topology, dir: &Path) -> Result<Vec<credentials::Credentials>> {
    private_dir(dir)?;
    let authority = certificates::Authority::ensure(dir, topology.cell().as_str())?;
    let host = certificates::endpoint_host(topology.router())
        .with_context(|| format!("router endpoint `{}` names no host", topology.router()))?;
    authority.issue_router(&[host])?;
    topology
        .users()
        .map(|u| {
            authority.ensure_client(u.as_str())?;
            credentials::ensure(dir, u.as_str()).map_err(Into::into)
        })
        .collect()
}

/// Creates `dir` if missing and makes it private (0700).
fn private_dir(dir: &Path) -> Result<()> {
    credentials::private_dir(dir)
        .with_context(|| format!("cannot make {} private (chmod 700)", dir.display()))
}

/// `falc-router bundle USER --out DIR`: DIR laid out as the PC's
/// `/etc/falc`, `cell.toml` and `credentials/` (a station may be called
/// `cell`, whose password file is `cell.toml` too).
fn bundle(
    topology: &Topology,
    cli_topology: &Path,
    dir: &Path,
    user: &str,
    out: &Path,
) -> Result<()> {
    if !topology.users().any(|u| u.as_str() == user) {
        anyhow::bail!(
            "`{user}` is neither a station nor a console of {}",
            cli_topology.display()
        );
    }
    if out.exists() {
        anyhow::bail!("{} exists already; give a new directory", out.display());
    }
    ensure_credentials(topology, dir)?;
    let to = out.join("credentials");
    let files = certificates::TlsFiles::of(dir, user);
    let password = dir.join(format!("{user}.toml"));
    let copies = vec![
        (password, true),
        (files.key, true),
        (files.cert, false),
        (files.ca, false),
    ];
    let mut copies: Vec<BundleFile> = copies
        .into_iter()
        .map(|(from, private)| BundleFile::into_dir(from, &to, private))
        .collect();
    copies.push(BundleFile {
        from: cli_topology.to_path_buf(),
        to: out.join("cell.toml"),
        private: false,
    });
    write_bundle(&copies)
}

/// One file of a bundle.
pub struct BundleFile {
    /// Where it is.
    pub from: PathBuf,
    /// Where it goes.
    pub to: PathBuf,
    /// Whether it is private (0600) or public (0644).
    pub private: bool,
}

impl BundleFile {
    /// `from` into directory `dir`, under its own name.
    pub fn into_dir(from: PathBuf, dir: &Path, private: bool) -> Self {
        let to = dir.join(from.file_name().unwrap_or_default());
        Self { from, to, private }
    }
}

/// Writes a bundle's files (their directories made private, 0700), each
/// named as it is written.
fn write_bundle(copies: &[BundleFile]) -> Result<()> {
    for c in copies {
        if let Some(parent) = c.to.parent() {
            if c.private || !parent.exists() {
                private_dir(parent)?;
            }
        }
        let text = std::fs::read_to_string(&c.from)
            .with_context(|| format!("cannot read {}", c.from.display()))?;
        if c.private {
            credentials::write_private(&c.to, &text)?;
        } else {
            credentials::write_public(&c.to, &text)?;
        }
        println!("{}", c.to.display());
    }
    Ok(())
}

/// zenoh's runtimes as the router runs them (the `ZENOH_RUNTIME`
/// environment variable, read once by zenoh at its first use; one set by
/// the user is kept). zenoh 1.10 runs every link's login on one thread
/// of its own (`acc`), and closes each link whose login timed out there;
/// its TCP links have SO_LINGER set (10 s), so each close(2) blocks until
/// the peer acknowledges the close (seen with `perf`: `acc-0` waiting in
/// `sk_stream_wait_close`). Under a thousand silent TCP connections,
/// dropped after the 3 s login limit and opened again at once, one
/// console login in three waited 3.1–3.7 s for that thread. Four threads:
/// every login within 205 ms (`cargo bench --bench flood -- --only tcp`).
const ZENOH_RUNTIME: &str = "(acc: (worker_threads: 4))";

fn main() -> Result<()> {
    // Before any thread exists, so nothing reads the environment meanwhile.
    if std::env::var_os("ZENOH_RUNTIME").is_none() {
        std::env::set_var("ZENOH_RUNTIME", ZENOH_RUNTIME);
    }
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the router's runtime")?
        .block_on(main_async())
}

async fn main_async() -> Result<()> {
    let cli = Cli::parse();
    let command = cli.command.unwrap_or(Command::Run {
        listen: None,
        trace_acl: false,
        cell: None,
    });
    if let Some(path) = &cli.plant {
        return plant_main(&Plant::load(path)?, path, &cli.credentials_dir, command).await;
    }
    if let Command::Run { cell: Some(id), .. } = &command {
        anyhow::bail!("`run --cell {id}` runs a cell router of a plant: give the plant (--plant)");
    }
    let topology = Topology::load(&cli.topology)?;
    match command {
        Command::Acl { matrix: true } => {
            print!("{}", acl::matrix(&topology));
            Ok(())
        }
        Command::Acl { matrix: false } => {
            println!(
                "{}",
                serde_json::to_string_pretty(&acl::access_control(&topology))?
            );
            Ok(())
        }
        Command::Credentials => {
            for c in ensure_credentials(&topology, &cli.credentials_dir)? {
                println!(
                    "{}",
                    cli.credentials_dir
                        .join(format!("{}.toml", c.user))
                        .display()
                );
            }
            Ok(())
        }
        Command::Firewall { listen, cell } => {
            if let Some(id) = cell {
                anyhow::bail!("`firewall --cell {id}` is for a cell router of a plant: give the plant (--plant)");
            }
            let listen = listen.unwrap_or_else(|| topology.router().to_string());
            print!("{}", firewall::rules(&topology, &listen)?);
            Ok(())
        }
        Command::Bundle { user, out, cell } => {
            if let Some(id) = cell {
                anyhow::bail!(
                    "`bundle --cell {id}` is for a station of a plant: give the plant (--plant)"
                );
            }
            bundle(&topology, &cli.topology, &cli.credentials_dir, &user, &out)
        }
        Command::Run {
            listen, trace_acl, ..
        } => run(&topology, &cli.credentials_dir, listen, trace_acl).await,
    }
}

/// `falc-router --plant FILE …`: the routers of a plant ([`plant`]).
async fn plant_main(plant: &Plant, path: &Path, dir: &Path, command: Command) -> Result<()> {
    match command {
        Command::Run {
            listen,
            trace_acl,
            cell,
        } => {
            let router = match &cell {
                Some(id) => plant::cell(plant, id, dir, listen)?,
                None => plant::factory(plant, dir, listen)?,
            };
            let what = match &cell {
                Some(id) => format!("cell {id}'s router, linked to the factory router"),
                None => format!("plant {}'s factory router", plant.name()),
            };
            serve(
                router.config,
                router.admit,
                &router.listen,
                trace_acl,
                &what,
            )
            .await
        }
        Command::Credentials => {
            for f in plant::ensure_credentials(plant, dir)? {
                println!("{}", f.display());
            }
            Ok(())
        }
        Command::Acl { matrix: false } => {
            let mut all = serde_json::Map::new();
            all.insert("factory".into(), acl::factory_access_control(plant));
            for c in plant.cells() {
                all.insert(
                    c.id().to_string(),
                    acl::cell_router_access_control(plant, c),
                );
            }
            println!("{}", serde_json::to_string_pretty(&all)?);
            Ok(())
        }
        Command::Acl { matrix: true } => {
            for c in plant.cells() {
                println!("cell {}:\n", c.id());
                print!("{}", acl::matrix(c.topology()));
                println!();
            }
            Ok(())
        }
        Command::Firewall { listen, cell } => {
            let cell = match &cell {
                Some(id) => Some(
                    plant
                        .cell(id)
                        .with_context(|| format!("the plant has no cell `{id}`"))?,
                ),
                None => None,
            };
            let listen = listen.unwrap_or_else(|| {
                cell.map_or(plant.router(), |c| c.topology().router())
                    .to_string()
            });
            print!("{}", firewall::plant_rules(plant, cell, &listen)?);
            Ok(())
        }
        Command::Bundle { user, out, cell } => {
            if out.exists() {
                anyhow::bail!("{} exists already; give a new directory", out.display());
            }
            write_bundle(&plant::bundle(
                plant,
                path,
                dir,
                &user,
                cell.as_ref(),
                &out,
            )?)
        }
    }
}

async fn run(
    topology: &Topology,
    dir: &Path,
    listen: Option<String>,
    trace_acl: bool,
) -> Result<()> {
    let creds = ensure_credentials(topology, dir)?;
    let dict = dir.join("router.dict");
    credentials::write_private(&dict, &credentials::dictionary(&creds))?;
    let listen = listen.unwrap_or_else(|| topology.router().to_string());
    let tls = certificates::is_secure(topology.router())
        .then(|| certificates::TlsFiles::of(dir, certificates::ROUTER));
    if certificates::is_secure(&listen) != tls.is_some() {
        anyhow::bail!(
            "listen endpoint `{listen}` and the topology's router `{}` must both be quic/ or both not",
            topology.router()
        );
    }
    let cfg = config::router(
        &listen,
        topology.lease(),
        &dict,
        tls.as_ref(),
        acl::access_control(topology),
        config::Place::Cell,
    )?;
    let what = format!(
        "cell {}'s router, {} stations, secure transport {}",
        topology.cell(),
        topology.stations().len(),
        if tls.is_some() { "on" } else { "off" }
    );
    serve(cfg, modes::Admit::default(), &listen, trace_acl, &what).await
}

/// Runs a router on `cfg` until asked to stop; `what` says which in its log.
async fn serve(
    cfg: zenoh::Config,
    admit: modes::Admit,
    listen: &str,
    trace_acl: bool,
    what: &str,
) -> Result<()> {
    let (denials, refusals) = init_tracing(trace_acl);
    raise_open_files();
    let session = modes::open(cfg, admit)
        .await
        .map_err(|e| anyhow::anyhow!("cannot start the router on {listen}: {e}"))?;
    tracing::info!(
        %listen,
        "router up ({what}): usrpwd authentication on, access control default deny"
    );
    // The one line on stdout: tests and the launcher wait for it.
    println!("falc-router ready on {listen}");
    let reporter = denials.map(|d| tokio::spawn(denials::report(d)));
    let logins = tokio::spawn(logins::report(refusals));
    falc_node::Shutdown::new().requested().await;
    tracing::info!("router stopping");
    if let Some(r) = reporter {
        r.abort();
    }
    logins.abort();
    session
        .close()
        .await
        .map_err(|e| anyhow::anyhow!("closing the router: {e}"))?;
    Ok(())
}

/// Installs logging: the normal log ([`falc_node::log_layer`]),
/// the refused-login reports ([`logins`]) and, with `trace_acl`, the denial
/// counter on zenoh's ACL target ([`denials`]).
fn init_tracing(trace_acl: bool) -> (Option<denials::Denials>, logins::Refusals) {
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    let (refused, refusals) = logins::layer();
    let (denied, denials) = denials::layer(trace_acl);
    let _ = tracing_subscriber::Registry::default()
        .with(falc_node::log_layer())
        .with(refused)
        .with(denied)
        .try_init();
    (denials, refusals)
}

/// Raises the soft limit of open files to the hard limit: every connection
/// in its handshake holds a file, and strangers may open hundreds.
fn raise_open_files() {
    use nix::sys::resource::{getrlimit, setrlimit, Resource};
    match getrlimit(Resource::RLIMIT_NOFILE) {
        Ok((soft, hard)) if soft < hard => {
            if let Err(e) = setrlimit(Resource::RLIMIT_NOFILE, hard, hard) {
                tracing::warn!("cannot raise the open-file limit from {soft} to {hard}: {e}");
            }
        }
        Ok(_) => {}
        Err(e) => tracing::warn!("cannot read the open-file limit: {e}"),
    }
}
