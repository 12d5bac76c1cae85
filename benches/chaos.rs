//! The chaos program: N rounds on the whole cell (real router, twins,
//! workstations, cell, operator; debug or release binaries as built), each
//! killing a random node (SIGKILL) at a random moment of an order, starting
//! it again and taking the documented way back (carriers set back, `falc
//! ack`, `falc start`). Prints, for N rounds: detection time p50/max per
//! victim, rounds recovered by ack + start alone, orders lost or run twice
//! (goal 0), and every round that did not recover with its journal.
//!
//! Run: `cargo bench --bench chaos -- --rounds 20 [--seed S]`. Prints
//! figures; asserts nothing about time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use std::collections::BTreeMap;
use std::time::Duration;
use support::chaos::{moment, round, Victim};
use support::rig::rig;

fn arg(name: &str) -> Option<u64> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
}

fn ms(d: Duration) -> String {
    format!("{:.1} ms", d.as_secs_f64() * 1000.0)
}

fn main() {
    // The nodes' own logs would drown the figures.
    if std::env::var_os("RUST_LOG").is_none() {
        std::env::set_var("RUST_LOG", "error");
    }
    let rounds = arg("--rounds").unwrap_or(8);
    let seed = arg("--seed").unwrap_or_else(|| rand::thread_rng().gen());
    println!("chaos: {rounds} rounds, seed {seed} (--seed {seed} repeats them)");
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut rig = rig("20");
    let mut detected: BTreeMap<Victim, Vec<Duration>> = BTreeMap::new();
    let mut unseen: BTreeMap<Victim, u32> = BTreeMap::new();
    let mut recovered = 0;
    let mut lost_or_twice = Vec::new();
    let mut failed = Vec::new();
    for i in 1..=rounds {
        let victim = *Victim::ALL.choose(&mut rng).unwrap_or(&Victim::Welding);
        let at = moment(&mut rng, Duration::from_secs(6));
        let r = round(&mut rig, victim, at);
        match r.detected {
            Some(d) => detected.entry(victim).or_default().push(d),
            None => *unseen.entry(victim).or_default() += 1,
        }
        println!(
            "round {i:>3}: {:<9} killed {:>6} into the order, alarm after {:>9}, {} start(s), {}",
            victim.name(),
            ms(r.killed_after),
            r.detected.map_or("—".into(), ms),
            r.starts,
            if r.recovered {
                "recovered"
            } else {
                "NOT recovered"
            }
        );
        if r.recovered && r.problem.is_none() {
            recovered += 1;
        }
        lost_or_twice.extend(r.lost_or_twice.iter().map(|l| format!("round {i}: {l}")));
        if let Some(p) = r.problem {
            failed.push(format!("round {i} ({}): {p}", victim.name()));
            // A fresh cell for the rounds after a failed one.
            rig = support::rig::rig("20");
        }
    }
    println!();
    println!("detection (kill → alarm at the operator; operator kill → abort at the cell):");
    for v in Victim::ALL {
        let mut d = detected.remove(&v).unwrap_or_default();
        d.sort();
        let unseen = unseen.get(&v).copied().unwrap_or(0);
        if d.is_empty() {
            println!(
                "  {:<9} no rounds with an alarm ({unseen} without)",
                v.name()
            );
            continue;
        }
        println!(
            "  {:<9} p50 {:>9}  max {:>9}  ({} rounds{})",
            v.name(),
            ms(d[d.len() / 2]),
            ms(d[d.len() - 1]),
            d.len(),
            if unseen > 0 {
                format!(", {unseen} killed after its part of the order: no alarm")
            } else {
                String::new()
            }
        );
    }
    println!("rounds recovered by ack + start alone: {recovered} of {rounds}");
    println!("orders lost or run twice: {}", lost_or_twice.len());
    for l in &lost_or_twice {
        println!("  {l}");
    }
    for f in &failed {
        println!("NOT RECOVERED {f}");
    }
}
