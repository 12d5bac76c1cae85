//! Pre- and postconditions on the whole cell (issue 44, item 1): the
//! shipped STORE's `#PRE` refuses the cell's start of it with a carrier
//! set by hand where it needs none, the order fails naming it and no coil
//! is written; the shipped UNSTORE's `#POST` fails the job when the sensor
//! of the place it leaves its carrier at is stuck dark. Each way back
//! (carriers home, the sensor mended, `ack`, `start`) runs the next order
//! to done.

use crate::support::rig::rig;
use falc_model::records::{EntryKind, OrderState};
use std::time::Duration;

/// The failed order's result and the alarm entries of order `id`.
fn failure_of(rig: &crate::support::rig::Rig, id: i64) -> (String, Vec<String>) {
    let order = rig
        .orders()
        .into_iter()
        .find(|o| o.id == id)
        .expect("the order");
    assert_eq!(order.state, OrderState::Failed, "{order:?}");
    let alarms = rig
        .journal(Some(id))
        .into_iter()
        .filter(|e| e.kind == EntryKind::Alarm)
        .map(|e| e.text)
        .collect();
    (order.result.unwrap_or_default(), alarms)
}

#[test]
fn a_false_precondition_refuses_the_start_and_a_false_postcondition_fails_the_job() {
    let mut rig = rig("20");
    // No carrier at W2, one at W3: STORE may not start. The transport
    // says so in its status before anything is asked of it.
    rig.plc.control("layout W3 W4");
    rig.until_status(Duration::from_secs(10), "STORE's #PRE false", |s| {
        s.stations.iter().any(|v| {
            v.name.as_str() == "transport"
                && v.status
                    .as_ref()
                    .is_some_and(|st| st.unmet.keys().any(|k| k.as_str() == "STORE"))
        })
    });
    // `falc status` says so too, in words.
    let text = rig.cell.falc(&["status"]);
    assert!(
        text.contains(
            "not startable: precondition of STORE: place 2 occupied, place 3 empty is false"
        ),
        "{text}"
    );
    rig.plc.forget("coil ");
    rig.cell.falc(&["order", "add", "--count", "2", "dikdroog"]);
    rig.cell.falc(&["start"]);
    rig.work_list("ja", Duration::from_secs(60));
    let (result, _) = failure_of(&rig, 1);
    assert!(
        result.contains(
            "the start of transport was refused: service/object-state-conflict: precondition \
             of STORE: place 2 occupied, place 3 empty is false"
        ),
        "{result}"
    );
    if let Some(l) = rig
        .plc
        .wait_line("coil button line K 1", Duration::from_millis(500))
    {
        panic!("the refused STORE pressed K: {l}");
    }
    // The way back: carriers home, ack, start: the next order done.
    rig.way_back();
    rig.orders_are(&[OrderState::Failed, OrderState::Done]);

    // UNSTORE leaves its carrier at W2; W2's sensor stuck dark from the
    // weld's start (the other carrier left W2 before it) keeps it unseen:
    // the job ends, its postcondition false, the order failed naming it.
    rig.rcm.forget("rx G");
    rig.cell.falc(&["order", "add", "--count", "2", "dikdroog"]);
    rig.cell.falc(&["start"]);
    rig.until_welding();
    rig.plc.control("stuck 2 0");
    rig.operator().expect_line(
        "EVENT order-ended id=3 state=failed",
        Duration::from_secs(60),
    );
    let (result, alarms) = failure_of(&rig, 3);
    let post = "postcondition of UNSTORE: place 2 occupied is false";
    assert!(
        result.contains(post) || alarms.iter().any(|a| a.contains(post)),
        "{result} / {alarms:?}"
    );
    // The way back: the sensor mended, carriers home, ack, start.
    rig.plc.control("unstuck 2");
    rig.way_back();
    rig.orders_are(&[
        OrderState::Failed,
        OrderState::Done,
        OrderState::Failed,
        OrderState::Done,
    ]);
}
