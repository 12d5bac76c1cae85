//! A station speaks only for itself (issue 41, finding 1), on the whole
//! cell: a session logged in with a station's own credentials publishes,
//! on its own keys, payloads that name another station: a job event
//! ending the cell's order, a status of the cell, an alarm and a journal
//! line of another station, and (from the transport's keys) the end of
//! welding's job while the robot welds. The operator and the cell take the
//! sender from the key: nothing changes (the order runs on, nothing is
//! journalled or listed, the conveyor does not move while the robot
//! welds), and the operator logs the refusal. The order ends done with its
//! weld.

use crate::support::rig::{rig, Rig};
use crate::support::st;
use falc_model::alarm::{AlarmClass, Cause};
use falc_model::ids::ObjectName;
use falc_model::mms::pdu::{JobEvent, Severity, Unconfirmed};
use falc_model::mms::vmd::{RecipeState, VmdStatus};
use falc_model::records::OrderState;
use std::time::Duration;

/// The forgeries a station with its own credentials may try: each names
/// `other` (or, for the job events, the job of `other`).
fn forgeries(other: &str, program: &str) -> Vec<Unconfirmed> {
    let program = ObjectName::new(program).expect("valid");
    vec![
        Unconfirmed::Job {
            station: st(other),
            program: program.clone(),
            event: JobEvent::Done,
        },
        Unconfirmed::Job {
            station: st(other),
            program,
            event: JobEvent::Alarm(Cause::new(AlarmClass::Safety, "forged job alarm")),
        },
        Unconfirmed::Status {
            station: st(other),
            status: VmdStatus {
                local_detail: RecipeState::Ready,
                unready: Some("forged unready".into()),
                ..VmdStatus::default()
            },
        },
        Unconfirmed::Report {
            station: st(other),
            severity: Severity::Alarm(AlarmClass::Safety),
            text: "forged alarm".into(),
        },
        Unconfirmed::Report {
            station: st(other),
            severity: Severity::Info,
            text: "forged journal line".into(),
        },
    ]
}

/// Publishes `messages` from a session of `station` (its own credentials).
fn publish_as(rig: &Rig, station: &str, messages: Vec<Unconfirmed>) {
    let rt = tokio::runtime::Runtime::new().expect("runtime");
    rt.block_on(async {
        let bus = rig.cell.bus(station).await.expect("a session");
        for m in &messages {
            bus.publish(m).await;
        }
        // Let the puts leave before the session closes.
        tokio::time::sleep(Duration::from_millis(200)).await;
        let _ = bus.session().close().await;
    });
}

#[test]
fn a_payload_naming_another_station_than_its_key_changes_nothing_at_the_operator_or_the_cell() {
    let mut rig = rig("20");
    rig.operator = None;
    rig.start_operator_logged();
    rig.cell.falc(&["order", "add", "dikdroog"]);
    rig.cell.falc(&["start"]);
    crate::support::wait::wait_until("the cell's question", Duration::from_secs(30), || {
        let s = rig.status();
        crate::support::wait::holds(s.question.is_some(), || s)
    });

    // The welding station, on its own keys, speaks for the cell (the
    // order's end, the cell's status) and for the transport; the
    // transport speaks for the cell and for welding.
    let mut from_welding = forgeries("cell", "DIKDROOG");
    from_welding.extend(forgeries("transport", "STORE"));
    publish_as(&rig, "welding", from_welding);
    publish_as(&rig, "transport", forgeries("cell", "DIKDROOG"));
    // A window in which nothing may happen.
    std::thread::sleep(Duration::from_secs(1));
    let orders = rig.orders();
    assert_eq!(orders[0].state, OrderState::Running, "{orders:?}");
    let s = rig.status();
    assert!(s.question.is_some(), "the cell still asks: {s:?}");
    let journal = rig.journal(None);
    assert!(
        journal.iter().all(|e| !e.text.contains("forged")),
        "{journal:#?}"
    );
    let alarms = rig.cell.falc(&["alarms"]);
    assert!(!alarms.contains("forged"), "{alarms}");
    let refused = rig
        .operator()
        .wait_line("names station cell", Duration::from_secs(5))
        .expect("the operator logs the refusal");
    assert!(refused.contains("falc/"), "it names the key: {refused}");

    // Mid-weld, the transport says welding's job is done: the cell must
    // not go on to unload while the robot welds (its program runs 6 s at
    // this time scale).
    rig.cell.falc(&["answer", "ja"]);
    rig.until_welding();
    rig.plc.forget("coil button line");
    publish_as(&rig, "transport", forgeries("welding", "DROOG_DIK"));
    publish_as(&rig, "welding", forgeries("transport", "MOVE_TO_MAN"));
    std::thread::sleep(Duration::from_millis(1500));
    assert_eq!(
        rig.plc.wait_line("coil button line F 1", Duration::ZERO),
        None,
        "the conveyor moved while the robot welded"
    );
    rig.work_list("ja", Duration::from_secs(120));
    let orders = rig.orders();
    assert_eq!(orders[0].state, OrderState::Done, "{orders:?}");
    // Its record holds the weld, ended by the robot.
    let record = rig.cell.falc(&["order", "show", "1"]);
    assert!(record.contains("DROOG_DIK"), "{record}");
    let journal = rig.journal(None);
    assert!(
        journal.iter().all(|e| !e.text.contains("forged")),
        "{journal:#?}"
    );
}
