//! Each output's safe state (issue 41, finding 6), on the whole cell: a
//! workstation that loses its commander or is stopped cannot know whether
//! the robot still welds, so the clamp on station 3 holds its workpiece
//! (its safe state) while the lines stop. The cell killed mid-weld, then
//! the transport stopped (SIGTERM, as `systemctl stop`) mid-weld: each
//! time the robot is halted (`H` at its twin) and the conveyor's twin gets
//! no write releasing station 3; the way back (the node started again,
//! carriers set back, `ack`, `start`) runs the next order to done. The
//! transport's link cut mid-weld is in `tests/hosts.rs`.

use crate::support::rig::{rig, Rig};
use crate::support::wait::{holds, wait_until};
use std::time::Duration;

/// After a fault mid-weld: the robot halted, and station 3 not released
/// for `window` after.
fn clamp_held_while_the_robot_stops(rig: &mut Rig, fault: &str, window: Duration) {
    rig.rcm.expect_line("rx H", Duration::from_secs(10));
    assert_eq!(
        rig.plc.wait_line("coil button station 3 0", window),
        None,
        "{fault}: the clamp let go of the workpiece"
    );
}

#[test]
fn the_clamp_holds_when_the_cell_is_killed_or_the_transport_stopped_mid_weld() {
    let mut rig = rig("20");

    // The cell controller killed mid-weld.
    rig.start_list_until_welding(&["dikdroog", "dikdroog"]);
    rig.plc.forget("coil button station 3");
    rig.rcm.forget("rx H");
    rig.cell_node.kill();
    clamp_held_while_the_robot_stops(&mut rig, "the cell killed", Duration::from_secs(3));
    rig.start_cell();
    rig.plc.control("layout W2 W2");
    rig.start_again_until_done();

    // The transport workstation stopped mid-weld (SIGTERM).
    rig.rcm.forget("rx G");
    rig.start_list_until_welding(&["dikdroog", "dikdroog"]);
    rig.plc.forget("coil button station 3");
    rig.rcm.forget("rx H");
    let transport = rig.transport.as_mut().expect("transport node");
    transport.terminate();
    transport.expect_line("EVENT stopped", Duration::from_secs(10));
    wait_until("the transport stopped", Duration::from_secs(10), || {
        let alive = rig.transport.as_mut().is_some_and(|t| t.alive());
        holds(!alive, || "still running")
    });
    clamp_held_while_the_robot_stops(&mut rig, "the transport stopped", Duration::from_secs(2));
    rig.start_transport();
    assert_eq!(
        rig.plc
            .wait_line("coil button station 3 0", Duration::from_secs(1)),
        None,
        "the restarted transport released the clamp"
    );
    rig.plc.control("layout W2 W2");
    rig.start_again_until_done();
}
