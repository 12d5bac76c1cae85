//! The hierarchy is enforced by the network: real `falc-router` with the
//! generated ACL and usrpwd authentication, real demo-station processes, and
//! sessions of this test process authenticated as each station in turn.

use crate::support::{st, TestCell};
use falc_bus::DEFAULT_DEADLINE;
use falc_model::envelope;
use falc_model::mms::pdu::{Request, Response, Unconfirmed};
use falc_model::mms::vmd::VmdStatus;
use std::collections::HashMap;
use std::time::Duration;

const STATIONS: [&str; 4] = ["operator", "cell", "welding", "transport"];
const WAIT: Duration = Duration::from_secs(10);

/// Every ordered pair of stations: Status is confirmed exactly when the
/// target is the caller's direct subordinate, and refused by the router
/// otherwise; operator communication only from the cell to the operator.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn commander_is_confirmed_and_every_forbidden_pair_refused() {
    let cell = TestCell::start();
    let _procs: Vec<_> = STATIONS.iter().map(|s| cell.demo_station(s)).collect();
    let mut buses = HashMap::new();
    for s in STATIONS {
        buses.insert(s, cell.bus(s).await.expect("authenticated session"));
    }
    let mut allowed_seen = 0;
    for caller in STATIONS {
        for target in STATIONS {
            if caller == target {
                continue;
            }
            let allowed = cell.topology.commander_of(&st(target)) == Some(&st(caller));
            let result = buses[caller]
                .request(&st(target), &Request::Status, DEFAULT_DEADLINE)
                .await;
            match (allowed, &result) {
                (true, Ok(Response::Status(_))) => allowed_seen += 1,
                (false, Err(e)) if e.is_unreachable() => {}
                _ => panic!("{caller} → {target} status: allowed={allowed}, got {result:?}"),
            }
        }
    }
    assert_eq!(
        allowed_seen, 3,
        "operator→cell, cell→welding, cell→transport"
    );

    // Operator communication: the cell may use the operator's output; the
    // workstations may not.
    let out = Request::Output {
        lines: vec!["staat blok 1 in de uitgangspositie ?".into()],
    };
    assert_eq!(
        buses["cell"]
            .request(&st("operator"), &out, DEFAULT_DEADLINE)
            .await,
        Ok(Response::Done)
    );
    for ws in ["welding", "transport"] {
        let r = buses[ws]
            .request(&st("operator"), &out, DEFAULT_DEADLINE)
            .await;
        assert!(
            matches!(&r, Err(e) if e.is_unreachable()),
            "{ws} → operator output: {r:?}"
        );
    }
    // A commander may not use its subordinates' keys for a service it does
    // not serve downward either: the cell's `input` key does not exist.
    let keys = buses["operator"].keys().clone();
    let input_key = keys.service(&st("cell"), falc_model::mms::pdu::ServiceName::Input);
    let r = buses["operator"]
        .request_bytes(
            &input_key,
            envelope::encode(&Request::Status),
            DEFAULT_DEADLINE,
            "x",
        )
        .await;
    assert!(matches!(&r, Err(e) if e.is_unreachable()), "{r:?}");
}

/// Wildcard queries are denied even where every concrete key is allowed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn wildcard_queries_are_refused() {
    let cell = TestCell::start();
    let _w = cell.demo_station("welding");
    let bus = cell.bus("cell").await.expect("session");
    let concrete = bus
        .keys()
        .service(&st("welding"), falc_model::mms::pdu::ServiceName::Status);
    let ok = bus
        .request_bytes(
            &concrete,
            envelope::encode(&Request::Status),
            DEFAULT_DEADLINE,
            "status",
        )
        .await;
    assert!(
        matches!(ok, Ok(Response::Status(_))),
        "control: the concrete key works: {ok:?}"
    );
    for wildcard in [
        "falc/falc1/welding/svc/*",
        "falc/falc1/welding/svc/**",
        "falc/falc1/*/svc/status",
        "falc/**",
    ] {
        let r = bus
            .request_bytes(
                wildcard,
                envelope::encode(&Request::Status),
                DEFAULT_DEADLINE,
                wildcard,
            )
            .await;
        assert!(
            matches!(&r, Err(e) if e.is_unreachable()),
            "{wildcard}: {r:?}"
        );
    }
}

/// Nobody publishes on another station's keys: the operator (who reads
/// everything) receives each station's own status and none of the forged
/// ones, which each station sends before its own on the same link.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn publishing_on_another_stations_status_is_refused() {
    let cell = TestCell::start();
    let operator = cell.bus("operator").await.expect("session");
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let mut subs = Vec::new();
    for s in STATIONS.iter().filter(|s| **s != "operator") {
        subs.extend(
            operator
                .subscribe(&st(s), tx.clone())
                .await
                .expect("subscribe"),
        );
    }
    for publisher in STATIONS {
        let bus = cell.bus(publisher).await.expect("session");
        // The subscriptions and this session's declarations are at the router.
        operator.sync_with_router().await.expect("sync");
        bus.sync_with_router().await.expect("sync");
        for victim in STATIONS.iter().filter(|v| **v != publisher) {
            // Well-formed: only the router's access control keeps it out.
            let forged = falc_model::mms::journal::Publication {
                stamp: None,
                message: Unconfirmed::Status {
                    station: st(victim),
                    status: VmdStatus::default(),
                },
            };
            let key = bus.keys().status(&st(victim));
            bus.session()
                .put(&key, envelope::encode(&forged))
                .await
                .expect("put sent");
        }
        if publisher == "operator" {
            continue; // nobody subscribes to the operator's own status here
        }
        bus.publish(&Unconfirmed::Status {
            station: st(publisher),
            status: VmdStatus::default(),
        })
        .await;
        let got = tokio::time::timeout(WAIT, rx.recv())
            .await
            .expect("own status arrives");
        match got.map(|p| p.message) {
            Some(Unconfirmed::Status { station, .. }) => {
                assert_eq!(station, st(publisher), "a forged status got through")
            }
            other => panic!("unexpected {other:?}"),
        }
    }
    // Absence needs a while to show: anything forged would be here by now.
    let more = tokio::time::timeout(Duration::from_millis(300), rx.recv()).await;
    assert!(more.is_err(), "something else arrived: {more:?}");
}

/// No credentials, a wrong password or an unknown user: no session at all.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nodes_without_valid_credentials_cannot_connect() {
    let cell = TestCell::start();
    let mut s = cell.settings("welding");
    assert!(
        cell.bus("welding").await.is_ok(),
        "control: valid credentials connect"
    );
    s.credentials = None;
    assert!(
        falc_bus::Bus::open(s.clone()).await.is_err(),
        "no credentials"
    );
    let mut wrong = cell.settings("welding");
    if let Some(c) = wrong.credentials.as_mut() {
        c.password.push('x');
    }
    assert!(falc_bus::Bus::open(wrong).await.is_err(), "wrong password");
    let mut stranger = cell.settings("welding");
    if let Some(c) = stranger.credentials.as_mut() {
        c.user = "painting".into();
    }
    assert!(falc_bus::Bus::open(stranger).await.is_err(), "unknown user");
}

/// A subordinate accepts one commander: a second session of the cell is
/// refused with an `initiate` error while the first is associated.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_commanders_initiate_is_refused() {
    let cell = TestCell::start();
    let mut welding = cell.demo_station("welding");
    let first = cell.bus("cell").await.expect("session");
    let second = cell.bus("cell").await.expect("session");
    let r1 = first
        .request(
            &st("welding"),
            &Request::Initiate {
                calling: first.me().clone(),
            },
            DEFAULT_DEADLINE,
        )
        .await;
    assert!(
        matches!(r1, Ok(Response::Initiate { ref responding }) if responding.station == st("welding")),
        "{r1:?}"
    );
    welding.expect_line("EVENT associated commander=cell", WAIT);
    let r2 = second
        .request(
            &st("welding"),
            &Request::Initiate {
                calling: second.me().clone(),
            },
            DEFAULT_DEADLINE,
        )
        .await;
    match r2 {
        Err(e) => {
            assert_eq!(e.class.class_name(), "initiate", "{e}");
            assert!(e.description.contains("already has a commander"), "{e}");
        }
        Ok(r) => {
            let l = welding.wait_line("abort", Duration::from_secs(1));
            panic!("second commander accepted: {r:?} {l:?}")
        }
    }
    // State-changing services need the association: the second session's
    // Start is refused, the first one's gets a definition error (no such PI).
    let start = Request::Start {
        name: falc_model::ids::ObjectName::new("X").expect("valid"),
        argument: String::new(),
    };
    let r = first
        .request(&st("welding"), &start, DEFAULT_DEADLINE)
        .await;
    assert!(
        matches!(&r, Err(e) if e.class.to_string() == "definition/object-undefined"),
        "{r:?}"
    );
}

/// The operator associates the cell, which associates its workstations
/// first. SIGKILL of the cell: the operator (its commander) gets an abort
/// indication, and both workstations (its subordinates) get one too.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigkill_gives_abort_indications_both_ways() {
    use falc_bus::station::{Station, StationEvent};
    use falc_model::mms::association::Role;
    let cell = TestCell::start();
    let mut cell_node = cell.demo_station("cell");
    let mut welding = cell.demo_station("welding");
    let mut transport = cell.demo_station("transport");
    let mut operator = Station::open(cell.settings("operator"), &cell.topology)
        .await
        .expect("operator station");
    let made = operator
        .associate_subordinates()
        .await
        .expect("tree associated");
    assert_eq!(made.len(), 1);
    // The workstations were associated before the cell confirmed.
    welding.expect_line("EVENT associated commander=cell", WAIT);
    transport.expect_line("EVENT associated commander=cell", WAIT);
    cell_node.expect_line("EVENT associated commander=operator", WAIT);

    cell_node.kill();
    let ev = tokio::time::timeout(WAIT, operator.next())
        .await
        .expect("abort indication in time");
    match ev {
        Some(StationEvent::Abort(a)) => {
            assert_eq!(a.role, Role::Subordinate);
            assert_eq!(a.peer.station, st("cell"));
        }
        other => panic!("expected an abort indication, got {other:?}"),
    }
    welding.expect_line("EVENT abort-indication role=Commander peer=cell", WAIT);
    transport.expect_line("EVENT abort-indication role=Commander peer=cell", WAIT);
    assert!(operator.associations().subordinate(&st("cell")).is_none());
}

/// If a workstation is down, the cell refuses the Initiate naming it, and
/// the workstation it had already associated is concluded again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn initiate_is_refused_when_a_workstation_is_down() {
    use falc_bus::station::Station;
    let cell = TestCell::start();
    let _cell_node = cell.demo_station("cell");
    let mut welding = cell.demo_station("welding");
    let mut operator = Station::open(cell.settings("operator"), &cell.topology)
        .await
        .expect("operator station");
    let err = operator
        .associate_subordinates()
        .await
        .expect_err("transport is down");
    assert!(
        err.description
            .contains("no connection with station transport"),
        "{err}"
    );
    welding.expect_line("EVENT associated commander=cell", WAIT);
    welding.expect_line("EVENT concluded commander=cell", WAIT);
}

/// Garbage, a wrong version and a request on the wrong key get an error
/// reply naming the problem; the server keeps serving.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn garbage_payload_gets_an_error_reply_and_the_server_keeps_serving() {
    let cell = TestCell::start();
    let _w = cell.demo_station("welding");
    let bus = cell.bus("cell").await.expect("session");
    let key = bus
        .keys()
        .service(&st("welding"), falc_model::mms::pdu::ServiceName::Status);
    let cases: [(&[u8], &str); 4] = [
        (b"\x00\xffgarbage", "envelope magic"),
        (b"FL\x09\x00", "version 9 is not supported"),
        (b"FL\x02\xff\xff\xff\xff\xff", "malformed message body"),
        (&[], "shorter than the 3-byte envelope header"),
    ];
    for (bytes, needle) in cases {
        match bus
            .request_bytes(&key, bytes.to_vec(), DEFAULT_DEADLINE, "garbage")
            .await
        {
            Err(e) => assert!(e.description.contains(needle), "{needle}: {e}"),
            Ok(r) => panic!("garbage accepted: {r:?}"),
        }
    }
    let wrong = bus
        .request_bytes(
            &key,
            envelope::encode(&Request::Identify),
            DEFAULT_DEADLINE,
            "x",
        )
        .await;
    assert!(
        matches!(&wrong, Err(e) if e.description.contains("identify request was sent to the status key")),
        "{wrong:?}"
    );
    let ok = bus
        .request(&st("welding"), &Request::Status, DEFAULT_DEADLINE)
        .await;
    assert!(
        matches!(ok, Ok(Response::Status(_))),
        "still serving: {ok:?}"
    );
}

/// A frozen node (SIGSTOP: its process alive, its socket open) is noticed
/// when the zenoh lease (1 s here) runs out: the commander gets an abort
/// indication, later than after a SIGKILL but within a few leases.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_frozen_subordinate_is_noticed_after_the_lease() {
    use falc_bus::BusEvent;
    use nix::sys::signal::{kill, Signal};
    use nix::unistd::Pid;
    let cell = TestCell::start();
    let welding = cell.demo_station("welding");
    let bus = cell.bus("cell").await.expect("session");
    let peer = match bus
        .request(
            &st("welding"),
            &Request::Initiate {
                calling: bus.me().clone(),
            },
            DEFAULT_DEADLINE,
        )
        .await
    {
        Ok(Response::Initiate { responding }) => responding,
        other => panic!("{other:?}"),
    };
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let _watch = bus.watch(&peer, tx).await.expect("watch");
    let pid = Pid::from_raw(welding.pid() as i32);
    let t = std::time::Instant::now();
    kill(pid, Signal::SIGSTOP).expect("SIGSTOP");
    let got = tokio::time::timeout(Duration::from_secs(10), rx.recv()).await;
    let _ = kill(pid, Signal::SIGCONT);
    match got {
        Ok(Some(BusEvent::PeerLost { .. })) => {
            let after = t.elapsed();
            assert!(
                after >= Duration::from_millis(500),
                "noticed too early to be the lease: {after:?}"
            );
            eprintln!("frozen subordinate noticed after {after:?} (lease 1 s)");
        }
        other => panic!("no abort indication for a frozen node: {other:?}"),
    }
}
