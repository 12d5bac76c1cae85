//! A robot program a maintainer starts by hand is theirs (issue 27, B12),
//! on the whole cell through the CLI: in maintenance mode, `manual welding
//! select 65` and `start` run the program on the robot's twin, and the
//! welding workstation does not stop it as an orphan; `manual welding
//! stop` stops it; back in auto, an order runs to done. Its line going
//! silent while it runs is an alarm of its own (no job to end); when the
//! line is back the program, unwatched meanwhile, is stopped, and the way
//! back runs the next order.

use crate::support::rig::{rig, Rig};
use std::time::Duration;

/// In maintenance mode, a maintainer selects and starts robot program 65
/// through the CLI; the twin starts it (`rx G`).
fn program_65_by_hand(rig: &mut Rig) {
    rig.cell.falc(&["mode", "maintenance"]);
    rig.rcm.forget("rx ");
    for args in [&["select", "65"][..], &["start"][..]] {
        let mut all = vec!["manual", "welding"];
        all.extend(args);
        let (code, out) = rig.cell.falc_as("maintainer", &all);
        assert_eq!(code, 0, "{args:?}: {out}");
    }
    rig.rcm.expect_line("rx G", Duration::from_secs(5));
}

#[test]
fn a_robot_program_started_by_hand_runs_until_the_maintainer_stops_it() {
    let mut rig = rig("20");
    program_65_by_hand(&mut rig);
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

#[test]
fn a_silent_line_under_a_program_started_by_hand_is_an_alarm_and_the_way_back_runs_the_next_order()
{
    use falc_model::alarm::AlarmClass;
    let mut rig = rig("20");
    program_65_by_hand(&mut rig);
    rig.rcm.control("unplug");
    // Nothing heard for an acknowledgement delay after the next status
    // request: an alarm naming the device and the program by hand.
    let s = rig.until_status(Duration::from_secs(6), "the silent line's alarm", |s| {
        s.alarms
            .iter()
            .any(|a| a.station == "welding" && a.class == AlarmClass::Communication)
    });
    let alarm = s
        .alarms
        .iter()
        .find(|a| a.station == "welding")
        .cloned()
        .unwrap_or_else(|| panic!("{:#?}", s.alarms));
    assert!(
        alarm.text.contains(&rig.rcm_path)
            && alarm.text.contains("nothing heard for 2.0 s")
            && alarm.text.contains("started by hand"),
        "{alarm:#?}"
    );
    // The line back: the workstation could not watch the program while
    // the line was silent, so it is nobody's any more and is stopped (as
    // any program found running that no job owns); the alarm clears once
    // the robot answers again.
    rig.replug_until_cleared(alarm.id);
    rig.cell.falc(&["mode", "auto"]);
    rig.cell.falc(&["ack"]);
    rig.next_order_done("dikdroog");
}
