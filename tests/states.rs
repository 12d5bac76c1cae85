//! The thesis' recipe states on the whole cell, as each controller
//! produces them for its own recipe: WAIT_ACK while a Start it sent waits
//! for its confirm, PENDING while it waits for a job below to end (`wait`),
//! EXECUTING otherwise while it runs; IDLE, LOADED, READY and ERROR (after
//! an alarm until a run starts again) around it. First an order run to
//! done, then one with the robot's emergency stop mid-weld, `ack` and
//! `start`: the alarm waiting for `ack` is shown as the alarm, not as a
//! recipe state. The operator logs each change (`EVENT recipe-state`),
//! and `falc status` shows the state.

use crate::support::rig::{rig, Rig};
use std::time::Duration;

/// The states the operator showed for `station` since it was last asked,
/// in order, each once per change.
fn states_of(rig: &mut Rig, station: &str) -> Vec<String> {
    let operator = rig.operator();
    operator.drain();
    let needle = format!("EVENT recipe-state station={station} state=");
    operator
        .lines_containing(&needle)
        .iter()
        .filter_map(|l| l.split_once(&needle).map(|(_, s)| s.to_string()))
        .collect()
}

/// Whether `want` appears in `states` in this order (others between).
fn in_order(states: &[String], want: &[&str]) -> bool {
    let mut it = states.iter();
    want.iter().all(|w| it.any(|s| s == w))
}

#[test]
fn each_level_shows_wait_ack_for_its_start_pending_for_its_wait_and_an_alarm_as_an_alarm() {
    let mut rig = rig("20");
    rig.operator().expect_line(
        "EVENT recipe-state station=cell state=READY",
        Duration::from_secs(20),
    );
    let status = rig.cell.falc(&["status"]);
    assert!(status.contains("recipe READY"), "{status}");

    // 1. An order run to done.
    rig.cell.falc(&["order", "add", "dikdroog"]);
    rig.cell.falc(&["start"]);
    rig.work_list("ja", Duration::from_secs(120));
    rig.operator()
        .expect_line("EVENT order-ended id=1 state=done", Duration::from_secs(10));
    let mut cell = Vec::new();
    crate::support::wait::wait_until("the cell READY again", Duration::from_secs(10), || {
        cell.extend(states_of(&mut rig, "cell"));
        crate::support::wait::holds(cell.last().is_some_and(|s| s == "READY"), || cell.clone())
    });
    let welding = states_of(&mut rig, "welding");
    let transport = states_of(&mut rig, "transport");
    println!("cell: {}", cell.join(" → "));
    println!("welding: {}", welding.join(" → "));
    println!("transport: {}", transport.join(" → "));
    // The cell: its greeting and question (EXECUTING), each `start` until
    // the workstation confirms (WAIT_ACK), each `wait` (PENDING).
    assert!(
        in_order(
            &cell,
            &[
                "READY",
                "EXECUTING",
                "WAIT_ACK",
                "PENDING",
                "WAIT_ACK",
                "PENDING",
                "READY"
            ]
        ),
        "the cell's states: {cell:?}"
    );
    // The welding station: `start rcm 65` until the robot confirms, then
    // `wait rcm` until the program ends.
    let weld_from = welding
        .iter()
        .position(|s| s == "WAIT_ACK")
        .unwrap_or_else(|| panic!("welding never WAIT_ACK: {welding:?}"));
    assert_eq!(
        &welding[weld_from..],
        ["WAIT_ACK", "PENDING", "READY"],
        "the welding station's states: {welding:?}"
    );
    // The transport starts nothing below it: its recipes only execute.
    assert!(
        transport.iter().any(|s| s == "EXECUTING")
            && !transport.iter().any(|s| s == "WAIT_ACK" || s == "PENDING"),
        "the transport's states: {transport:?}"
    );

    // 2. The robot's emergency stop mid-weld: the order fails, the cell
    // and the welding station are in ERROR, and the alarm waiting for
    // `ack` is the status's ALARM line, not a recipe state.
    rig.rcm.forget("rx G");
    rig.start_list_until_welding(&["dikdroog", "dikdroog"]);
    states_of(&mut rig, "cell");
    states_of(&mut rig, "welding");
    rig.rcm.control("estop");
    rig.operator().expect_line(
        "EVENT order-ended id=2 state=failed",
        Duration::from_secs(10),
    );
    let status = rig.until_status(Duration::from_secs(10), "the cell in ERROR", |s| {
        s.stations.iter().any(|v| {
            v.name.as_str() == "cell"
                && v.status
                    .as_ref()
                    .is_some_and(|st| st.local_detail.to_string() == "ERROR")
        })
    });
    assert!(status.alarm.is_some(), "{status:?}");
    let text = rig.cell.falc(&["status"]);
    assert!(
        text.contains("ALARM:") && text.contains("recipe ERROR") && !text.contains("WAIT_ACK"),
        "{text}"
    );
    rig.rcm.control("estop-clear");
    rig.operator()
        .expect_line("EVENT alarm-cleared", Duration::from_secs(10));
    rig.way_back();
    rig.operator()
        .expect_line("EVENT order-ended id=3 state=done", Duration::from_secs(10));
    let mut cell = Vec::new();
    crate::support::wait::wait_until("the cell READY again", Duration::from_secs(10), || {
        cell.extend(states_of(&mut rig, "cell"));
        crate::support::wait::holds(cell.last().is_some_and(|s| s == "READY"), || cell.clone())
    });
    let welding = states_of(&mut rig, "welding");
    println!("after the alarm, cell: {}", cell.join(" → "));
    println!("after the alarm, welding: {}", welding.join(" → "));
    assert!(
        in_order(
            &cell,
            &["ERROR", "EXECUTING", "WAIT_ACK", "PENDING", "READY"]
        ),
        "the cell's states: {cell:?}"
    );
    assert!(
        in_order(&welding, &["ERROR", "WAIT_ACK", "PENDING", "READY"]),
        "the welding station's states: {welding:?}"
    );
    let status = rig.cell.falc(&["status"]);
    assert!(status.contains("recipe READY"), "{status}");
}
