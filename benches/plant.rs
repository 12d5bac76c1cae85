//! Plant scale benchmark: 1, 4 and 16 cells, each a cell router and three
//! demo stations (cell, welding, transport: no device; the cell's order
//! ends by itself after 200 ms), under one factory router and one
//! `falc-operator` (debug build unless run with `--profile release`).
//!
//! Prints, per plant size:
//! - start-up: from the operator's spawn to every cell associated and its
//!   recipes delivered;
//! - dispatch latency, p50 and tail: an order added for a cell → that
//!   cell's `start` confirmed by the cell controller, the order running
//!   (rounds: each demo cell's order ends by itself after 200 ms);
//! - the hand-over in a running list: a batch for every cell worked from
//!   the one list, one order's end → the same cell's next order running
//!   at the cell. The records mark the next order running in the same
//!   step as they end the last (0 ms on their clock), so the figure is
//!   what the cell's jobs show: the time between two ends of one cell
//!   less the job's own 200 ms (the operator's work, the Start through
//!   both routers to the cell, the job's end back);
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
use falc_model::api::{ApiReply, ApiRequest, Placement};
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
    handover_p50: f64,
    handover_tail: (&'static str, f64),
    handovers: usize,
    idle: Vec<Load>,
    busy: Vec<Load>,
}

/// How long a demo cell's order runs before it ends by itself, in ms.
const JOB_MS: i64 = 200;

/// Orders per cell in the queued batch.
const BATCH: usize = 4;

fn run(cells: usize) -> Figures {
    let plant = TestPlant::start_cells(cells);
    let mut stations: Vec<Proc> = Vec::new();
    for c in plant.plant.cells() {
        let id = c.id().as_str();
        stations.push(plant.demo_station(id, "welding"));
        stations.push(plant.demo_station(id, "transport"));
        stations.push(plant.demo_station_with(id, "cell", &["--job-ms", &JOB_MS.to_string()]));
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
    let mut handovers = Vec::new();
    let busy = load_over(&watched, || {
        rt.block_on(async {
            let settings = plant.settings("console", "console.toml", plant.plant.router(), "plant");
            let console = Bus::open(settings).await.expect("console");
            let operator = StationName::new("operator").expect("name");
            let api = |bus: Bus, r: ApiRequest| {
                let operator = operator.clone();
                async move { bus.api(&operator, r, Duration::from_secs(30)).await }
            };
            let ids: Vec<CellId> = plant.plant.cells().iter().map(|c| c.id().clone()).collect();
            // Order added for a cell → that cell's start confirmed.
            for _ in 0..ROUNDS {
                for id in &ids {
                    let to_cell = console.clone().for_cell(Some(id.clone()));
                    let add = ApiRequest::OrderAdd {
                        recipe: "dikdroog".into(),
                        placement: Placement {
                            cell: Some(id.clone()),
                            ..Placement::default()
                        },
                        count: 1,
                    };
                    let t = Instant::now();
                    api(console.clone(), add).await.expect("order add");
                    match api(to_cell, ApiRequest::Start).await {
                        Ok(ApiReply::Done(text)) if text.contains("started") => {
                            samples.push(t.elapsed().as_secs_f64() * 1000.0)
                        }
                        other => panic!("{id}: start answered {other:?}"),
                    }
                }
                // Every cell's order ends by itself.
                until_idle(&console, &operator).await;
            }
            // A batch for every cell at once, worked from the one list:
            // one order's end → the same cell's next order running. Only
            // the batch's orders count: between the dispatch rounds above
            // the bench itself waits (for every cell idle, then adds and
            // starts the cells one after the other), which is no
            // hand-over and grew with the cells.
            let Ok(ApiReply::Orders(before)) = api(console.clone(), ApiRequest::OrderList).await
            else {
                panic!("no order list")
            };
            let batch_from = before.iter().map(|o| o.id).max().unwrap_or(0);
            let add = ApiRequest::OrderAdd {
                recipe: "dikdroog".into(),
                placement: Placement::default(),
                count: u16::try_from(BATCH * ids.len()).unwrap_or(100).min(100),
            };
            api(console.clone(), add).await.expect("batch");
            api(console.clone(), ApiRequest::Start)
                .await
                .expect("start");
            until_idle(&console, &operator).await;
            let Ok(ApiReply::Orders(orders)) = api(console.clone(), ApiRequest::OrderList).await
            else {
                panic!("no order list")
            };
            for id in &ids {
                let mut mine: Vec<_> = orders
                    .iter()
                    .filter(|o| o.id > batch_from && o.cell.as_deref() == Some(id.as_str()))
                    .filter_map(|o| Some((o.started_ms?, o.ended_ms?)))
                    .collect();
                mine.sort();
                for w in mine.windows(2) {
                    handovers.push((w[1].1 - w[0].1 - JOB_MS) as f64);
                }
            }
        })
    });
    Figures {
        cells,
        startup_ms,
        dispatch_p50: median(&samples),
        dispatch_tail: tail(&samples),
        handover_p50: median(&handovers),
        handover_tail: tail(&handovers),
        handovers: handovers.len(),
        idle,
        busy,
    }
}

/// Waits until no cell runs an order and none is queued.
async fn until_idle(console: &Bus, operator: &StationName) {
    let end = Instant::now() + Duration::from_secs(300);
    loop {
        // A plant of one answers as its one cell.
        let cells = match console
            .api(operator, ApiRequest::Status, Duration::from_secs(10))
            .await
        {
            Ok(ApiReply::Plant(p)) => p.cells.into_iter().map(|(_, s)| s).collect(),
            Ok(ApiReply::Status(s)) => vec![s],
            _ => Vec::new(),
        };
        if !cells.is_empty() && cells.iter().all(|s| s.running.is_none() && s.queued == 0) {
            return;
        }
        assert!(Instant::now() < end, "the plant's orders did not end");
        tokio::time::sleep(Duration::from_millis(20)).await;
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
        println!(
            "  hand-over, an order's end → the cell's next queued order running at the cell: p50 {:.0} ms, {} {:.0} ms (n={}; two ends of a cell's orders less the job's 200 ms, the records' clock)",
            f.handover_p50, f.handover_tail.0, f.handover_tail.1, f.handovers
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
                "  {:>2} cells: start-up ×{:.1}, dispatch p50 ×{:.2}, hand-over p50 ×{:.2}, operator RSS ×{:.2}, factory router RSS ×{:.2}, operator busy CPU ×{:.1}",
                f.cells,
                r(f.startup_ms, base.startup_ms),
                r(f.dispatch_p50, base.dispatch_p50),
                r(f.handover_p50, base.handover_p50),
                r(f.busy[1].rss, base.busy[1].rss),
                r(f.busy[0].rss, base.busy[0].rss),
                r(f.busy[1].cpu_pct, base.busy[1].cpu_pct),
            );
        }
    }
}
