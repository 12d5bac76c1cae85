//! A robot program a maintainer starts by hand is theirs (issue 27, B12),
//! on the whole cell through the CLI: in maintenance mode, `manual welding
//! select 65` and `start` run the program on the robot's twin, and the
//! welding workstation does not stop it as an orphan; `manual welding
//! stop` stops it; back in auto, an order runs to done.

use crate::support::rig::rig;
use std::time::Duration;

#[test]
fn a_robot_program_started_by_hand_runs_until_the_maintainer_stops_it() {
    let mut rig = rig("20");
    rig.cell.falc(&["mode", "maintenance"]);
    rig.rcm.forget("rx ");
    for args in [&["select", "65"][..], &["start"][..]] {
        let mut all = vec!["manual", "welding"];
        all.extend(args);
        let (code, out) = rig.cell.falc_as("maintainer", &all);
        assert_eq!(code, 0, "{args:?}: {out}");
    }
    rig.rcm.expect_line("rx G", Duration::from_secs(5));
    // The workstation watches the robot's status (a request every second
    // or so); none of its answers makes it stop the program.
    assert_eq!(
        rig.rcm.wait_line("rx H", Duration::from_secs(4)),
        None,
        "the workstation stopped a program the maintainer started"
    );
    let (code, out) = rig
        .cell
        .falc_as("maintainer", &["manual", "welding", "stop"]);
    assert_eq!(code, 0, "{out}");
    rig.rcm.expect_line("rx H", Duration::from_secs(5));
    rig.cell.falc(&["mode", "auto"]);
    rig.cell.falc(&["ack"]);
    rig.next_order_done("dikdroog");
}
