//! A workstation lost while no order runs (issue 27, B17 and B18), on the
//! whole cell through the CLI: SIGKILL of the transport workstation in
//! auto mode with the list idle, and of the welding workstation in
//! maintenance mode, are each a communication alarm naming the station;
//! the alarm clears by itself when the station is back on the bus (no
//! `start` needed), and `ack` + `start` run the next order to done. A
//! workstation lost mid-order: the cell's "no connection with station"
//! alarm clears when the station returns, not at the next start. A
//! workstation started again and again faster than its recipes can be
//! delivered is reached at the next start.

use crate::support::rig::{rig, Rig};
use crate::support::wait::{holds, wait_until};
use falc_model::alarm::AlarmClass;
use falc_model::records::OrderState;
use std::time::Duration;

/// Waits until `falc status` lists an alarm of `station` that `done`
/// accepts; that alarm's text.
fn alarm_of(rig: &Rig, station: &str, done: impl Fn(&falc_model::alarm::Alarm) -> bool) -> String {
    wait_until(
        &format!("such an alarm of {station}"),
        Duration::from_secs(10),
        || {
            let s = rig.status();
            s.alarms
                .iter()
                .find(|a| a.station == station && done(a))
                .map(|a| a.text.clone())
                .ok_or(s.alarms)
        },
    )
}

#[test]
fn a_workstation_lost_while_idle_is_an_alarm_cleared_by_its_return() {
    let mut rig = rig("20");
    // Auto mode, the list idle: transport dies.
    if let Some(t) = rig.transport.as_mut() {
        t.kill();
    }
    let text = alarm_of(&rig, "transport", |a| {
        a.class == AlarmClass::Communication && a.cleared_ms.is_none()
    });
    assert_eq!(text, "no connection with station transport");
    let (code, out) = rig.cell.falc_as("console", &["start"]);
    assert_eq!(code, 1, "start waits for the acknowledgement: {out}");
    rig.start_transport();
    alarm_of(&rig, "transport", |a| a.cleared_ms.is_some());

    // Maintenance mode: welding dies, then returns.
    rig.cell.falc(&["mode", "maintenance"]);
    if let Some(w) = rig.welding.as_mut() {
        w.kill();
    }
    alarm_of(&rig, "welding", |a| {
        a.text == "no connection with station welding" && a.cleared_ms.is_none()
    });
    rig.start_welding();
    alarm_of(&rig, "welding", |a| a.cleared_ms.is_some());
    rig.cell.falc(&["mode", "auto"]);

    // The way back: ack, start, the next order done.
    rig.cell.falc(&["ack"]);
    rig.next_order_done("dikdroog");
    assert!(rig.status().alarms.is_empty(), "{:?}", rig.status().alarms);
}

#[test]
fn the_cells_no_connection_alarm_clears_when_the_station_returns() {
    let mut rig = rig("20");
    rig.start_list_until_welding(&["dikdroog", "dundroog"]);
    if let Some(w) = rig.welding.as_mut() {
        w.kill();
    }
    let lost = |a: &falc_model::alarm::Alarm| {
        a.class == AlarmClass::Communication
            && a.text
                .to_lowercase()
                .contains("no connection with station welding")
    };
    wait_until("the welding's lost alarm", Duration::from_secs(10), || {
        let alarms = rig.status().alarms;
        holds(alarms.iter().any(lost), || alarms)
    });
    rig.start_welding();
    // Cleared by the return itself, before any start.
    wait_until("cleared by the return", Duration::from_secs(10), || {
        let alarms = rig.status().alarms;
        let named: Vec<_> = alarms.iter().filter(|a| lost(a)).collect();
        let cleared = !named.is_empty() && named.iter().all(|a| a.cleared_ms.is_some());
        holds(cleared, || alarms.clone())
    });
    rig.way_back();
    let orders = rig.orders();
    assert_eq!(orders[0].state, OrderState::Failed, "{orders:?}");
    assert_eq!(orders[1].state, OrderState::Done, "{orders:?}");
}

/// A workstation killed and started again 25 times in a row, faster than
/// the cell can deliver its recipes: a delivery under way to a node that
/// is gone ends at once instead of waiting out its 10 s deadline, a
/// catch-up queued for it is dropped, and what a later catch-up delivered
/// is owed no more. The next `ack` + `start` is taken at once and the
/// order ends done.
#[test]
fn a_workstation_started_again_and_again_gets_its_recipes_and_the_next_start_is_taken() {
    let mut rig = rig("20");
    for _ in 0..25 {
        drop(rig.transport.take());
        rig.station_connected("transport", false);
        rig.start_transport();
        rig.station_connected("transport", true);
    }
    rig.cell.falc(&["ack"]);
    rig.cell.falc(&["order", "add", "dikdroog"]);
    let (code, out) = rig.cell.falc_as("console", &["start"]);
    assert_eq!(code, 0, "the first start after the restarts: {out}");
    rig.work_list("ja", Duration::from_secs(120));
    rig.last_order_done();
}
