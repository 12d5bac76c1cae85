//! A list of orders on a noisy robot line, for the test and the benchmark:
//! the RCM twin flips one bit in a given share of the bytes on the DNC
//! line, both ways, while the whole list runs; what came of it.

use super::rig::Rig;
use falc_model::records::{EntryKind, OrderState};
use std::time::Duration;

/// What a list on a noisy line came to.
pub struct NoisyList {
    /// Orders done.
    pub done: usize,
    /// Orders in the list.
    pub orders: usize,
    /// Every alarm journalled: `who: text`.
    pub alarms: Vec<String>,
    /// Bytes the twin spoilt.
    pub flipped: u64,
    /// How long the list took.
    pub took: Duration,
}

/// Runs `orders` dikdroog orders with `percent` % of the line's bytes
/// flipped. A list that stops in alarm is taken back the documented way
/// (`falc ack`, carriers set back, `falc start`) until every order ended.
pub fn list_with_flips(rig: &mut Rig, percent: &str, orders: usize) -> NoisyList {
    for _ in 0..orders {
        rig.cell.falc(&["order", "add", "dikdroog"]);
    }
    rig.rcm.send(&format!("flips {percent}"));
    rig.rcm
        .take_line(&format!("ok flips {percent}"), Duration::from_secs(10));
    let began = std::time::Instant::now();
    rig.cell.falc(&["start"]);
    rig.work_list("ja", Duration::from_secs(900));
    while rig.orders().iter().any(|o| o.state == OrderState::Queued) {
        rig.way_back();
    }
    let took = began.elapsed();
    rig.rcm.send("flips 0");
    let line = rig.rcm.take_line("ok flips 0", Duration::from_secs(10));
    let flipped = line
        .split_once('(')
        .and_then(|(_, n)| n.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no count in {line:?}"));
    let done = rig
        .orders()
        .iter()
        .filter(|o| o.state == OrderState::Done)
        .count();
    let alarms = rig
        .journal(None)
        .into_iter()
        .filter(|e| e.kind == EntryKind::Alarm)
        .map(|e| format!("{}: {}", e.who, e.text))
        .collect();
    NoisyList {
        done,
        orders,
        alarms,
        flipped,
        took,
    }
}
