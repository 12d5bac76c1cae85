//! `falc-operator`: the factory controller at the root of the cell. At start
//! it checks every recipe of the recipe directory (the PPS, `recipe_store`) and
//! refuses to start with every problem as `file:line: reason`; it opens the
//! order list and journal (`database`, SQLite WAL), marks an order a crash
//! interrupted, associates the cell (retrying every second while it cannot)
//! and delivers the recipes; then it serves the operator API to consoles
//! and operator communication (`input`, `output`) to the cell
//! (`operator`). A thin driver: this file is start-up and the event loop.

mod alarms;
mod database;
mod operator;
mod recipe_store;

use anyhow::{Context, Result};
use clap::Parser;
use falc_bus::station::{Station, StationEvent};
use falc_model::ids::StationName;
use falc_node::{init_tracing, say, NodeArgs};
use operator::Operator;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

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
    #[command(flatten)]
    node: NodeArgs,
}

/// How often to try the cell again while it is not associated.
const RETRY: Duration = Duration::from_secs(1);

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
    let recipes = match recipe_store::load(&cli.recipes, &topology, &cell) {
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
    let mut db = database::Database::open(&cli.db)?;
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
    let (api_tx, mut api) = tokio::sync::mpsc::unbounded_channel();
    let _api = bus.serve_api(api_tx).await?;
    let (utx, mut publications) = tokio::sync::mpsc::unbounded_channel();
    let (ptx, mut presence) = tokio::sync::mpsc::unbounded_channel();
    let mut subscriptions = Vec::new();
    for st in topology.stations().iter().filter(|s| &s.name != me) {
        subscriptions.extend(bus.subscribe(&st.name, utx.clone()).await?);
        subscriptions.push(bus.presence(&st.name, ptx.clone()).await?);
    }
    bus.sync_with_router().await?;
    let mut op = Operator::new(station, db, topology, cell, cli.recipes.clone(), recipes);
    let who = me.to_string();
    op.journal(
        falc_model::console::EntryKind::System,
        None,
        &who,
        "operator node started",
    );
    say(&format!("EVENT ready station={me} db={}", cli.db.display()));
    let _ = op.connect().await;
    let mut retry = tokio::time::interval(RETRY);
    retry.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut shutdown = falc_node::Shutdown::new();
    loop {
        tokio::select! {
            ev = op.station.recv() => {
                let Some(ev) = ev else { anyhow::bail!("the cell network session ended") };
                match op.station.handle(ev).await {
                    Some(StationEvent::Indication(ind)) => op.upward(ind.request, ind.responder).await,
                    Some(StationEvent::Abort(a)) => op.cell_lost(&a.reason),
                    Some(StationEvent::Associated(_) | StationEvent::Concluded(_)) | None => {}
                }
            }
            Some(ind) = api.recv() => {
                let result = op.api(&ind.user, ind.request).await;
                ind.responder.respond(result).await;
            }
            Some(u) = publications.recv() => op.publication(u).await,
            Some(p) = presence.recv() => op.presence(p),
            _ = retry.tick() => { let _ = op.connect().await; }
            _ = shutdown.requested() => break,
        }
        // A failed write halts the running order before anything else.
        op.enforce().await;
        if op.should_stop() {
            break;
        }
    }
    op.journal(
        falc_model::console::EntryKind::System,
        None,
        &who,
        "operator node stopped",
    );
    op.station.conclude_subordinates().await;
    drop(subscriptions);
    say("EVENT stopped");
    Ok(ExitCode::SUCCESS)
}
