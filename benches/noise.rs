//! The whole cell on a noisy robot line: 15 dikdroog orders with 2 % and
//! then 5 % of the DNC line's bytes given a flipped bit (the RCM twin,
//! both ways; twin scale 20, so each weld has about eight status
//! requests). A list that stops in alarm is taken back the documented way
//! until every order ended. Prints, per rate: orders done, bytes flipped,
//! the list's time and every alarm's cause.
//!
//! Run: `cargo bench --bench noise [-- --orders N]`. Prints figures;
//! asserts nothing about time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

use support::noise::list_with_flips;
use support::rig::rig;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let orders = args
        .iter()
        .position(|a| a == "--orders")
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(15);
    for percent in ["2", "5"] {
        let mut rig = rig("20");
        let run = list_with_flips(&mut rig, percent, orders);
        println!(
            "{percent} % bit flips: {} of {} orders done, {} bytes flipped, list {:.0} s, {} alarm entries",
            run.done,
            run.orders,
            run.flipped,
            run.took.as_secs_f64(),
            run.alarms.len()
        );
        for a in &run.alarms {
            println!("  {a}");
        }
    }
}
