//! A bumpless restart of the transport workstation (issue 27, B15), on the
//! whole cell through the CLI: SIGKILLed mid-weld, with the workpiece
//! clamped on station 3, and started again, the workstation reads the
//! PLC's coils back and adopts them: station 3 stays pressed (the twin
//! gets no write releasing it), nothing moves. The order fails as a lost
//! station's does; the way back (carriers set back, `ack`, `start`) runs
//! the next order to done. And a workstation restarted in maintenance
//! mode (issue 27, B13) comes back associated, in maintenance, with its
//! recipes: the maintainer's manual operations and `home` work at once.
//! A workstation started again with too little recipe memory cannot be
//! given its recipes: the start is refused saying so, and the way back
//! (room again, `ack`, `start`) runs the order to done.

use crate::support::rig::rig;
use crate::support::wait::{holds, wait_until};
use falc_model::records::OrderState;
use std::time::Duration;

/// The buttons the conveyor's twin holds, as its `show` prints them.
fn held(rig: &mut crate::support::rig::Rig) -> String {
    rig.plc.forget("buttons held:");
    rig.plc.control("show");
    rig.plc.expect_line("buttons held:", Duration::from_secs(5))
}

/// Station 3 pressed mid-weld; the transport SIGKILLed and started again
/// (and back with its commander, told the cell's mode): the twin gets no
/// write releasing station 3, and it is still pressed. `who` names the
/// transport in the failures.
fn restarted_keeps_the_clamp(rig: &mut crate::support::rig::Rig, who: &str) {
    let before = held(rig);
    assert!(
        before.split_whitespace().any(|w| w == "3"),
        "station 3 is pressed mid-weld: {before}"
    );
    rig.plc.forget("coil ");
    if let Some(t) = rig.transport.as_mut() {
        t.kill();
    }
    rig.start_transport();
    rig.operator()
        .expect_line("EVENT rejoined station=transport", Duration::from_secs(10));
    assert_eq!(
        rig.plc
            .wait_line("coil button station 3 0", Duration::from_secs(3)),
        None,
        "{who} released the clamped workpiece"
    );
    let after = held(rig);
    assert!(
        after.split_whitespace().any(|w| w == "3"),
        "station 3 still pressed after the restart: {after}"
    );
}

#[test]
fn a_restarted_transport_workstation_keeps_the_workpiece_clamped() {
    let mut rig = rig("20");
    rig.start_list_until_welding(&["dikdroog", "dundroog"]);
    restarted_keeps_the_clamp(&mut rig, "the restarted workstation");
    rig.way_back();
    let orders = rig.orders();
    assert_eq!(orders[0].state, OrderState::Failed, "{orders:?}");
    assert_eq!(orders[1].state, OrderState::Done, "{orders:?}");
}

/// Issue 27, B13: a workstation restarted in maintenance mode is told the
/// cell's mode and given its recipes when it comes back, so the
/// maintainer's way back works without `mode auto` and an empty `start`.
#[test]
fn a_workstation_restarted_in_maintenance_gets_the_mode_and_its_recipes() {
    let mut rig = rig("20");
    rig.cell.falc(&["mode", "maintenance"]);
    let (code, out) = rig
        .cell
        .falc_as("maintainer", &["manual", "transport", "line", "A", "20"]);
    assert_eq!(code, 0, "{out}");
    if let Some(t) = rig.transport.as_mut() {
        t.kill();
    }
    rig.start_transport();
    rig.operator()
        .expect_line("EVENT rejoined station=transport", Duration::from_secs(10));
    for args in [
        &["manual", "transport", "press", "B"][..],
        &["manual", "transport", "release", "B"][..],
        &["manual", "transport", "home"][..],
    ] {
        let (code, out) = rig.cell.falc_as("maintainer", args);
        assert_eq!(code, 0, "{args:?} after the restart: {out}");
    }
    rig.transport.as_mut().expect("transport node").expect_line(
        "EVENT job program=HOME event=Done",
        Duration::from_secs(120),
    );
    rig.cell.falc(&["mode", "auto"]);
    rig.cell.falc(&["ack"]);
    rig.next_order_done("dikdroog");
}

/// Issue 41, finding 6, in step mode: the transport SIGKILLed mid-weld
/// and started again is told the cell's step mode when it associates.
/// Leaving auto brought every output to its safe state, which used to
/// release every button: the clamp let go 11 ms after the reconnection
/// with the robot's weld under it. Now the lines stop and the clamp holds;
/// the way back (auto, carriers back, `ack`, `start`) runs the next order.
#[test]
fn a_transport_restarted_in_step_mode_keeps_the_workpiece_clamped() {
    let mut rig = rig("20");
    rig.start_list_until_welding(&["dikdroog", "dundroog"]);
    rig.cell.falc(&["mode", "step", "--station", "transport"]);
    restarted_keeps_the_clamp(&mut rig, "the transport, told the step mode,");
    rig.cell.falc(&["mode", "auto"]);
    rig.way_back();
    let orders = rig.orders();
    assert_eq!(orders[0].state, OrderState::Failed, "{orders:?}");
    assert_eq!(orders[1].state, OrderState::Done, "{orders:?}");
}

/// Issue 42: a transport started again with a 64-byte recipe memory (a
/// controller replaced) is associated, but the cell cannot give it its
/// recipes. `falc start` is refused naming the recipe and the full
/// memory, and the order stays queued: before, the cell started it and it
/// failed at the transport ("program invocation STORE does not exist").
/// The way back: the transport started again with room, `ack`, `start`;
/// the order runs to done.
#[test]
fn a_workstation_with_too_little_recipe_memory_refuses_the_start_until_it_has_room() {
    let mut rig = rig("20");
    if let Some(t) = rig.transport.as_mut() {
        t.kill();
    }
    rig.start_transport_with(&["--recipe-memory", "64"]);
    rig.operator()
        .expect_line("EVENT rejoined station=transport", Duration::from_secs(10));
    rig.cell.falc(&["order", "add", "dikdroog"]);
    // Its loss while idle, and each recipe it could not be given, are
    // alarms of their own: acknowledged, they no longer hold the start
    // back, and the start is refused by the cell.
    let out = wait_until("the cell's refusal", Duration::from_secs(20), || {
        rig.cell.falc(&["ack"]);
        let (code, out) = rig.cell.falc_as("console", &["start"]);
        holds(
            code != 0 && out.contains("the cell starts no order until"),
            || out.clone(),
        )
        .map(|()| out)
    });
    assert!(
        out.contains("cannot be created on WS TRANSPORT")
            && out.contains("the recipe memory is full: 0 of 64 bytes used"),
        "{out}"
    );
    let orders = rig.orders();
    assert_eq!(orders[0].state, OrderState::Queued, "{orders:?}");
    if let Some(t) = rig.transport.as_mut() {
        t.kill();
    }
    rig.start_transport();
    rig.operator()
        .expect_line("EVENT rejoined station=transport", Duration::from_secs(10));
    let orders = rig.start_again_until_done();
    assert_eq!(orders.len(), 1, "{orders:?}");
}
