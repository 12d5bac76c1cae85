//! A bumpless restart of the transport workstation (issue 27, B15), on the
//! whole cell through the CLI: SIGKILLed mid-weld, with the workpiece
//! clamped on station 3, and started again, the workstation reads the
//! PLC's coils back and adopts them: station 3 stays pressed (the twin
//! gets no write releasing it), nothing moves. The order fails as a lost
//! station's does; the way back (carriers set back, `ack`, `start`) runs
//! the next order to done. And a workstation restarted in maintenance
//! mode (issue 27, B13) comes back associated, in maintenance, with its
//! recipes: the maintainer's manual operations and `home` work at once.

use crate::support::rig::rig;
use falc_model::console::OrderState;
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
