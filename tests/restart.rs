//! A bumpless restart of the transport workstation (issue 27, B15), on the
//! whole cell through the CLI: SIGKILLed mid-weld, with the workpiece
//! clamped on station 3, and started again, the workstation reads the
//! PLC's coils back and adopts them: station 3 stays pressed (the twin
//! gets no write releasing it), nothing moves. The order fails as a lost
//! station's does; the way back (carriers set back, `ack`, `start`) runs
//! the next order to done.

use crate::support::rig::rig;
use falc_model::console::OrderState;
use std::time::Duration;

/// The buttons the conveyor's twin holds, as its `show` prints them.
fn held(rig: &mut crate::support::rig::Rig) -> String {
    rig.plc.forget("buttons held:");
    rig.plc.control("show");
    rig.plc.expect_line("buttons held:", Duration::from_secs(5))
}

#[test]
fn a_restarted_transport_workstation_keeps_the_workpiece_clamped() {
    let mut rig = rig("20");
    rig.start_list_until_welding(&["dikdroog", "dundroog"]);
    let before = held(&mut rig);
    assert!(
        before.split_whitespace().any(|w| w == "3"),
        "station 3 is pressed mid-weld: {before}"
    );
    rig.plc.forget("coil ");
    if let Some(t) = rig.transport.as_mut() {
        t.kill();
    }
    rig.start_transport();
    assert_eq!(
        rig.plc
            .wait_line("coil button station 3 0", Duration::from_secs(3)),
        None,
        "the restarted workstation released the clamped workpiece"
    );
    let after = held(&mut rig);
    assert!(
        after.split_whitespace().any(|w| w == "3"),
        "station 3 still pressed after the restart: {after}"
    );
    rig.way_back();
    let orders = rig.orders();
    assert_eq!(orders[0].state, OrderState::Failed, "{orders:?}");
    assert_eq!(orders[1].state, OrderState::Done, "{orders:?}");
}
