//! The cell as separate hosts: the router, the operator, the cell and each
//! workstation in a network namespace of its own, joined by veth links to a
//! bridge, every link mutual TLS (`support::hosts`). An order runs to done,
//! and what crossed the bridge holds none of the recipe text, questions,
//! answers or keys, while a control text sent in clear is seen. Then links are cut mid-order, for 3 s and for 30 s:
//! each cut is an alarm within the lease, the station rejoins by itself,
//! and `ack` + `start` run the next order. Needs root (namespaces); without
//! it the test says so and does nothing else.

use crate::support::hosts::{Hosts, ROUTER_ADDRESS};
use crate::support::rig::{rig_hosts, Rig};
use falc_model::console::OrderState;
use std::time::{Duration, Instant};

fn hosts_or_say_why() -> Option<Hosts> {
    match Hosts::create() {
        Ok(h) => Some(h),
        Err(e) => {
            eprintln!(
                "NOT RUN: the cell as separate hosts needs root to create network namespaces and veth links: {e}"
            );
            None
        }
    }
}

/// Waits until `falc status` names an unacknowledged alarm of `station`
/// (an acknowledged one of an earlier cut does not count); how long it
/// took.
fn alarm_of(rig: &Rig, station: &str, within: Duration) -> Duration {
    let begin = Instant::now();
    loop {
        let s = rig.status();
        if s.alarms
            .iter()
            .any(|a| a.acked.is_none() && a.text.contains(station))
        {
            return begin.elapsed();
        }
        assert!(
            begin.elapsed() < within,
            "no alarm naming {station} within {within:?}: {s:?}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Waits until every station is on the bus again.
fn all_back(rig: &Rig, within: Duration) -> Duration {
    let begin = Instant::now();
    loop {
        let s = rig.status();
        if s.stations.iter().all(|v| v.connected) {
            return begin.elapsed();
        }
        assert!(
            begin.elapsed() < within,
            "not every station rejoined within {within:?}: {s:?}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn the_cell_as_separate_hosts_over_tls_runs_orders_and_rides_out_cut_links() {
    let Some(hosts) = hosts_or_say_why() else {
        return;
    };
    let capture = hosts.capture();
    // The control: a text sent in clear across the bridge is seen.
    let control = "FALC capture control, sent in clear";
    let mut rig = rig_hosts(hosts, "20");
    if let Some(h) = rig.cell.hosts.as_ref() {
        h.send_in_clear("operator", &format!("{ROUTER_ADDRESS}:7447"), control);
    }
    rig.cell.falc(&["order", "add", "dikdroog"]);
    rig.cell.falc(&["start"]);
    let questions = rig.work_list("ja", Duration::from_secs(120));
    assert!(!questions.is_empty(), "the order asked nothing");
    assert_eq!(
        rig.orders()[0].state,
        OrderState::Done,
        "{:?}",
        rig.orders()
    );

    // What crossed the wire: enough to have carried the order, and none of
    // it readable.
    let bytes = capture.bytes();
    assert!(bytes.len() > 20_000, "captured only {} bytes", bytes.len());
    assert!(
        bytes
            .windows(control.len())
            .any(|w| w == control.as_bytes()),
        "the capture did not see the control text: it could not see a secret either"
    );
    let recipe = std::fs::read_to_string(rig.recipes.join("cell/dikdroog.rcp")).expect("recipe");
    let mut secrets: Vec<&str> = vec!["falc/falc1", "operator/api", "DROOG_DIK", "DIKDROOG"];
    secrets.extend(questions.iter().map(|q| q.as_str()));
    secrets.extend(recipe.lines().filter(|l| l.len() > 20));
    for secret in secrets {
        let needle = secret.as_bytes();
        assert!(
            !bytes.windows(needle.len()).any(|w| w == needle),
            "`{secret}` crossed the bridge in clear"
        );
    }
    println!(
        "captured {} bytes on the bridge: no recipe text, question, answer or key in clear",
        bytes.len()
    );

    for (host, cut) in [("welding", 3), ("transport", 3), ("welding", 30)] {
        // The first order is cut, the second runs after the way back.
        rig.cell.falc(&["order", "add", "dikdroog"]);
        rig.cell.falc(&["order", "add", "dundroog"]);
        rig.rcm.forget("rx G");
        rig.cell.falc(&["start"]);
        rig.until_welding();
        let hosts = rig.cell.hosts.as_ref().expect("hosts");
        hosts.cut(host);
        let noticed = alarm_of(&rig, host, Duration::from_secs(5));
        std::thread::sleep(Duration::from_secs(cut).saturating_sub(noticed));
        let hosts = rig.cell.hosts.as_ref().expect("hosts");
        hosts.mend(host);
        let back = all_back(&rig, Duration::from_secs(30));
        println!(
            "{host} cut for {cut} s mid-order: alarm after {} ms, back {} ms after the link was mended",
            noticed.as_millis(),
            back.as_millis()
        );
        let orders = rig.orders();
        let cut_order = &orders[orders.len() - 2];
        assert_eq!(cut_order.state, OrderState::Failed, "{orders:?}");
        rig.way_back();
        let orders = rig.orders();
        assert_eq!(
            orders.last().map(|o| o.state),
            Some(OrderState::Done),
            "after {host} cut for {cut} s: {orders:?}"
        );
    }
}
