//! `falc-router`: the cell's network. Runs a zenoh router that authenticates
//! every node (usrpwd against a generated dictionary) and enforces the
//! access control generated from `launch/cell.toml` (default deny; the
//! hierarchy of DESIGN.md §4). Creates missing per-node credential files
//! (mode 0600). With `--trace-acl` it logs ACL denials, which zenoh itself
//! only traces (see `denials` for what that count can and cannot tell).

mod denials;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use falc_bus::{acl, config, credentials};
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
    },
    /// Create missing credential files and list them.
    Credentials,
    /// Print the generated access control (zenoh JSON).
    Acl {
        /// Print the hierarchy matrix (Markdown) instead.
        #[arg(long)]
        matrix: bool,
    },
}

fn ensure_credentials(topology: &Topology, dir: &Path) -> Result<Vec<credentials::Credentials>> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    topology
        .users()
        .map(|u| credentials::ensure(dir, u.as_str()).map_err(Into::into))
        .collect()
}

#[tokio::main]
async fn main() -> Result<()> {
    let cli = Cli::parse();
    let topology = Topology::load(&cli.topology)?;
    match cli.command.unwrap_or(Command::Run {
        listen: None,
        trace_acl: false,
    }) {
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
        Command::Run { listen, trace_acl } => {
            run(&topology, &cli.credentials_dir, listen, trace_acl).await
        }
    }
}

async fn run(
    topology: &Topology,
    dir: &Path,
    listen: Option<String>,
    trace_acl: bool,
) -> Result<()> {
    let denials = denials::init_tracing(trace_acl);
    let creds = ensure_credentials(topology, dir)?;
    let dict = dir.join("router.dict");
    credentials::write_private(&dict, &credentials::dictionary(&creds))?;
    let listen = listen.unwrap_or_else(|| topology.router().to_string());
    let cfg = config::router(
        &listen,
        topology.lease(),
        &dict,
        acl::access_control(topology),
    )?;
    let session = zenoh::open(cfg)
        .await
        .map_err(|e| anyhow::anyhow!("cannot start the router on {listen}: {e}"))?;
    tracing::info!(
        %listen,
        stations = topology.stations().len(),
        "router up: usrpwd authentication on, access control default deny"
    );
    // The one line on stdout: tests and the launcher wait for it.
    println!("falc-router ready on {listen}");
    let reporter = denials.map(|d| tokio::spawn(denials::report(d)));
    falc_node::Shutdown::new().requested().await;
    tracing::info!("router stopping");
    if let Some(r) = reporter {
        r.abort();
    }
    session
        .close()
        .await
        .map_err(|e| anyhow::anyhow!("closing the router: {e}"))?;
    Ok(())
}
