//! The simulation in CI: clean runs and runs with every fault, the
//! invariants checked after every step.

use falc_model::console::EntryKind;
use falc_sim::{Config, Fault, Run};

fn run(cfg: Config) -> falc_sim::Summary {
    let seed = cfg.seed;
    match Run::new(cfg).and_then(|r| r.run().map_err(|v| v.to_string())) {
        Ok(s) => {
            println!("seed {seed}: {s}");
            s
        }
        Err(e) => panic!("seed {seed}: {e}"),
    }
}

#[test]
fn ten_orders_without_faults_all_end_done() {
    let s = run(Config {
        orders: 10,
        faults: Vec::new(),
        ..Config::default()
    });
    assert_eq!((s.done, s.failed), (10, 0), "{s}");
}

/// The acceptance run: 1,200 orders with every kind of fault a cell has
/// at least 50 times (ten kinds), each followed by the way back; the
/// invariants hold after every step.
#[test]
fn a_thousand_orders_with_every_fault_keep_the_invariants() {
    let s = run(Config {
        seed: 1,
        orders: 1200,
        ..Config::default()
    });
    assert_eq!(s.done + s.failed, 1200, "{s}");
    // A cell of its own has no uplink to cut.
    assert_eq!(s.faults.get(&Fault::Uplink), None, "{s}");
    for f in Fault::ALL.into_iter().filter(|f| *f != Fault::Uplink) {
        let n = s.faults.get(&f).copied().unwrap_or(0);
        assert!(n >= 50, "{f} injected {n} times: {s}");
    }
    assert!(s.done > s.failed, "{s}");
}

#[test]
fn the_same_seed_gives_the_same_run() {
    let cfg = Config {
        seed: 7,
        orders: 40,
        ..Config::default()
    };
    let (a, b) = (run(cfg.clone()), run(cfg));
    assert_eq!(a.kinds, b.kinds);
    assert_eq!((a.steps, a.simulated), (b.steps, b.simulated));
}

/// The records are stamped by the virtual clock: every entry between the
/// start of the run and its end, in order, and the orders' runs (the
/// journal's start to its end of each) fill most of the production time,
/// not the few milliseconds a clock of the records' own gave them.
#[test]
fn recorded_times_follow_the_virtual_clock() {
    let s = run(Config {
        orders: 10,
        faults: Vec::new(),
        keep_journal: true,
        ..Config::default()
    });
    let start = falc_sim::world::EPOCH_MS;
    let end = start + i64::try_from(s.simulated.as_millis()).expect("fits");
    let mut last = start;
    let mut spans: std::collections::BTreeMap<i64, (i64, i64)> = Default::default();
    for e in &s.entries {
        assert!(
            (last..=end).contains(&e.at_ms),
            "entry {} at {} not between {last} and {end}",
            e.id,
            e.at_ms
        );
        last = e.at_ms;
        if let (Some(o), EntryKind::Order) = (e.order, e.kind) {
            let span = spans.entry(o).or_insert((e.at_ms, e.at_ms));
            span.1 = e.at_ms;
        }
    }
    assert_eq!(spans.len(), 10, "{spans:?}");
    let busy: i64 = spans.values().map(|(a, b)| b - a).sum();
    let production = end - start;
    assert!(
        busy * 2 > production && busy <= production,
        "orders spanned {busy} ms of {production} ms"
    );
}

/// The shipped plant of three cells under one operator: orders for any
/// cell, every fault including cut uplinks and the operator's crash; the
/// invariants across cells hold after every step (no order started twice
/// anywhere, a cut-off cell keeps its order, a fault in one cell fails no
/// order of another) and every cell works.
#[test]
fn a_plant_of_three_cells_keeps_the_invariants_across_cells() {
    let topology =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../launch/factory.toml");
    let s = run(Config {
        topology: Some(topology),
        seed: 3,
        orders: 400,
        ..Config::default()
    });
    assert_eq!(s.done + s.failed, 400, "{s}");
    assert_eq!(s.cells.len(), 3, "{s}");
    for (cell, done, _) in &s.cells {
        assert!(*done > 60, "{cell} did {done} orders: {s}");
    }
    for f in [Fault::Uplink, Fault::Crash, Fault::Partition] {
        assert!(s.faults.get(&f).copied().unwrap_or(0) >= 3, "{f}: {s}");
    }
}

#[test]
fn a_plant_topology_that_the_simulation_cannot_drive_is_refused_naming_it() {
    let dir = std::env::temp_dir().join(format!("falc-sim-topology-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temporary directory");
    let path = dir.join("plant.toml");
    let shipped = include_str!("../../../launch/factory.toml");
    let odd = shipped.replacen("name = \"welding\"", "name = \"welder\"", 1);
    std::fs::write(&path, odd).expect("written");
    let refused = Run::new(Config {
        topology: Some(path),
        ..Config::default()
    });
    let _ = std::fs::remove_dir_all(&dir);
    let e = refused.err().expect("refused");
    assert!(e.contains("cell falc1") && e.contains("welder"), "{e}");
}
