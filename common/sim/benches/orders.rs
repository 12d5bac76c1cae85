//! The nightly-style run (not in CI): 100,000 orders of the whole cell on
//! the virtual clock with every kind of fault, the invariants checked after
//! every step; prints orders per second of simulated production and how
//! much faster than real time it ran. Figures only: nothing is asserted
//! about time. `cargo bench -p falc-sim --bench orders`
//! (`FALC_SIM_ORDERS=N` for another count).

use falc_sim::{Config, Run};
use std::process::ExitCode;
use std::time::Instant;

fn main() -> ExitCode {
    let orders = std::env::var("FALC_SIM_ORDERS")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or(100_000);
    let cfg = Config {
        seed: 1,
        orders,
        ..Config::default()
    };
    let started = Instant::now();
    let summary = match Run::new(cfg)
        .map_err(|e| e.to_string())
        .and_then(|r| r.run().map_err(|v| v.to_string()))
    {
        Ok(s) => s,
        Err(e) => {
            println!("falc-sim bench: {e}");
            return ExitCode::FAILURE;
        }
    };
    let wall = started.elapsed().as_secs_f64().max(1e-9);
    let ended = (summary.done + summary.failed) as f64;
    println!("{summary}");
    println!(
        "{orders} orders in {wall:.1} s of wall time: {:.0} orders per second, {:.0} steps per second, {:.0}× real time ({:.1} simulated hours)",
        ended / wall,
        summary.steps as f64 / wall,
        summary.simulated.as_secs_f64() / wall,
        summary.simulated.as_secs_f64() / 3600.0
    );
    ExitCode::SUCCESS
}
