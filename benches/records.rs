//! Records benchmark: what the product records and the figures cost, on
//! the operator's own SQLite code (`nodes/operator/database.rs`, WAL,
//! synchronous FULL) in a file on this disk.
//!
//! Prints:
//! - `falc figures` over a week of a busy cell, as the operator computes
//!   it (the records read for the range, then the sans-I/O figures):
//!   10,000 orders (each a run, with its recipe versions), 100,000
//!   journal entries, 600 alarms, 40 mode changes; median and tail of 20;
//! - what an order start costs with the recipe versions of its run kept
//!   (a cell recipe and five workstation recipes) next to one without,
//!   interleaved, median and tail of 200 each: the only work the records
//!   add while orders run (the figures are computed when asked, never as
//!   orders run).
//!
//! Run: `cargo bench --bench records`. Prints figures; asserts nothing
//! about time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used, dead_code)]

#[path = "../nodes/operator/database.rs"]
mod database;

#[path = "../tests/support/stats.rs"]
mod stats;

use database::Database;
use falc_factory::figures;
use falc_factory::records::Records;
use falc_model::api::Placement;
use falc_model::calendar::Calendar;
use falc_model::figures::FigureQuery;
use falc_model::ids::StationName;
use falc_model::product::{UsedRecipe, VersionHash};
use falc_model::recipe_file::RecipeFile;
use rusqlite::params;
use stats::{median, tail};
use std::time::Instant;

const ORDERS: i64 = 10_000;
const ENTRIES: i64 = 100_000;
const ALARMS: i64 = 600;
const MODES: i64 = 40;
const WEEK_MS: i64 = 7 * 86_400_000;

/// A week of a busy cell, written in one transaction.
fn fill(path: &std::path::Path, start: i64) {
    drop(Database::open(path, "falc1").expect("open"));
    let mut conn = rusqlite::Connection::open(path).expect("open");
    let tx = conn.transaction().expect("tx");
    let step = WEEK_MS / ORDERS;
    for id in 1..=ORDERS {
        let s = start + (id - 1) * step;
        let e = s + step * 7 / 10;
        let state = if id % 20 == 0 { "failed" } else { "done" };
        let recipe = ["dikdroog", "dundroog", "pipdroog"][(id % 3) as usize];
        tx.execute(
            "INSERT INTO orders (id, recipe, state, added_by, added_ms, started_ms, ended_ms, result, cell) \
             VALUES (?1, ?2, ?3, 'console', ?4, ?4, ?5, ?3, 'falc1')",
            params![id, recipe, state, s, e],
        )
        .expect("order");
        tx.execute(
            "INSERT INTO order_runs (order_id, recipe, cell, started_ms, ended_ms, state) \
             VALUES (?1, ?2, 'falc1', ?3, ?4, ?5)",
            params![id, recipe, s, e, state],
        )
        .expect("run");
        for p in 0..6 {
            tx.execute(
                "INSERT INTO order_recipes (order_id, started_ms, position, domain, file, version, hash, starts) \
                 VALUES (?1, ?2, ?3, 'WELDING$DROOG_DIK', 'welding/droog_dik.rcp', 1, ?4, '[]')",
                params![id, s, p, VersionHash::of(b"x").as_str()],
            )
            .expect("recipes");
        }
    }
    for n in 0..ENTRIES {
        let at = start + n * (WEEK_MS / ENTRIES);
        tx.execute(
            "INSERT INTO journal (at_ms, order_id, kind, who, text, cell) \
             VALUES (?1, ?2, 'message', 'cell', 'dikke plaat droog', 'falc1')",
            params![at, n / 10 + 1],
        )
        .expect("entry");
    }
    for n in 0..ALARMS {
        let at = start + n * (WEEK_MS / ALARMS);
        let class = ["safety", "device", "process", "communication", "warning"][(n % 5) as usize];
        let station = ["welding", "transport", "cell"][(n % 3) as usize];
        tx.execute(
            "INSERT INTO alarms (station, class, text, raised_ms, acked_by, acked_ms, cleared_ms, cell) \
             VALUES (?1, ?2, 'x', ?3, 'console', ?4, ?5, 'falc1')",
            params![station, class, at, at + 60_000, at + 90_000],
        )
        .expect("alarm");
    }
    for n in 0..MODES {
        let mode = ["step", "auto", "maintenance", "auto"][(n % 4) as usize];
        tx.execute(
            "INSERT INTO modes (cell, at_ms, mode) VALUES ('falc1', ?1, ?2)",
            params![start + n * (WEEK_MS / MODES), mode],
        )
        .expect("mode");
    }
    tx.commit().expect("commit");
}

fn ms(d: std::time::Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

fn main() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("falc.db");
    let start = 1_795_564_800_000;
    let t = Instant::now();
    fill(&path, start);
    println!(
        "filled: {ORDERS} orders with their runs and recipe versions, {ENTRIES} journal entries, \
         {ALARMS} alarms, {MODES} mode changes in {:.1} s",
        t.elapsed().as_secs_f64()
    );
    let mut db = Database::open(&path, "falc1").expect("open");
    let calendar = Calendar::default();
    let query = FigureQuery {
        since_ms: start,
        until_ms: Some(start + WEEK_MS),
        planned: Vec::new(),
    };
    let mut read = Vec::new();
    let mut computed = Vec::new();
    let mut last = None;
    for _ in 0..20 {
        let t = Instant::now();
        let inputs = db.figure_inputs(start, start + WEEK_MS).expect("read");
        let r = t.elapsed();
        let f = figures::compute(&inputs, &calendar, &["falc1"], &query, start + WEEK_MS);
        computed.push(ms(t.elapsed()));
        read.push(ms(r));
        last = Some(f);
    }
    let f = last.expect("figures");
    let c = &f.cells[0];
    println!(
        "falc figures over a week ({} runs read): median {:.1} ms ({} {:.1} ms), of which reading \
         the records {:.1} ms; OEE {:.1}%, {} periods, {} Pareto lines",
        c.total.quantities.produced + c.total.quantities.stopped,
        median(&computed),
        tail(&computed).0,
        tail(&computed).1,
        median(&read),
        c.total.oee().unwrap_or(0.0) * 100.0,
        c.periods.len(),
        c.pareto.len()
    );
    // An order start, with and without the versions of its run.
    let used: Vec<UsedRecipe> = (0..6)
        .map(|i| UsedRecipe {
            domain: format!("TRANSPORT$R{i}"),
            file: RecipeFile::new(StationName::new("transport").expect("v"), &format!("r{i}"))
                .expect("file"),
            version: 1,
            hash: VersionHash::of(format!("r{i}").as_bytes()),
            starts: vec!["program 65".into()],
        })
        .collect();
    let mut with = Vec::new();
    let mut without = Vec::new();
    for i in 0..400 {
        let o = db
            .add_order("dikdroog", "console", &Placement::default())
            .expect("add");
        let recipes: &[UsedRecipe] = if i % 2 == 0 { &used } else { &[] };
        let t = Instant::now();
        db.set_running(o.id, "falc1", recipes).expect("run");
        let d = ms(t.elapsed());
        if i % 2 == 0 {
            with.push(d);
        } else {
            without.push(d);
        }
        db.end_order(o.id, falc_model::records::OrderState::Done, "done")
            .expect("end");
    }
    println!(
        "order start (durably running, synchronous FULL): with its run's 6 recipe versions \
         median {:.2} ms ({} {:.2} ms), without median {:.2} ms ({} {:.2} ms): ratio {:.2}",
        median(&with),
        tail(&with).0,
        tail(&with).1,
        median(&without),
        tail(&without).0,
        tail(&without).1,
        median(&with) / median(&without)
    );
}
