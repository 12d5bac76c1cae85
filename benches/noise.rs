//! The robot line, dead and noisy. First a dead line: the whole cell mid-
//! weld, the DNC line unplugged at the RCM twin at a different point of
//! the status period each round, and the time until the welding station
//! ends the job in alarm; the way back after each. Then 15 dikdroog
//! orders with 2 % and then 5 % of the DNC line's bytes given a flipped
//! bit (the RCM twin, both ways; twin scale 20, so each weld has about
//! sixteen status requests). A list that stops in alarm is taken back the
//! documented way until every order ended. Prints the detection times
//! (median, least, most) and, per rate, orders done, bytes flipped, the
//! list's time and every alarm's cause, beside what a70706b measured
//! (a dead line seen after 7.0–7.4 s, median 7.15 s; 15 of 15 orders at
//! 2 % and 5 %, no alarm).
//!
//! Run: `cargo bench --bench noise [-- --orders N --rounds N]`. Prints
//! figures; asserts nothing about time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

use std::time::{Duration, Instant};
use support::noise::list_with_flips;
use support::rig::{rig, Rig};

fn arg(name: &str, default: usize) -> usize {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// One round: the next order started (the alarm of the round before
/// acknowledged) and mid-weld, the line unplugged `into` the weld; how
/// long until the welding station's job ends in alarm, and its line. Then
/// the line back (the program nobody owns stopped) and the carriers set
/// back: the way back's first half.
fn dead_line(rig: &mut Rig, into: Duration) -> (Duration, String) {
    rig.rcm.forget("rx G");
    rig.ack_until_started();
    rig.until_welding();
    std::thread::sleep(into);
    let welding = rig.welding.as_mut().expect("the welding node runs");
    welding.forget("event=Alarm");
    rig.rcm.control("unplug");
    let unplugged = Instant::now();
    let line = welding.expect_line("event=Alarm", Duration::from_secs(20));
    let took = unplugged.elapsed();
    rig.rcm.forget("rx H");
    rig.rcm.control("replug");
    rig.rcm.take_line("rx H", Duration::from_secs(15));
    rig.plc.control("layout W2 W2");
    (took, line)
}

fn main() {
    let orders = arg("--orders", 15);
    let rounds = arg("--rounds", 7);
    // Scale 20: each weld takes 8.5 s.
    let mut r = rig("20");
    for _ in 0..rounds {
        r.cell.falc(&["order", "add", "dikdroog"]);
    }
    let mut took = Vec::new();
    for i in 0..rounds {
        // Spread over the 0.5 s status period.
        let into = Duration::from_millis(300 + 70 * i as u64);
        let (t, line) = dead_line(&mut r, into);
        println!(
            "dead line {:.2} s into the weld: alarm after {:.2} s ({line})",
            into.as_secs_f64(),
            t.as_secs_f64()
        );
        took.push(t);
    }
    // The way back's second half: ack, start, the next order done.
    r.cell.falc(&["order", "add", "dikdroog"]);
    let done = r.start_again_until_done();
    println!(
        "after the last round: ack, start, the next order (order {}) done",
        done.len()
    );
    drop(r);
    took.sort();
    if let (Some(least), Some(most)) = (took.first(), took.last()) {
        let median = took[took.len() / 2];
        println!(
            "a dead DNC line seen after: median {:.2} s (least {:.2} s, most {:.2} s) over {rounds} rounds; \
             a70706b: median 7.15 s (7.0–7.4 s); ratio {:.2}",
            median.as_secs_f64(),
            least.as_secs_f64(),
            most.as_secs_f64(),
            median.as_secs_f64() / 7.15
        );
    }
    for percent in ["2", "5"] {
        let mut rig = rig("20");
        let run = list_with_flips(&mut rig, percent, orders);
        println!(
            "{percent} % bit flips: {} of {} orders done, {} bytes flipped, list {:.0} s, {} alarm entries \
             (a70706b: 15 of 15, no alarm)",
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
