//! `falc-sim [--topology FILE] --seed S --orders N [--faults …]`: one
//! seeded run of the whole cell, or of a plant of cells, on a virtual
//! clock; prints a summary, or the broken invariant with the events that
//! led there (exit status 1). The same seed replays it.

use clap::Parser;
use falc_sim::{Config, Fault, Run};
use std::io::Write;
use std::process::ExitCode;
use std::time::Instant;

#[derive(Parser, Debug)]
#[command(version, about = "FALC's whole cell in one process on a virtual clock")]
struct Cli {
    /// A topology file, a cell's or a plant's (`launch/factory.toml`);
    /// without it, the shipped cell (`launch/cell.toml`).
    #[arg(long)]
    topology: Option<std::path::PathBuf>,
    /// A recipe tree with a directory per station (`cell/`, `welding/`,
    /// `welding2/` …), for a topology of other stations; without it, the
    /// shipped recipes.
    #[arg(long)]
    recipes: Option<std::path::PathBuf>,
    /// The cell recipes ordered, in turn, comma-separated.
    #[arg(long, default_value = "dikdroog,dundroog,pipdroog")]
    order_recipes: String,
    /// Drives every random choice; the same seed gives the same run.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Orders to work through.
    #[arg(long, default_value_t = 100)]
    orders: usize,
    /// The faults to inject, comma-separated (crash, estop, limit-switch,
    /// unplug, noise, jam, stuck, partition, disk-full, memory, uplink),
    /// `all` or `none`. A cell of its own has no uplink: it skips it.
    #[arg(long, default_value = "all")]
    faults: String,
    /// Chance that an order meets a fault (0 to 1).
    #[arg(long, default_value_t = 0.8)]
    fault_rate: f64,
    /// The twins' time scale.
    #[arg(long, default_value_t = 20.0)]
    time_scale: f64,
    /// Print the journal at the end.
    #[arg(long)]
    journal: bool,
}

fn faults(s: &str) -> Result<Vec<Fault>, String> {
    match s {
        "all" => Ok(Fault::ALL.to_vec()),
        "none" | "" => Ok(Vec::new()),
        list => list
            .split(',')
            .map(|f| Fault::parse(f.trim()).ok_or_else(|| format!("unknown fault `{f}`")))
            .collect(),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let faults = match faults(&cli.faults) {
        Ok(f) => f,
        Err(e) => {
            eprintln!("falc-sim: {e}");
            return ExitCode::from(2);
        }
    };
    let cfg = Config {
        topology: cli.topology.clone(),
        recipe_dir: cli.recipes.clone(),
        recipes: cli
            .order_recipes
            .split(',')
            .map(|r| r.trim().to_string())
            .filter(|r| !r.is_empty())
            .collect(),
        seed: cli.seed,
        orders: cli.orders,
        faults,
        fault_rate: cli.fault_rate,
        time_scale: cli.time_scale,
        keep_journal: cli.journal,
        ..Config::default()
    };
    let started = Instant::now();
    let run = match Run::new(cfg) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("falc-sim: {e}");
            return ExitCode::from(2);
        }
    };
    // Written with errors taken (a closed pipe ends the output, not the
    // program with a panic).
    let mut out = std::io::stdout().lock();
    let written = match run.run() {
        Ok(s) => {
            let wall = started.elapsed().as_secs_f64();
            let lines = s.lines.iter().try_for_each(|l| writeln!(out, "{l}"));
            lines
                .and_then(|()| writeln!(out, "seed {}: {s}", cli.seed))
                .and_then(|()| {
                    writeln!(
                        out,
                        "{:.1} s of wall time: {:.0} orders per second, {:.0}× real time",
                        wall,
                        (s.done + s.failed) as f64 / wall.max(1e-9),
                        s.simulated.as_secs_f64() / wall.max(1e-9)
                    )
                })
                .map(|()| ExitCode::SUCCESS)
        }
        Err(v) => writeln!(out, "seed {}: {v}", cli.seed)
            .and_then(|()| {
                let mut topology = cli
                    .topology
                    .as_ref()
                    .map_or(String::new(), |t| format!("--topology {} ", t.display()));
                if let Some(r) = &cli.recipes {
                    topology += &format!(
                        "--recipes {} --order-recipes {} ",
                        r.display(),
                        cli.order_recipes
                    );
                }
                writeln!(
                    out,
                    "replay: cargo run -p falc-sim -- {topology}--seed {} --orders {} --faults {}",
                    cli.seed, cli.orders, cli.faults
                )
            })
            .map(|()| ExitCode::FAILURE),
    };
    written.unwrap_or(ExitCode::FAILURE)
}
