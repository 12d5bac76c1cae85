//! Plant scale benchmark: 1, 4 and 16 cells, each a cell router and three
//! demo stations (cell, welding, transport: no device, so a started order
//! runs until it is stopped), under one factory router and one
//! `falc-operator` (debug build unless run with `--profile release`).
//!
//! Prints, per plant size:
//! - start-up: from the operator's spawn to every cell associated and its
//!   recipes delivered;
//! - dispatch latency, p50 and tail: an order added for a cell → that
//!   cell's `start` confirmed by the cell controller, the order running
//!   (rounds: each cell's order stopped, a new one added and started);
//! - CPU (% of one core) and RSS of the factory router, the busiest cell
//!   router and the operator, idle (5 s) and busy (the dispatch rounds);
//! - how each figure grows against one cell.
//!
//! Run: `cargo bench --bench plant [-- 1 4 16]`. Prints figures; asserts
//! nothing about time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

use falc_bus::Bus;
use falc_model::console::{ApiReply, ApiRequest, Placement};
use falc_model::ids::{CellId, StationName};
use std::time::{Duration, Instant};
use support::plant::TestPlant;
use support::stats::{cpu_ticks, median, rss_mib, tail};
use support::Proc;

/// Dispatch rounds per plant size: every cell gets one order a round.
const ROUNDS: usize = 5;

/// Clock ticks per second (`getconf CLK_TCK`, 100 on Linux).
const TICKS: f64 = 100.0;

struct Load {
    cpu_pct: f64,
    rss: f64,
}

/// CPU of `pid` over `during` (% of one core) and its RSS at the end.
fn load_over(pids: &[u32], during: impl FnOnce()) -> Vec<Load> {
    let before: Vec<u64> = pids.iter().map(|&p| cpu_ticks(p)).collect();
    let t = Instant::now();
    during();
    let secs = t.elapsed().as_secs_f64();
    pids.iter()
        .zip(before)
        .map(|(&p, b)| Load {
            cpu_pct: (cpu_ticks(p).saturating_sub(b)) as f64 / TICKS / secs * 100.0,
            rss: rss_mib(p),
        })
        .collect()
}

struct Figures {
    cells: usize,
    startup_ms: f64,
    dispatch_p50: f64,
    dispatch_tail: (&'static str, f64),
    idle: Vec<Load>,
    busy: Vec<Load>,
}

fn run(cells: usize) -> Figures {
    let plant = TestPlant::start_cells(cells);
    let mut stations: Vec<Proc> = Vec::new();
    for c in plant.plant.cells() {
        for st in ["welding", "transport", "cell"] {
            stations.push(plant.demo_station(c.id().as_str(), st));
        }
    }
    let spawned = Instant::now();
    let mut operator = plant.spawn_operator();
    operator.expect_line("EVENT ready", Duration::from_secs(60));
    for _ in 0..cells {
        operator.take_line("EVENT delivered recipe=PIPDROOG", Duration::from_secs(120));
    }
    let startup_ms = spawned.elapsed().as_secs_f64() * 1000.0;

    // The routers: the factory router is the last; the cell routers before.
    let factory = plant.routers.last().map(Proc::pid).expect("factory router");
    let cell_routers: Vec<u32> = plant.routers[..plant.routers.len() - 1]
        .iter()
        .map(Proc::pid)
        .collect();
    let mut watched = vec![factory, operator.pid()];
    watched.extend(&cell_routers);
    let idle = load_over(&watched, || std::thread::sleep(Duration::from_secs(5)));

    let rt = tokio::runtime::Runtime::new().expect("runtime");
    let mut samples = Vec::new();
    let busy = load_over(&watched, || {
        rt.block_on(async {
            let settings = plant.settings("console", "console.toml", plant.plant.router(), "plant");
            let console = Bus::open(settings).await.expect("console");
            let operator = StationName::new("operator").expect("name");
            let ids: Vec<CellId> = plant.plant.cells().iter().map(|c| c.id().clone()).collect();
            for round in 0..ROUNDS {
                for id in &ids {
                    let to_cell = console.clone().for_cell(Some(id.clone()));
                    if round > 0 {
                        to_cell
                            .api(&operator, ApiRequest::Stop, Duration::from_secs(20))
                            .await
                            .expect("stop");
                    }
                    let t = Instant::now();
                    let add = ApiRequest::OrderAdd {
                        recipe: "dikdroog".into(),
                        placement: Placement {
                            cell: Some(id.clone()),
                            ..Placement::default()
                        },
                        count: 1,
                    };
                    console
                        .api(&operator, add, Duration::from_secs(20))
                        .await
                        .expect("order add");
                    match to_cell
                        .api(&operator, ApiRequest::Start, Duration::from_secs(20))
                        .await
                    {
                        Ok(ApiReply::Done(text)) if text.contains("started") => {
                            samples.push(t.elapsed().as_secs_f64() * 1000.0)
                        }
                        other => panic!("{id}: start answered {other:?}"),
                    }
                }
            }
        })
    });
    Figures {
        cells,
        startup_ms,
        dispatch_p50: median(&samples),
        dispatch_tail: tail(&samples),
        idle,
        busy,
    }
}

fn show(load: &[Load]) -> String {
    let cell_routers = &load[2..];
    let busiest = cell_routers
        .iter()
        .max_by(|a, b| a.cpu_pct.total_cmp(&b.cpu_pct))
        .expect("a cell router");
    format!(
        "factory router {:.1} % {:.0} MiB, busiest cell router {:.1} % {:.0} MiB, operator {:.1} % {:.0} MiB",
        load[0].cpu_pct, load[0].rss, busiest.cpu_pct, busiest.rss, load[1].cpu_pct, load[1].rss
    )
}

fn main() {
    let sizes: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let sizes = if sizes.is_empty() {
        vec![1, 4, 16]
    } else {
        sizes
    };
    let mut all = Vec::new();
    for n in sizes {
        let f = run(n);
        println!("{n} cell(s), {} processes:", 2 + n * 4);
        println!(
            "  start-up, operator spawned → every cell associated and delivered: {:.0} ms",
            f.startup_ms
        );
        println!(
            "  dispatch, order added → its cell running: p50 {:.1} ms, {} {:.1} ms (n={})",
            f.dispatch_p50,
            f.dispatch_tail.0,
            f.dispatch_tail.1,
            n * ROUNDS
        );
        println!("  idle: {}", show(&f.idle));
        println!("  busy: {}", show(&f.busy));
        all.push(f);
    }
    if let Some(base) = all.first() {
        println!("growth against {} cell(s):", base.cells);
        for f in &all {
            let r = |a: f64, b: f64| if b > 0.0 { a / b } else { f64::NAN };
            println!(
                "  {:>2} cells: start-up ×{:.1}, dispatch p50 ×{:.2}, operator RSS ×{:.2}, factory router RSS ×{:.2}, operator busy CPU ×{:.1}",
                f.cells,
                r(f.startup_ms, base.startup_ms),
                r(f.dispatch_p50, base.dispatch_p50),
                r(f.busy[1].rss, base.busy[1].rss),
                r(f.busy[0].rss, base.busy[0].rss),
                r(f.busy[1].cpu_pct, base.busy[1].cpu_pct),
            );
        }
    }
}
