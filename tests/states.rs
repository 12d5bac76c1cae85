//! The thesis' recipe states (issue 31, item 3) over a run with an alarm,
//! then `ack` and `start`, on the whole cell: the robot's emergency stop
//! mid-weld. Each station's controller produces IDLE, LOADED, READY,
//! EXECUTING and ERROR (after an alarm until a run starts again); the
//! operator adds WAIT_ACK while a station's alarm waits for `falc ack`
//! and, for the cell, PENDING while a start waits. The operator logs each
//! change (`EVENT recipe-state`), and `falc status` shows the state.

use crate::support::rig::{rig, Rig};
use std::time::Duration;

/// The states the operator showed for `station`, in order, each once per
/// change.
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

/// The part of `states` from the first `from` on.
fn from<'a>(states: &'a [String], from: &str) -> &'a [String] {
    let at = states
        .iter()
        .position(|s| s == from)
        .unwrap_or_else(|| panic!("never {from}: {states:?}"));
    &states[at..]
}

#[test]
fn the_recipe_states_go_pending_executing_wait_ack_error_and_back_over_an_alarm_ack_and_start() {
    let mut rig = rig("20");
    rig.operator().expect_line(
        "EVENT recipe-state station=cell state=READY",
        Duration::from_secs(20),
    );
    let status = rig.cell.falc(&["status"]);
    assert!(status.contains("recipe READY"), "{status}");

    rig.start_list_until_welding(&["dikdroog", "dikdroog"]);
    rig.rcm.control("estop");
    rig.operator().expect_line(
        "EVENT order-ended id=1 state=failed",
        Duration::from_secs(10),
    );
    rig.operator().expect_line(
        "EVENT recipe-state station=cell state=WAIT_ACK",
        Duration::from_secs(10),
    );
    let status = rig.cell.falc(&["status"]);
    assert!(status.contains("recipe WAIT_ACK"), "{status}");
    rig.rcm.control("estop-clear");
    rig.operator()
        .expect_line("EVENT alarm-cleared", Duration::from_secs(10));
    rig.way_back();
    let orders = rig.orders();
    assert_eq!(
        orders.last().map(|o| o.state),
        Some(falc_model::records::OrderState::Done),
        "{orders:?}"
    );
    rig.operator()
        .expect_line("EVENT order-ended id=2 state=done", Duration::from_secs(10));
    crate::support::wait::wait_until("the cell READY again", Duration::from_secs(10), || {
        let states = states_of(&mut rig, "cell");
        crate::support::wait::holds(states.last().is_some_and(|s| s == "READY"), || states)
    });

    let cell = states_of(&mut rig, "cell");
    assert_eq!(
        from(&cell, "PENDING"),
        [
            "PENDING",
            "EXECUTING",
            "WAIT_ACK",
            "ERROR",
            "PENDING",
            "EXECUTING",
            "READY"
        ],
        "the cell's states: {cell:?}"
    );
    let welding = states_of(&mut rig, "welding");
    assert_eq!(
        from(&welding, "EXECUTING"),
        ["EXECUTING", "WAIT_ACK", "ERROR", "EXECUTING", "READY"],
        "the welding workstation's states: {welding:?}"
    );
    println!("cell: {}", cell.join(" → "));
    println!("welding: {}", welding.join(" → "));
    let status = rig.cell.falc(&["status"]);
    assert!(status.contains("recipe READY"), "{status}");
}
