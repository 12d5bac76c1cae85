//! The simulation in CI: clean runs and runs with every fault, the
//! invariants checked after every step.

use falc_model::records::EntryKind;
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
    // The operator's process crashed or its link was cut, reaching every
    // cell.
    assert!(s.operator_faults >= 1, "{s}");
}

/// The stations come from the topology: a plant whose cell names its
/// welding station otherwise runs no shipped recipe, and is refused with
/// every recipe that names a station it lacks, by file and line.
#[test]
fn a_plant_whose_recipes_name_a_station_it_lacks_is_refused_naming_file_and_line() {
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
    assert!(
        e.contains("recipes/welding/droog_dik.rcp:1: station welding is not a workstation"),
        "{e}"
    );
}

/// Copies the recipe tree `from` into `to`, each station directory also
/// as the stations named in `also` (`("welding", "welding2")`).
fn recipe_tree(
    from: &std::path::Path,
    to: &std::path::Path,
    also: &[(&str, &str)],
) -> std::io::Result<()> {
    for entry in std::fs::read_dir(from)? {
        let dir = entry?.path();
        let Some(station) = dir.file_name().and_then(|n| n.to_str()) else {
            continue;
        };
        if !dir.is_dir() {
            continue;
        }
        let mut names = vec![station];
        names.extend(also.iter().filter(|(a, _)| *a == station).map(|(_, b)| *b));
        for name in names {
            std::fs::create_dir_all(to.join(name))?;
            for file in std::fs::read_dir(&dir)? {
                let file = file?.path();
                if let Some(f) = file.file_name() {
                    std::fs::copy(&file, to.join(name).join(f))?;
                }
            }
        }
    }
    Ok(())
}

/// A cell grown by two stanzas (`welding2`, `transport2`), its recipes a
/// tree read at the start: the simulation builds the stations from the
/// topology, an order that uses all four workstations runs beside the
/// shipped ones, every fault comes, and the invariants hold for every
/// workstation.
#[test]
fn a_cell_grown_by_two_stanzas_runs_its_second_robot_and_conveyor() {
    let here = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let root = here.join("../..");
    let dir = std::env::temp_dir().join(format!("falc-sim-grown-{}", std::process::id()));
    let recipes = dir.join("recipes");
    std::fs::create_dir_all(&recipes).expect("a temporary directory");
    let grown = here.join("tests/fixtures/grown");
    let topology = [
        std::fs::read_to_string(root.join("launch/cell.toml")).expect("launch/cell.toml"),
        std::fs::read_to_string(grown.join("more-stations.toml")).expect("the stanzas"),
    ]
    .concat();
    std::fs::write(dir.join("cell.toml"), topology).expect("written");
    let also = [("welding", "welding2"), ("transport", "transport2")];
    recipe_tree(&root.join("recipes"), &recipes, &also).expect("the recipes copied");
    std::fs::copy(grown.join("dubbel.rcp"), recipes.join("cell/dubbel.rcp")).expect("copied");
    let cfg = Config {
        topology: Some(dir.join("cell.toml")),
        recipe_dir: Some(recipes),
        recipes: vec!["dubbel".into(), "dikdroog".into()],
        seed: 2,
        orders: 120,
        keep_journal: true,
        ..Config::default()
    };
    let ran = Run::new(cfg).and_then(|r| r.run().map_err(|v| v.to_string()));
    let _ = std::fs::remove_dir_all(&dir);
    let s = ran.unwrap_or_else(|e| panic!("{e}"));
    println!("{s}");
    assert_eq!(s.done + s.failed, 120, "{s}");
    assert!(s.done > s.failed, "{s}");
    let jobs = |who: &str, job: &str| {
        s.lines
            .iter()
            .filter(|l| l.contains(&format!("{who}: job {job} ")) && l.ends_with("done"))
            .count()
    };
    // Both robots and both conveyors did their jobs to the end.
    assert!(jobs("welding2", "DROOG_DUN") > 20, "{}", s.lines.join("\n"));
    assert!(jobs("welding", "DROOG_DIK") > 20, "{s}");
    assert!(jobs("transport2", "UNLOAD") > 20, "{s}");
    for f in [Fault::Crash, Fault::Jam, Fault::EStop, Fault::Memory] {
        assert!(s.faults.get(&f).copied().unwrap_or(0) >= 3, "{f}: {s}");
    }
}

/// The in/out cell of `launch/cell-inout.toml`, defined by data alone
/// (its conveyor `equipment/conveyor-inout.toml`, its recipes
/// `recipes-inout/`): 1,000 orders with every fault a cell has, the
/// invariants holding after every step, on its own layout (one carrier,
/// an in/out station, four lines).
#[test]
fn the_in_out_cell_keeps_the_invariants_with_every_fault() {
    let here = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let root = here.join("../..");
    let dir = std::env::temp_dir().join(format!("falc-sim-inout-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temporary directory");
    let equipment = root.join("equipment/conveyor-inout.toml");
    let topology = std::fs::read_to_string(root.join("launch/cell-inout.toml"))
        .expect("launch/cell-inout.toml")
        .replace(
            "equipment = \"equipment/conveyor-inout.toml\"",
            &format!("equipment = \"{}\"", equipment.display()),
        );
    std::fs::write(dir.join("cell.toml"), topology).expect("written");
    let cfg = Config {
        topology: Some(dir.join("cell.toml")),
        recipe_dir: Some(root.join("recipes-inout")),
        recipes: vec!["inoutlas".into()],
        seed: 1,
        orders: 1000,
        keep_journal: true,
        ..Config::default()
    };
    let ran = Run::new(cfg).and_then(|r| r.run().map_err(|v| v.to_string()));
    let _ = std::fs::remove_dir_all(&dir);
    let s = ran.unwrap_or_else(|e| panic!("{e}"));
    println!("{s}");
    assert_eq!(s.done + s.failed, 1000, "{s}");
    assert!(s.done > s.failed, "{s}");
    for f in Fault::ALL.into_iter().filter(|f| *f != Fault::Uplink) {
        let n = s.faults.get(&f).copied().unwrap_or(0);
        assert!(n >= 40, "{f} injected {n} times: {s}");
    }
    let jobs = |job: &str| {
        s.lines
            .iter()
            .filter(|l| l.contains(&format!("transport: job {job} ")) && l.ends_with("done"))
            .count()
    };
    for job in ["LOAD", "TO_TABLE", "TO_OUT", "UNLOAD"] {
        assert!(jobs(job) > 500, "{job}: {}", jobs(job));
    }
}
