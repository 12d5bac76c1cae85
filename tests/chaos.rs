//! Chaos in the suite (bounded: one round per node, twins at a high time
//! scale): each round kills a node with SIGKILL at a random moment of an
//! order, starts it again and takes the documented way back (carriers set
//! back, `falc ack`, `falc start`); every round must end with the next
//! order done, no order lost or run twice (journal checked) and every node
//! running. The seed is printed; `CHAOS_SEED=N` repeats a run.
//! `cargo bench --bench chaos -- --rounds N` runs many rounds with figures.

use crate::support::chaos::{moment, round, Victim};
use crate::support::rig::rig;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use std::time::Duration;

#[test]
fn a_random_node_killed_mid_order_every_round_recovers_by_ack_and_start() {
    let seed: u64 = std::env::var("CHAOS_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| rand::thread_rng().gen());
    println!("chaos seed {seed} (CHAOS_SEED={seed} repeats this run)");
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut victims = Victim::ALL.to_vec();
    victims.shuffle(&mut rng);
    let mut rig = rig("20");
    let mut failed = Vec::new();
    for v in victims {
        let at = moment(&mut rng, Duration::from_secs(6));
        let r = round(&mut rig, v, at);
        println!(
            "round: {} killed {:?} into the order, seen after {:?}, {} start(s), recovered {}",
            v.name(),
            r.killed_after,
            r.detected,
            r.starts,
            r.recovered
        );
        if !r.recovered || !r.lost_or_twice.is_empty() || r.problem.is_some() {
            failed.push(format!(
                "{}: recovered {}, lost or twice {:?}, {}",
                v.name(),
                r.recovered,
                r.lost_or_twice,
                r.problem.unwrap_or_default()
            ));
        }
    }
    assert!(
        failed.is_empty(),
        "seed {seed}: rounds that did not recover:\n{}",
        failed.join("\n")
    );
}
