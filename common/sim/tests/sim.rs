//! The simulation in CI: clean runs and runs with every fault, the
//! invariants checked after every step.

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

/// The acceptance run: 1,000 orders with every kind of fault at least 50
/// times, each followed by the way back; the invariants hold after every
/// step.
#[test]
fn a_thousand_orders_with_every_fault_keep_the_invariants() {
    let s = run(Config {
        seed: 1,
        orders: 1000,
        ..Config::default()
    });
    assert_eq!(s.done + s.failed, 1000, "{s}");
    for f in Fault::ALL {
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
