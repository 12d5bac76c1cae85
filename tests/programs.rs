//! Robot programs delivered like recipes (issue 44), on the whole cell:
//! the store's `robot/065.prg` goes to the robot controller's twin over
//! the DNC line at the list's start; an edit saved with `falc store put`
//! while program 65 runs is delivered only at the next start, after the
//! weld; the twin runs the text it was given (its log shows each step);
//! `falc order show` names the program version each weld ran; a rollback
//! puts the old text back at the twin.

use crate::support::rig::{rig, Rig};
use falc_model::product::OrderRecord;
use std::time::Duration;

const WAIT: Duration = Duration::from_secs(30);

/// The version of robot program 65 each run of order `id` ran.
fn program_versions(rig: &Rig, id: i64) -> Vec<u32> {
    let record: OrderRecord = rig.reply(&["order", "show", &id.to_string()]);
    record
        .runs
        .iter()
        .map(|run| {
            let p = run
                .recipes
                .iter()
                .find(|u| u.domain == "WELDING$PROGRAM_065")
                .unwrap_or_else(|| panic!("no robot program in {run:?}"));
            assert_eq!(p.file.to_string(), "robot/065.prg");
            p.version
        })
        .collect()
}

/// Saves `text` as robot program 65 (engineer, with `why`); the answer.
fn save(rig: &Rig, text: &str, why: &str) -> String {
    let local = rig.recipes.join("../065.edited.prg");
    std::fs::write(&local, text).expect("write");
    let (code, out) = rig.cell.falc_as(
        "engineer",
        &[
            "store",
            "put",
            "robot",
            "065",
            &local.display().to_string(),
            "-m",
            why,
        ],
    );
    assert_eq!(code, 0, "{out}");
    out
}

/// The next order runs to done; its start delivered program 65 (`lasts`
/// in all) and its weld ran `second_step`.
fn next_order_runs(rig: &mut Rig, lasts: &str, second_step: &str) {
    rig.next_order_done("dikdroog");
    rig.rcm
        .expect_line(&format!("program 65 stored: 5 steps, {lasts}"), WAIT);
    rig.rcm
        .expect_line(&format!("program 65 step 2/5: {second_step}"), WAIT);
}

#[test]
fn a_robot_program_is_delivered_run_replaced_after_its_weld_named_in_the_record_and_rolled_back() {
    let mut rig = rig("20");
    let original =
        std::fs::read_to_string(rig.recipes.join("robot/065.prg")).expect("the shipped program");

    // The list's start delivers every program; the weld runs program 65's
    // delivered text step by step.
    rig.cell.falc(&["order", "add", "dikdroog"]);
    rig.cell.falc(&["start"]);
    rig.rcm
        .expect_line("program 65 stored: 5 steps, 120.0 s", WAIT);
    rig.until_welding();
    rig.rcm
        .expect_line("program 65 step 2/5: weld seam_1 45 s", WAIT);

    // Saved while program 65 runs: a version, not delivered now.
    rig.rcm.forget("program 65 stored");
    let edited = original.replace("weld seam_1 45", "weld seam_1 50");
    let out = save(&rig, &edited, "longer first seam");
    assert!(out.contains("version 2"), "{out}");
    rig.work_list("ja", Duration::from_secs(120));
    rig.last_order_done();
    rig.rcm.forget("rx ");
    assert_eq!(
        rig.rcm.lines_containing("program 65 stored"),
        Vec::<String>::new(),
        "program 65 replaced before the next start"
    );
    rig.rcm.forget("program 65");

    // The next start delivers the edit; the weld runs it.
    next_order_runs(&mut rig, "125.0 s", "weld seam_1 50 s");
    assert_eq!(program_versions(&rig, 1), vec![1]);
    assert_eq!(program_versions(&rig, 2), vec![2]);
    let text = rig.cell.falc(&["order", "show", "2"]);
    assert!(
        text.contains("WELDING$PROGRAM_065") && text.contains("robot/065.prg"),
        "{text}"
    );

    // A rollback is version 3 with version 1's text: the twin gets the
    // old text back at the next start.
    rig.rcm.forget("program 65");
    let (code, out) = rig.cell.falc_as(
        "engineer",
        &["store", "rollback", "robot", "065", "1", "-m", "back"],
    );
    assert_eq!(code, 0, "{out}");
    next_order_runs(&mut rig, "120.0 s", "weld seam_1 45 s");
    assert_eq!(program_versions(&rig, 3), vec![3]);

    // Its history says who changed it and why; the diff, what.
    let said = |v: u32, who: &str, why: &str| (v, who.to_string(), why.to_string());
    assert_eq!(
        rig.history("robot", "065"),
        vec![
            said(1, "operator", "found in the recipe store"),
            said(2, "engineer", "longer first seam"),
            said(3, "engineer", "back"),
        ]
    );
    let diff = rig.cell.falc(&["store", "diff", "robot", "065", "1", "2"]);
    assert!(
        diff.contains("-weld seam_1 45") && diff.contains("+weld seam_1 50"),
        "{diff}"
    );
}
