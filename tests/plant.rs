//! A plant: the factory router and a router per cell (real `falc-router`
//! processes joined by zenoh's own router-to-router links), demo stations
//! in two cells, and sessions of this test process as the operator, as
//! stations of either cell and as a cell router. The hierarchy holds
//! across routers, nothing of one cell reaches another, and a cell router
//! links up again by itself.

use crate::support::plant::TestPlant;
use crate::support::st;
use crate::support::wait::{wait_until_async, POLL};
use falc_bus::{Bus, DEFAULT_DEADLINE};
use falc_model::mms::error::ServiceError;
use falc_model::mms::pdu::{Request, Response};
use std::time::{Duration, Instant};

async fn status(bus: &Bus, station: &str) -> Result<Response, ServiceError> {
    bus.request(&st(station), &Request::Status, DEFAULT_DEADLINE)
        .await
}

async fn refused(bus: &Bus, station: &str, what: &str) {
    let r = status(bus, station).await;
    assert!(matches!(&r, Err(e) if e.is_unreachable()), "{what}: {r:?}");
}

/// A probe's payload: a sample sent until the subscribers hear them, not
/// counted by [`heard`].
const PROBE: u8 = 255;

/// Every sample but probes `sub` receives within `wait`.
async fn heard(
    sub: zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
    wait: Duration,
) -> usize {
    let mut n = 0;
    let end = tokio::time::Instant::now() + wait;
    while let Ok(Ok(s)) = tokio::time::timeout_at(end, sub.recv_async()).await {
        if s.payload().to_bytes().as_ref() != [PROBE] {
            n += 1;
        }
    }
    n
}

/// Every liveliness token `bus` sees under `key`.
async fn tokens(bus: &Bus, key: &str) -> Vec<String> {
    let replies = bus
        .session()
        .liveliness()
        .get(key)
        .timeout(Duration::from_secs(1))
        .await
        .expect("liveliness get");
    let mut v = Vec::new();
    while let Ok(r) = replies.recv_async().await {
        if let Ok(s) = r.result() {
            v.push(s.key_expr().to_string());
        }
    }
    v
}

/// The operator commands each cell controller through the factory router
/// and that cell's router; a cell's controller associates its own
/// workstation there. Cell 1's welding credentials reach nothing of cell 2
/// (neither through its own router nor at cell 2's or the factory's), nor
/// the operator API; cell 1's router's credentials reach nothing of
/// cell 2 at the factory router.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_hierarchy_holds_across_routers_and_no_cell_reaches_another() {
    let plant = TestPlant::start();
    let _stations = [
        plant.demo_station("falc1", "cell"),
        plant.demo_station("falc1", "welding"),
        plant.demo_station("falc2", "cell"),
        plant.demo_station("falc2", "transport"),
    ];
    for cell in ["falc1", "falc2"] {
        let op = plant.operator_in(cell).await;
        let r = op
            .request(
                &st("cell"),
                &Request::Initiate {
                    calling: op.me().clone(),
                },
                DEFAULT_DEADLINE,
            )
            .await;
        assert!(
            matches!(r, Ok(Response::Initiate { .. })),
            "{cell}: the operator associates the cell (and it its workstation): {r:?}"
        );
        assert!(
            matches!(status(&op, "cell").await, Ok(Response::Status(_))),
            "{cell}"
        );
        let ws = if cell == "falc1" {
            "welding"
        } else {
            "transport"
        };
        refused(
            &op,
            ws,
            "the operator skips no level, across routers either",
        )
        .await;
        let alive = tokens(&op, &format!("falc/{cell}/alive/{ws}/*")).await;
        assert!(
            alive.iter().any(|k| k.contains(&format!("/alive/{ws}/"))),
            "{cell}: the operator watches every station of the cell: {alive:?}"
        );
        op.session().close().await.expect("close");
    }

    // Cell 1's welding credentials, at its own router, in cell 2's keys.
    let router1 = plant.cell_router("falc1");
    let router2 = plant.cell_router("falc2");
    let foreign = plant
        .station_at("falc1", "welding", &router1, "falc2")
        .await
        .expect("welding logs in at its own router");
    for target in ["cell", "transport", "operator"] {
        refused(
            &foreign,
            target,
            &format!("cell 1's welding → cell 2's {target}"),
        )
        .await;
    }
    for key in [
        "falc/falc2/cell/svc/status",
        "falc/falc2/transport/svc/start",
        "falc/falc2/**",
        "falc/plant/operator/api/status/welding",
        "falc/plant/operator/api/status/console",
    ] {
        let replies = foreign
            .session()
            .get(key)
            .timeout(Duration::from_secs(1))
            .await
            .expect("get");
        assert!(
            replies.recv_async().await.is_err(),
            "cell 1's welding got a reply on {key}"
        );
    }
    // (Its own token, declared in cell 2's keys, is its session's own:
    // the router never took it.)
    let seen: Vec<String> = tokens(&foreign, "falc/falc2/**")
        .await
        .into_iter()
        .filter(|k| !k.contains("/alive/welding/"))
        .collect();
    assert!(
        seen.is_empty(),
        "cell 2's stations seen from cell 1: {seen:?}"
    );
    // Cell 2's transport publishes; the operator hears it across the
    // routers, cell 1's welding does not.
    let op2 = plant.operator_in("falc2").await;
    let subscribe = |bus: &Bus, key: &'static str| {
        let session = bus.session().clone();
        async move { session.declare_subscriber(key).await.expect("subscriber") }
    };
    let op_sub = subscribe(&op2, "falc/falc2/transport/status").await;
    let foreign_sub = subscribe(&foreign, "falc/falc2/**").await;
    let transport2 = plant
        .station_at("falc2", "transport", &router2, "falc2")
        .await
        .expect("transport logs in at its router");
    // Probes until the operator hears one: the subscriptions went round
    // the routers.
    wait_until_async(
        "the operator hears cell 2's transport",
        Duration::from_secs(10),
        || async {
            transport2
                .session()
                .put("falc/falc2/transport/status", vec![PROBE])
                .await
                .expect("put");
            match tokio::time::timeout(POLL, op_sub.recv_async()).await {
                Ok(Ok(_)) => Ok(()),
                other => Err(format!("{other:?}")),
            }
        },
    )
    .await;
    let listen_op = tokio::spawn(heard(op_sub, Duration::from_secs(3)));
    let listen_foreign = tokio::spawn(heard(foreign_sub, Duration::from_secs(3)));
    for i in 0..5 {
        transport2
            .session()
            .put("falc/falc2/transport/status", vec![i])
            .await
            .expect("put");
    }
    assert_eq!(listen_op.await.expect("task"), 5, "the operator hears all");
    assert_eq!(listen_foreign.await.expect("task"), 0, "cell 1 hears none");

    // Cell 1's welding credentials at cell 2's router and at the factory
    // router: no session at all.
    for (endpoint, which) in [
        (&router2, "cell 2's router"),
        (&plant.plant.router().to_string(), "the factory router"),
    ] {
        let r = plant
            .station_at("falc1", "welding", endpoint, "falc2")
            .await;
        assert!(r.is_err(), "cell 1's welding logged in at {which}");
    }

    // Cell 1's router's credentials as a client of the factory router:
    // nothing of cell 2, nor the operator API.
    let rogue = Bus::open(plant.settings(
        "router-falc1",
        "router-falc1.toml",
        plant.plant.router(),
        "falc2",
    ))
    .await
    .expect("a cell router's user may log in at the factory router");
    refused(&rogue, "cell", "router-falc1 → cell 2's controller").await;
    refused(
        &rogue,
        "operator",
        "router-falc1 → cell 2's operator services",
    )
    .await;
    let seen: Vec<String> = tokens(&rogue, "falc/falc2/**")
        .await
        .into_iter()
        .filter(|k| !k.contains("/alive/router-falc1/"))
        .collect();
    assert!(
        seen.is_empty(),
        "cell 2's stations seen by router-falc1: {seen:?}"
    );
    let replies = rogue
        .session()
        .get("falc/plant/operator/api/status/console")
        .timeout(Duration::from_secs(1))
        .await
        .expect("get");
    assert!(replies.recv_async().await.is_err());
}

/// A session that claims the factory router's zenoh id at a cell router
/// (the id by which the cell router's access control knows its link up)
/// gets no session: while the link is up zenoh refuses a second transport
/// of that id; while it is cut the cell router closes it at once and names
/// it. The real link comes back untouched.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_session_claiming_the_factory_routers_id_is_closed() {
    let mut plant = TestPlant::start();
    let _cell = plant.demo_station("falc1", "cell");
    let router1 = plant.cell_router("falc1");
    let id = falc_bus::config::factory_router_id(plant.plant.name());
    let settings = plant.settings("welding", "falc1/welding.toml", &router1, "falc1");
    let forge = || {
        let mut cfg = falc_bus::config::client(
            &settings.endpoint,
            settings.lease,
            settings.credentials.as_ref(),
            None,
            Duration::from_secs(2),
        )
        .expect("config");
        cfg.insert_json5("id", &format!("\"{id}\"")).expect("id");
        zenoh::open(cfg)
    };
    // While the link up is there.
    let forged = forge().await;
    assert!(
        forged.is_err(),
        "a second transport with the factory router's id was admitted"
    );
    // While it is cut.
    let mut factory = plant.routers.pop().expect("the factory router");
    factory.kill();
    drop(factory);
    // Refused as a second transport of that id until the cell router
    // noticed the cut; then admitted by zenoh and closed by FALC, named.
    let closed_line = format!("(zenoh id {id}) closed");
    let forged = std::cell::RefCell::new(Vec::new());
    let cell_router = std::cell::RefCell::new(&mut plant.routers[0]);
    let line = wait_until_async(
        "the cell router closes the forged session and names it",
        plant.plant.lease() * 3 + Duration::from_secs(5),
        || {
            let (forged, cell_router, closed_line) = (&forged, &cell_router, &closed_line);
            async move {
                let attempt = forge().await;
                forged.borrow_mut().push(attempt);
                let closed = cell_router.borrow_mut().wait_line(closed_line, POLL);
                closed.ok_or("no close logged")
            }
        },
    )
    .await;
    assert!(line.contains(&id) && line.contains("as welding"), "{line}");
    for s in forged.into_inner().into_iter().flatten() {
        wait_until_async(
            "the forged session disconnected",
            Duration::from_secs(5),
            || async {
                let routers = s.info().routers_zid().await.count();
                if routers == 0 {
                    Ok(())
                } else {
                    Err(routers)
                }
            },
        )
        .await;
        let _ = s.close().await;
    }
    // The real link comes back, and the operator commands the cell.
    plant.routers.push(plant.router(None));
    let op = plant.operator_in("falc1").await;
    wait_until_async("cell 1 reached again", Duration::from_secs(15), || async {
        match status(&op, "cell").await {
            Ok(Response::Status(_)) => Ok(()),
            other => Err(other),
        }
    })
    .await;
}

/// The factory router stops and starts again: each cell router links up
/// again by itself, and the operator reaches every cell once more.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cell_router_links_up_again_by_itself() {
    let mut plant = TestPlant::start();
    let _stations = [
        plant.demo_station("falc1", "cell"),
        plant.demo_station("falc2", "cell"),
    ];
    let op = plant.operator_in("falc2").await;
    assert!(matches!(status(&op, "cell").await, Ok(Response::Status(_))));
    op.session().close().await.expect("close");
    let mut factory = plant.routers.pop().expect("the factory router");
    factory.kill();
    drop(factory);
    // Each cell router saw its link up close (its log says so).
    for router in &mut plant.routers {
        let closed = router.wait_line("link closed (the link up", plant.plant.lease() * 5);
        assert!(
            closed.is_some(),
            "a cell router did not log its link up's end"
        );
    }
    let started = Instant::now();
    plant.routers.push(plant.router(None));
    for cell in ["falc1", "falc2"] {
        let op = plant.operator_in(cell).await;
        wait_until_async(
            &format!("{cell} reached after the factory router came back"),
            Duration::from_secs(15),
            || async {
                match status(&op, "cell").await {
                    Ok(Response::Status(_)) => Ok(()),
                    other => Err(other),
                }
            },
        )
        .await;
        eprintln!(
            "{cell} reached {:?} after the factory router came back",
            started.elapsed()
        );
    }
}

/// Two whole cells (twins, workstations, cell controllers) under one
/// operator: four orders of one list run on both cells at once, each
/// started once; the plant's status shows each cell, `--cell` one cell.
#[test]
fn two_cells_work_through_one_order_list_in_parallel() {
    use crate::support::plant::whole_plant;
    use falc_model::records::OrderState;
    let plant = TestPlant::start_text(&whole_plant());
    let _one = plant.start_cell_nodes("falc1", "100");
    let _two = plant.start_cell_nodes("falc2", "100");
    let _operator = plant.start_operator();
    let out = plant.falc(None, &["order", "add", "dikdroog", "--count", "4"]);
    assert!(out.contains("4") && out.contains("dikdroog"), "{out}");
    let out = plant.falc(None, &["start"]);
    // Each cell takes one of the first two (whichever is ready first).
    assert!(
        out.lines().any(|l| l.starts_with("falc1: order "))
            && out.lines().any(|l| l.starts_with("falc2: order "))
            && out.contains("order 1 (dikdroog) started")
            && out.contains("order 2 (dikdroog) started"),
        "{out}"
    );
    let text = plant.falc(None, &["status"]);
    assert!(
        text.contains("falc1") && text.contains("falc2") && text.contains("list running"),
        "{text}"
    );
    let one = plant.falc(Some("falc2"), &["status"]);
    assert!(one.contains("list running; running order "), "{one}");
    let asked = plant.work_list("ja", Duration::from_secs(240));
    assert!(asked.iter().any(|(c, _)| c == "falc1") && asked.iter().any(|(c, _)| c == "falc2"));
    let orders = plant.orders();
    assert!(
        orders.iter().all(|o| o.state == OrderState::Done),
        "{orders:#?}"
    );
    let on = |cell: &str| {
        orders
            .iter()
            .filter(|o| o.cell.as_deref() == Some(cell))
            .count()
    };
    assert!(on("falc1") >= 1 && on("falc2") >= 1, "{orders:#?}");
    assert_eq!(on("falc1") + on("falc2"), 4);
    // In parallel: orders 1 and 2 ran at the same time.
    let span = |id: i64| {
        let o = orders.iter().find(|o| o.id == id).expect("order");
        (o.started_ms.unwrap_or(0), o.ended_ms.unwrap_or(0))
    };
    let ((s1, e1), (s2, e2)) = (span(1), span(2));
    assert!(
        s1 < e2 && s2 < e1,
        "orders 1 and 2 did not overlap: {orders:#?}"
    );
    // Each order started once, in the one journal.
    plant.assert_each_started_once(&orders);
}

/// A plant on the secure transport: every router on QUIC with mutual TLS
/// (one certificate authority for the plant, a certificate beside every
/// password, each cell's in its own directory). Both cells run an order;
/// cell 1's welding station, with its own certificate and password, logs
/// in neither at cell 2's router nor at the factory router.
#[test]
fn a_plant_on_the_secure_transport_runs_an_order_on_each_cell_and_keeps_cells_apart() {
    use crate::support::plant::whole_plant;
    use falc_model::records::OrderState;
    let plant = TestPlant::start_secure(&whole_plant());
    assert!(
        plant.plant.router().starts_with("quic/"),
        "{}",
        plant.plant.router()
    );
    let creds = plant.credentials_dir();
    for file in [
        "ca.crt",
        "operator.crt",
        "router-falc2.crt",
        "falc2/ca.crt",
        "falc2/welding.crt",
        "falc2/router.crt",
    ] {
        assert!(creds.join(file).exists(), "{file}");
    }
    let _one = plant.start_cell_nodes("falc1", "100");
    let _two = plant.start_cell_nodes("falc2", "100");
    let _operator = plant.start_operator();
    plant.falc(None, &["order", "add", "dikdroog", "--count", "2"]);
    let out = plant.falc(None, &["start"]);
    assert!(
        out.contains("falc1: order") && out.contains("falc2: order"),
        "{out}"
    );
    plant.work_list("ja", Duration::from_secs(120));
    let orders = plant.orders();
    assert!(
        orders.iter().all(|o| o.state == OrderState::Done),
        "{orders:#?}"
    );
    let cells: std::collections::BTreeSet<_> =
        orders.iter().filter_map(|o| o.cell.clone()).collect();
    assert_eq!(cells.len(), 2, "one order on each cell: {orders:#?}");
    plant.assert_each_started_once(&orders);
    let rt = tokio::runtime::Runtime::new().expect("runtime");
    rt.block_on(async {
        let foreign = plant
            .station_at("falc1", "welding", &plant.cell_router("falc2"), "falc2")
            .await;
        assert!(foreign.is_err(), "cell 1's welding at cell 2's router");
        let up = plant
            .station_at("falc1", "welding", plant.plant.router(), "falc1")
            .await;
        assert!(up.is_err(), "cell 1's welding at the factory router");
        // Its own router takes it.
        let own = plant
            .station_at("falc1", "welding", &plant.cell_router("falc1"), "falc1")
            .await;
        assert!(own.is_ok(), "{:?}", own.err());
    });
}

/// A robot's emergency stop in cell 2 mid-weld stops cell 2's list only:
/// cell 1 runs on and takes the next order; the failed order is not run
/// again. Cell 2's way back is its own: the stop released, its carriers
/// back, `ack` and `start` for cell 2, and the next order for it done.
#[test]
fn an_emergency_stop_in_one_cell_stops_that_cell_only_and_its_way_back_is_its_own() {
    use crate::support::plant::whole_plant;
    use falc_model::api::ListState;
    use falc_model::records::OrderState;
    let plant = TestPlant::start_text(&whole_plant());
    let _one = plant.start_cell_nodes("falc1", "100");
    let mut two = plant.start_cell_nodes("falc2", "10");
    let mut operator = plant.start_operator();
    plant.falc(None, &["order", "add", "dikdroog", "--cell", "falc2"]);
    plant.falc(None, &["order", "add", "dikdroog", "--count", "2"]);
    plant.falc(None, &["start"]);
    plant.until_welding(&mut two);
    two.rcm.control("estop");
    operator.expect_line(
        "EVENT order-ended id=1 state=failed",
        Duration::from_secs(10),
    );
    let status = plant.status();
    let state = |cell: &str| {
        status
            .cells
            .iter()
            .find(|(c, _)| c.as_str() == cell)
            .map(|(_, s)| s.clone())
            .expect("cell")
    };
    assert_eq!(state("falc2").list, ListState::Alarm, "{status:#?}");
    assert!(state("falc2")
        .alarm
        .as_deref()
        .is_some_and(|a| a.contains("emergency stop")));
    assert!(state("falc1").alarm.is_none(), "{status:#?}");
    // Cell 1 runs both other orders; cell 2 stays stopped.
    plant.work_list("ja", Duration::from_secs(120));
    let orders = plant.orders();
    let of = |id: i64| orders.iter().find(|o| o.id == id).expect("order").clone();
    assert_eq!(
        (of(1).state, of(1).cell.as_deref()),
        (OrderState::Failed, Some("falc2"))
    );
    for id in [2, 3] {
        assert_eq!(
            (of(id).state, of(id).cell.as_deref()),
            (OrderState::Done, Some("falc1")),
            "{orders:#?}"
        );
    }
    // `alarms` lists the plant's; `ack N` finds cell 2's alarm.
    let alarms = plant.falc(None, &["alarms"]);
    assert!(
        alarms
            .lines()
            .any(|l| l.starts_with("falc2") && l.contains("emergency stop")),
        "each alarm with its cell: {alarms}"
    );
    // Cell 2's way back: the stop released, carriers back, ack, start.
    two.rcm.control("estop-clear");
    two.plc.control("layout W2 W2");
    let out = plant.falc(Some("falc2"), &["ack"]);
    assert!(out.contains("emergency stop"), "{out}");
    plant.falc(None, &["order", "add", "dikdroog", "--cell", "falc2"]);
    let out = plant.falc(Some("falc2"), &["start"]);
    assert!(out.contains("order 4 (dikdroog) started"), "{out}");
    plant.work_list("ja", Duration::from_secs(120));
    let orders = plant.orders();
    let four = orders.iter().find(|o| o.id == 4).expect("order 4");
    assert_eq!(
        (four.state, four.cell.as_deref()),
        (OrderState::Done, Some("falc2"))
    );
    // Nothing ran twice.
    plant.assert_each_started_once(&orders);
}

/// The OPC UA gateway of a plant, driven by the independent client
/// (`tests/opcua_client.py plant`): the plant object `FALC` with its cells
/// and every order, and one object per cell with its own PackML state and
/// methods. An order added and started through cell 2's object runs on
/// cell 2 to done, while cell 1's object stays Idle.
#[test]
fn the_opcua_gateway_serves_the_plant_and_each_cell_with_its_own_state_and_methods() {
    use crate::support::opcua::{client_of, step};
    use falc_model::records::OrderState;
    let plant = TestPlant::start_text(&crate::support::plant::whole_plant());
    let _one = plant.start_cell_nodes("falc1", "100");
    let _two = plant.start_cell_nodes("falc2", "100");
    let _operator = plant.start_operator();
    let (_gateway, listen) = plant.start_gateway();
    let mut c = client_of(
        "plant",
        &format!("opc.tcp://{listen}/"),
        &plant.credentials_dir(),
        &plant.dir.path().join("opcua-client"),
        &["plant", "falc2", "falc1"],
    );
    let t = Duration::from_secs(60);
    let names = |v: &serde_json::Value| -> Vec<String> {
        v.as_array()
            .unwrap_or_else(|| panic!("not an array: {v}"))
            .iter()
            .filter_map(|s| s.as_str().map(str::to_string))
            .collect()
    };
    let b = step(&mut c, "browse", t);
    let (of_plant, of_cell) = (names(&b["plant"]), names(&b["cell"]));
    for n in [
        "falc1",
        "falc2",
        "Cells",
        "Orders",
        "OperatorReachable",
        "AddOrder",
        "Start",
    ] {
        assert!(of_plant.iter().any(|x| x == n), "{n} in {of_plant:?}");
    }
    for n in [
        "PackMLState",
        "Stations",
        "Orders",
        "Journal",
        "Alarms",
        "AddOrder",
        "Start",
        "Answer",
    ] {
        assert!(of_cell.iter().any(|x| x == n), "{n} in {of_cell:?}");
    }
    assert_eq!(names(&b["cells"]), ["falc1", "falc2"]);
    let s = step(&mut c, "subscribed", t);
    assert_eq!(s["first"]["FALC.falc2.PackMLState"], "Idle", "{s}");
    assert_eq!(s["first"]["FALC.falc1.PackMLState"], "Idle", "{s}");
    let added = step(&mut c, "added", t);
    let order: i64 = added["order"]
        .as_str()
        .and_then(|o| o.parse().ok())
        .unwrap_or_else(|| panic!("order id: {added}"));
    let q = step(&mut c, "question", Duration::from_secs(120));
    assert_eq!(q["asked"], true, "{q}");
    step(&mut c, "answered", t);
    let e = step(&mut c, "ended", Duration::from_secs(180));
    assert_eq!(e["order_state"], "done", "{e}");
    let states = names(&e["states"]);
    assert!(states.iter().any(|s| s == "Execute"), "{states:?}");
    assert_eq!(
        states.last().map(String::as_str),
        Some("Idle"),
        "{states:?}"
    );
    let p = step(&mut c, "plant", t);
    let other = names(&p["other_states"]);
    assert!(
        !other.is_empty() && other.iter().all(|s| s == "Idle"),
        "cell 1 stays Idle while cell 2 works: {other:?}"
    );
    assert_eq!(p["ids"], serde_json::json!([order]), "{p}");
    assert_eq!(names(&p["cells"]), ["falc2"], "{p}");
    // Each cell is a machine of OPC UA Machinery, idle again after the
    // order.
    assert_eq!(
        p["machines"],
        serde_json::json!({"falc1": "NotExecuting", "falc2": "NotExecuting"}),
        "{p}"
    );
    // Each cell's journal is its own: cell 2's holds its order's end,
    // cell 1's nothing of it.
    let done = format!("order {order} (dikdroog) done");
    assert!(
        names(&p["journal"]).iter().any(|t| t.contains(&done)),
        "{p}"
    );
    assert!(
        !names(&p["other_journal"]).iter().any(|t| t.contains(&done)),
        "{p}"
    );
    // The operator's view agrees: the order ran on cell 2 once.
    let orders = plant.orders();
    assert_eq!(orders.len(), 1, "{orders:#?}");
    assert_eq!(
        (
            orders[0].state,
            orders[0].cell.as_deref(),
            orders[0].wanted.as_deref()
        ),
        (OrderState::Done, Some("falc2"), Some("falc2"))
    );
    plant.assert_each_started_once(&orders);
}

/// A manufacturing execution system nobody here wrote (Python asyncua)
/// dispatches a job order to cell 2 of a plant by the standards alone:
/// OPC 40001-3 Job Management over OPC 10031-4 ISA-95 Job Control. The
/// job order runs as a FALC order carrying its JobOrderID, and its job
/// response names the recipe versions and workstation jobs of the order.
#[test]
fn a_foreign_mes_dispatches_an_isa95_job_order_to_cell_2_and_reads_its_response() {
    use crate::support::opcua::{client_of, step};
    use falc_model::records::OrderState;
    let plant = TestPlant::start_text(&crate::support::plant::whole_plant());
    let _one = plant.start_cell_nodes("falc1", "100");
    let _two = plant.start_cell_nodes("falc2", "100");
    let _operator = plant.start_operator();
    let (_gateway, listen) = plant.start_gateway();
    let job = "MES-4711";
    let mut c = client_of(
        "mes",
        &format!("opc.tcp://{listen}/"),
        &plant.credentials_dir(),
        &plant.dir.path().join("opcua-client"),
        &["falc2", job],
    );
    let t = Duration::from_secs(60);
    let s = step(&mut c, "stored", t);
    println!("stored: {s}");
    // The machine as the MES reads it.
    assert_eq!(
        s["machine"]["identification_is_machinery_type"], true,
        "{s}"
    );
    assert_eq!(
        s["machine"]["states"]["item"]["id_in_machinery"], true,
        "{s}"
    );
    // StoreAndStart took the job order: ReturnStatus 1, no error.
    assert_eq!(s["stored"], serde_json::json!(["Good", 1]), "{s}");
    // Refused, Uncertain with its ReturnStatus bit: the same id again
    // (unable to accept), an unknown one (unknown JobOrderID), an unknown
    // parameter (unable to accept); an observer is denied.
    assert_eq!(s["twice"], serde_json::json!(["Uncertain", 16]), "{s}");
    assert_eq!(s["unknown"], serde_json::json!(["Uncertain", 2]), "{s}");
    assert_eq!(s["wrong"], serde_json::json!(["Uncertain", 16]), "{s}");
    assert_eq!(s["observer"][0], "BadUserAccessDenied", "{s}");
    // The cell's operator answers its question; the job order ends.
    plant.answer_until(Duration::from_secs(240), "the job order's end", || {
        c.wait_line("\"step\": \"ended\"", Duration::ZERO).is_some()
    });
    let e = step(&mut c, "ended", t);
    println!("ended: {e}");
    let states: Vec<&str> = e["states"]
        .as_array()
        .unwrap_or_else(|| panic!("{e}"))
        .iter()
        .filter_map(|s| s.as_str())
        .collect();
    assert!(states.contains(&"Running"), "{states:?}");
    assert_eq!(states.last(), Some(&"Ended"), "{states:?}");
    // The job response: its state, its times, the cell as equipment, and
    // the order's recipe versions and workstation jobs.
    let r = &e["response"];
    assert_eq!(e["response_status"], serde_json::json!(["Good", 1]), "{e}");
    assert_eq!(r["JobOrderID"], job, "{e}");
    assert_eq!(r["JobState"][0]["StateText"], "Ended", "{e}");
    assert_eq!(r["JobState"][0]["StateNumber"], 5, "{e}");
    assert_eq!(r["EquipmentActuals"][0]["ID"], "falc2", "{e}");
    let data = r["JobResponseData"].to_string();
    for want in [
        "Recipe",
        "dikdroog",
        "RecipeVersion",
        "DIKDROOG",
        "Job",
        "Outcome",
        "done",
    ] {
        assert!(data.contains(want), "{want} in {data}");
    }
    assert_eq!(e["responses"][0]["JobOrderID"], job, "{e}");
    assert_eq!(e["listed"][0]["State"][0]["StateText"], "Ended", "{e}");
    // FALC's records name the MES's job order.
    let orders = plant.orders();
    assert_eq!(
        orders.len(),
        1,
        "only the one job order became an order: {orders:#?}"
    );
    let o = &orders[0];
    assert_eq!(
        (o.state, o.cell.as_deref(), o.job_order.as_deref()),
        (OrderState::Done, Some("falc2"), Some(job))
    );
    let shown = plant.falc(Some("falc2"), &["order", "show", &o.id.to_string()]);
    assert!(shown.contains(&format!("job order: {job}")), "{shown}");
    // Its result (OPC 40001-101): none before; the latest after, by id
    // too, with the job order, the recipe and its version, OK, and the
    // product record as content; sent as a ResultReadyEvent.
    assert_eq!(e["before"], serde_json::json!(["Good", -1]), "{e}");
    assert_eq!(e["latest"], serde_json::json!(["Good", 0]), "{e}");
    let meta = &e["result"]["ResultMetaData"];
    assert_eq!(meta["ResultId"], o.id.to_string(), "{e}");
    assert_eq!(meta["JobId"], job, "{e}");
    assert_eq!(meta["ExternalRecipeId"], "dikdroog", "{e}");
    assert!(
        meta["InternalRecipeId"]
            .as_str()
            .is_some_and(|v| v.starts_with("v1 ")),
        "{e}"
    );
    assert_eq!(meta["ResultEvaluation"], 1, "{e}");
    let content = e["result"]["ResultContent"].to_string();
    assert!(
        content.contains("DIKDROOG") && content.contains("DROOG_DIK"),
        "{content}"
    );
    assert_eq!(e["by_id"][1], 0, "{e}");
    assert_eq!(e["by_id"][2], e["result"], "{e}");
    assert_eq!(e["unknown_result"], serde_json::json!(["Good", -1]), "{e}");
    let events = e["events"].as_array().unwrap_or_else(|| panic!("{e}"));
    assert_eq!(events.len(), 1, "{e}");
    assert_eq!(
        events[0]["ResultMetaData"]["ResultId"],
        o.id.to_string(),
        "{e}"
    );
    plant.assert_each_started_once(&orders);
}

/// The plant's cells as `plant.status()` shows them: cell `cell`'s.
fn cell_status(plant: &TestPlant, cell: &str) -> falc_model::api::CellStatus {
    plant
        .status()
        .cells
        .into_iter()
        .find(|(c, _)| c.as_str() == cell)
        .map(|(_, s)| s)
        .unwrap_or_else(|| panic!("no cell {cell} in the plant's status"))
}

/// Three whole cells under one operator work through nine orders of one
/// list in parallel, each cell on a network of its own (a namespace, its
/// router on it; the factory router, the operator and the consoles on the
/// factory's, the cells' links up joined there by a bridge). A robot's
/// emergency stop in cell 2 stops cell 2 only; its way back is its own
/// (the stop released, carriers back, ack, start). Cell 3's link to the
/// factory is cut for 30 s mid-order (its bridge port down: nothing
/// passes, as a pulled cable): cell 3 runs its order on to
/// its end by its own recipe, the other cells run on, and when the link is
/// back the operator learns how the order ended. No order is lost, none
/// started twice; the journal says what happened.
#[test]
fn three_cells_run_nine_orders_through_an_estop_in_one_and_a_cut_uplink_of_another() {
    use crate::support::plant::plant_text;
    use falc_model::api::ListState;
    use falc_model::records::{Entry, OrderState};
    let whole: &[&str] = &["welding", "transport"];
    let text = plant_text(&[("falc1", whole), ("falc2", whole), ("falc3", whole)]);
    let plant = match TestPlant::start_in_namespaces(&text) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("NOT RUN: the plant on networks of its own needs root to create network namespaces and veth links: {e}");
            return;
        }
    };
    let hosts = plant.hosts.as_ref().expect("namespaces");
    let _one = plant.start_cell_nodes("falc1", "100");
    let mut two = plant.start_cell_nodes("falc2", "100");
    let mut three = plant.start_cell_nodes("falc3", "10");
    let mut operator = plant.start_operator();
    plant.falc(None, &["order", "add", "dikdroog", "--count", "9"]);
    let out = plant.falc(None, &["start"]);
    assert_eq!(
        out.matches(") started").count(),
        3,
        "one order per cell: {out}"
    );

    // Cell 3 mid-weld: its link up is cut.
    plant.until_welding(&mut three);
    let cut_order = cell_status(&plant, "falc3")
        .running
        .expect("cell 3 runs an order")
        .id;
    hosts.cut("falc3");
    let cut = Instant::now();
    three.cell.expect_line(
        "EVENT abort-indication peer=operator",
        Duration::from_secs(10),
    );
    plant.answer_until(Duration::from_secs(10), "cell 3 seen lost", || {
        !cell_status(&plant, "falc3").cell_associated
    });
    eprintln!("cell 3 lost {:?} after the cut", cut.elapsed());

    // Meanwhile an emergency stop in cell 2, mid-weld.
    two.rcm.forget("rx G");
    plant.until_welding(&mut two);
    two.rcm.control("estop");
    plant.answer_until(Duration::from_secs(15), "cell 2's alarm", || {
        cell_status(&plant, "falc2").list == ListState::Alarm
    });
    // Cell 1 runs on through the cut (orders end there meanwhile).
    let done_on_one = |plant: &TestPlant| {
        plant
            .orders()
            .iter()
            .filter(|o| o.cell.as_deref() == Some("falc1") && o.state == OrderState::Done)
            .count()
    };
    let before = done_on_one(&plant);
    plant.answer_until(Duration::from_secs(60), "cell 1 running on", || {
        done_on_one(&plant) > before
    });
    // The order of the cut cell is neither failed nor done while cut.
    let during: Vec<_> = plant.orders();
    let o = during.iter().find(|o| o.id == cut_order).expect("order");
    assert_eq!(o.state, OrderState::Running, "{during:#?}");
    // Acknowledged while cut (the alarm stays until the cell is back), a
    // start is still refused: the order's end is not known.
    let out = plant.falc(Some("falc3"), &["ack"]);
    assert!(out.contains("no connection with station cell"), "{out}");
    let (code, out) = plant.falc_as("console", Some("falc3"), &["start"]);
    assert_ne!(
        code, 0,
        "start of a cell whose order's end is unknown: {out}"
    );
    assert!(out.contains("not known yet"), "{out}");

    // The link back after 30 s: the order's true end is learned.
    let left = Duration::from_secs(30).saturating_sub(cut.elapsed());
    plant.answer_until(left + Duration::from_secs(1), "30 s", || {
        cut.elapsed() >= Duration::from_secs(30)
    });
    hosts.mend("falc3");
    let mended = Instant::now();
    plant.answer_until(Duration::from_secs(90), "the cut order's end", || {
        plant
            .orders()
            .iter()
            .any(|o| o.id == cut_order && o.state != OrderState::Running)
    });
    eprintln!(
        "cell 3's order {cut_order} known {:?} after the link came back",
        mended.elapsed()
    );
    let orders = plant.orders();
    let o = orders.iter().find(|o| o.id == cut_order).expect("order");
    assert_eq!(
        (o.state, o.cell.as_deref()),
        (OrderState::Done, Some("falc3")),
        "the cell ran its order on to its end: {orders:#?}"
    );
    operator.expect_line(
        &format!("EVENT order-ended id={cut_order} state=done"),
        Duration::from_secs(1),
    );
    assert!(cell_status(&plant, "falc3").cell_associated);

    // Each cell's way back: cell 2 (its stop released, carriers back, ack)
    // and cell 3 (its alarm acknowledged above, its connection back) start.
    two.rcm.control("estop-clear");
    two.plc.control("layout W2 W2");
    let out = plant.falc(Some("falc2"), &["ack"]);
    assert!(out.contains("emergency stop"), "{out}");
    // (Cell 2's failed order is never run again: an order for each of
    // cells 2 and 3 shows its way back to production, whatever the others
    // took.)
    for cell in ["falc2", "falc3"] {
        plant.falc(None, &["order", "add", "dikdroog", "--cell", cell]);
    }
    for cell in ["falc2", "falc3"] {
        let (code, out) = plant.falc_as("console", Some(cell), &["start"]);
        assert!(
            code == 0 || out.contains("holds no queued order"),
            "{cell}: {out}"
        );
    }
    plant.work_list("ja", Duration::from_secs(150));
    let orders = plant.orders();
    assert_eq!(orders.len(), 11);
    let failed: Vec<_> = orders
        .iter()
        .filter(|o| o.state != OrderState::Done)
        .collect();
    assert!(
        matches!(failed.as_slice(), [o] if o.state == OrderState::Failed && o.cell.as_deref() == Some("falc2")),
        "all done but cell 2's stopped order: {orders:#?}"
    );
    for cell in ["falc1", "falc2", "falc3"] {
        assert!(
            orders
                .iter()
                .any(|o| o.cell.as_deref() == Some(cell) && o.state == OrderState::Done),
            "{cell} did an order: {orders:#?}"
        );
    }
    // Cell 3 back in production: the order added for it after the way
    // back ran there to done.
    let last = orders.iter().max_by_key(|o| o.id).expect("orders");
    assert_eq!(
        (last.state, last.cell.as_deref()),
        (OrderState::Done, Some("falc3")),
        "{orders:#?}"
    );
    plant.assert_each_started_once(&orders);
    let journal: Vec<Entry> = plant.reply(
        Some("falc3"),
        &["journal", "--order", &cut_order.to_string()],
    );
    let says = |what: &str| journal.iter().any(|e| e.text.contains(what));
    assert!(
        says("the connection with cell was lost while it ran")
            && says("ended at cell while the connection was lost"),
        "{journal:#?}"
    );
    // What the cell showed while cut off is not lost: shown once back.
    assert!(
        says("einde dikke plaat droog") && says("shown late"),
        "{journal:#?}"
    );
    // Every workstation job of the cut order has its start in the record,
    // those begun while the link was cut (the unload after the weld) read
    // back with the station's time (issue 41, finding 11).
    let record: falc_model::product::OrderRecord =
        plant.reply(Some("falc3"), &["order", "show", &cut_order.to_string()]);
    assert!(
        record.jobs.iter().any(|j| j.program == "UNLOAD")
            && record.jobs.iter().all(|j| j.started_ms.is_some()),
        "{:#?}",
        record.jobs
    );
}
