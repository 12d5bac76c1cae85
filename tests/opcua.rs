//! The OPC UA gateway driven by an independent client: Python asyncua
//! (`tests/opcua_client.py`, installed by `.ci/run`) against `falc-opcua`
//! started by the launcher with the all-in-one cell. Every step the client
//! takes is a JSON line this test asserts on: an unknown client certificate
//! refused until admitted, the address space browsed, the robot's
//! emergency stop seen as an alarm event and acknowledged through the
//! Acknowledge method, then the way back (AddOrder dikdroog, Start, Answer
//! "ja") to done and the PackML state back to Idle; the observer reads but
//! every method refuses it, a wrong password and an anonymous session are
//! refused.

use crate::support::opcua::{client, step};
use crate::support::{free_port, LaunchedCell};
use serde_json::Value;
use std::time::Duration;

fn strings(v: &Value) -> Vec<String> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|s| s.as_str().map_or_else(|| s.to_string(), str::to_string))
        .collect()
}

#[test]
fn a_plant_client_browses_subscribes_and_runs_dikdroog_over_opcua() {
    let port = free_port();
    let listen = format!("127.0.0.1:{port}");
    let mut cell = LaunchedCell::start_with("50", &["--opcua", &listen]);
    let url = format!("opc.tcp://{listen}/");
    let mut c = client(&cell, "scenario", &url, &[]);
    let t = Duration::from_secs(60);

    // What the gateway keeps is private: its users, its key.
    let creds = cell.dir.path().join("credentials");
    let mode = |p: &str| {
        use std::os::unix::fs::PermissionsExt;
        std::fs::metadata(creds.join(p))
            .unwrap_or_else(|e| panic!("{p}: {e}"))
            .permissions()
            .mode()
            & 0o777
    };
    assert_eq!(mode("opcua-users.toml"), 0o600);
    assert_eq!(mode("opcua-pki"), 0o700);
    assert_eq!(mode("opcua-pki/private/private.pem"), 0o600);

    let s = step(&mut c, "untrusted", t);
    assert_eq!(s["refused"], "BadCertificateUntrusted", "{s}");
    let s = step(&mut c, "admitted", t);
    assert_eq!(s["files"], 1, "{s}");

    let b = step(&mut c, "browse", t);
    let cell_nodes = strings(&b["cell"]);
    for n in [
        "PackMLState",
        "PackMLStateCode",
        "Mode",
        "RunningOrder",
        "CellProgram",
        "CellRecipeState",
        "Question",
        "Orders",
        "Journal",
        "Alarms",
        "Stations",
        "AddOrder",
        "RemoveOrder",
        "Start",
        "Stop",
        "Acknowledge",
        "Answer",
    ] {
        assert!(cell_nodes.iter().any(|x| x == n), "{n} in {cell_nodes:?}");
    }
    assert_eq!(
        strings(&b["stations"]),
        ["cell", "operator", "transport", "welding"]
    );
    assert!(
        strings(&b["welding"]).contains(&"RobotState".to_string()),
        "{b}"
    );
    assert!(
        strings(&b["transport"]).contains(&"LitInputs".to_string()),
        "{b}"
    );

    let s = step(&mut c, "subscribed", t);
    assert_eq!(s["first"]["FALC.PackMLState"], "Idle", "{s}");
    // The thesis' recipe state of each station, as falc status shows it.
    let recipe = s["first"]["FALC.Stations.cell.RecipeStatus"]
        .as_str()
        .unwrap_or_default();
    assert!(
        ["IDLE", "LOADED", "READY"].contains(&recipe),
        "the cell's RecipeStatus at rest: {s}"
    );

    // An alarm: the robot's emergency stop, seen as an event.
    step(&mut c, "listening", t);
    cell.launcher.send("rcm estop");
    cell.launcher
        .expect_line("[rcm-welding] ok estop", Duration::from_secs(10));
    let r = step(&mut c, "raised", t);
    let event = r["event"]
        .as_str()
        .unwrap_or_else(|| panic!("no event: {r}"));
    assert!(event.contains("welding"), "{r}");
    assert!(
        !r["alarm"].as_str().unwrap_or_default().is_empty(),
        "the Alarm value names it: {r}"
    );
    cell.launcher.send("rcm estop-clear");
    cell.launcher
        .expect_line("[rcm-welding] ok estop-clear", Duration::from_secs(10));
    c.send("released");
    let a = step(&mut c, "acknowledged", t);
    assert!(
        a["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("alarm acknowledged") && e.contains("welding")),
        "{a}"
    );
    assert_eq!(a["alarm"], "", "nothing holds start back: {a}");

    // A refused method's words are in LastRefusal as it returns.
    let r = step(&mut c, "refusals", t);
    for (i, name) in ["nosuch_a", "nosuch_b"].iter().enumerate() {
        let one = &r["refusals"][i];
        assert_eq!(one["code"], "BadInvalidArgument", "{r}");
        assert!(
            one["last"].as_str().is_some_and(|l| l.contains(name)),
            "LastRefusal names {name} at once: {r}"
        );
    }

    // The way back: an order through the methods, to done.
    let added = step(&mut c, "added", t);
    let order = added["order"].as_str().expect("order id").to_string();
    let q = step(&mut c, "question", Duration::from_secs(120));
    assert_eq!(q["asked"], true, "{q}");
    assert!(
        q["question"]
            .as_str()
            .unwrap_or_default()
            .contains("(ja/nee)"),
        "{q}"
    );
    let a = step(&mut c, "answered", t);
    assert_eq!(a["reply"], "answered ja", "{a}");
    let e = step(&mut c, "ended", Duration::from_secs(180));
    assert_eq!(e["ended"], true, "{e}");
    assert_eq!(e["order_state"], "done", "{e}");
    let states = strings(&e["states"]);
    for s in ["Execute", "Held"] {
        assert!(states.contains(&s.to_string()), "{s} in {states:?}");
    }
    assert_eq!(
        states.last().map(String::as_str),
        Some("Idle"),
        "{states:?}"
    );
    assert!(
        e["recipe_states"].as_array().is_some_and(|v| v.len() > 3),
        "the cell recipe's state moved: {e}"
    );

    let j = step(&mut c, "journal", t);
    let texts = strings(&j["texts"]);
    assert!(
        texts
            .iter()
            .any(|t| t.contains(&format!("order {order} (dikdroog) done"))),
        "{texts:?}"
    );
    let who = strings(&j["who"]);
    assert!(
        who.iter().any(|w| w == "opcua"),
        "actions name the gateway: {who:?}"
    );

    let o = step(&mut c, "observer", t);
    assert_eq!(o["state"], "Idle", "{o}");
    assert_eq!(o["user_executable"], false, "{o}");
    assert_eq!(o["start_refused"], "BadUserAccessDenied", "{o}");
    assert_eq!(o["write_refused"], "BadServiceUnsupported", "{o}");
    let w = step(&mut c, "wrong_password", t);
    assert_eq!(w["refused"], "BadUserAccessDenied", "{w}");
    let n = step(&mut c, "anonymous", t);
    assert!(
        n["refused"].as_str().is_some_and(|r| r.starts_with("Bad")),
        "{n}"
    );

    // The operator's view agrees, and no order ran twice.
    let (code, list) = cell.falc_as("observer", &["order", "list"]);
    assert_eq!(code, 0, "{list}");
    assert_eq!(list.lines().count(), 1, "{list}");
    assert!(list.contains("done"), "{list}");
}

/// A gateway of the test's own beside the launched cell's, with the users
/// file `users` and `extra` arguments, ready; the client script doing
/// `what` (with its arguments) against it; and where it listens.
fn own_gateway(
    cell: &LaunchedCell,
    users: &str,
    extra: &[&str],
    (what, args): (&str, &[&str]),
    within: Duration,
) -> (crate::support::Proc, crate::support::Proc, String) {
    let own = cell.dir.path().join("gateway");
    falc_bus::credentials::private_dir(&own).expect("dir");
    let file = own.join("opcua-users.toml");
    falc_bus::credentials::write_private(&file, users).expect("users file");
    let listen = format!("127.0.0.1:{}", free_port());
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_falc-opcua"));
    cmd.args(cell.falc_args("opcua"))
        .args(["--listen", &listen])
        .args(extra)
        .arg("--users")
        .arg(&file)
        .arg("--pki-dir")
        .arg(own.join("opcua-pki"));
    let mut gateway = crate::support::Proc::spawn_logged("falc-opcua", cmd);
    gateway.expect_line("EVENT ready", within);
    let client = crate::support::opcua::client_of(
        what,
        &format!("opc.tcp://{listen}/"),
        &own,
        &cell.dir.path().join("opcua-client"),
        args,
    );
    (gateway, client, listen)
}

#[test]
fn a_user_certificate_logs_in_as_its_user_and_role() {
    let cell = LaunchedCell::start("50");
    let t = Duration::from_secs(60);
    let mut made = client(&cell, "user-cert", "-", &[]);
    let der = step(&mut made, "user_cert", t)["der"]
        .as_str()
        .expect("path")
        .to_string();
    // A gateway of the test's own, whose users file names the certificate.
    let (mut gateway, mut c, _) = own_gateway(
        &cell,
        &format!(
            "[[user]]\nname = \"console\"\nrole = \"operator\"\npassword = \"console-secret\"\n\
             [[user]]\nname = \"scada\"\nrole = \"observer\"\ncertificate = \"{der}\"\n"
        ),
        &[],
        ("by-certificate", &[]),
        t,
    );
    let s = step(&mut c, "by_certificate", t);
    assert_eq!(s["state"], "Idle", "{s}");
    assert_eq!(s["start_refused"], "BadUserAccessDenied", "{s}");
    assert!(
        s["stranger_refused"]
            .as_str()
            .is_some_and(|r| r.starts_with("Bad")),
        "{s}"
    );
    let log = gateway.wait_line("authenticated by user certificate", t);
    assert!(log.is_some_and(|l| l.contains("scada")));
}

#[test]
fn the_gateway_rides_out_a_lost_operator_and_the_next_order_runs_through_it() {
    let t = Duration::from_secs(60);
    let mut rig = crate::support::rig::rig("50");
    let listen = format!("127.0.0.1:{}", free_port());
    let mut cmd = rig.cell.command("opcua", env!("CARGO_BIN_EXE_falc-opcua"));
    cmd.args(["--user", "opcua", "--listen", &listen, "--topology"])
        .arg(&rig.cell.topology_path)
        .arg("--credentials-dir")
        .arg(rig.cell.credentials_dir());
    let mut gateway = crate::support::Proc::spawn_logged("falc-opcua", cmd);
    gateway.expect_line("EVENT ready", t);
    let url = format!("opc.tcp://{listen}/");
    let creds = rig.cell.credentials_dir();
    let work = rig.cell.dir.path().join("opcua-client");
    let mut w = crate::support::opcua::client_of(
        "watch",
        &url,
        &creds,
        &work,
        &["FALC.OperatorReachable", "FALC.PackMLState"],
    );
    step(&mut w, "watching", t);
    let change =
        |node: &str, value: &str| format!("\"node\": \"FALC.{node}\", \"value\": \"{value}\"");
    w.take_line(&change("OperatorReachable", "True"), t);
    w.take_line(&change("PackMLState", "Idle"), t);

    // The operator node dies: subscribers are told, the gateway says so.
    rig.operator().kill();
    w.take_line(&change("OperatorReachable", "False"), t);
    w.take_line(&change("PackMLState", "Stopped"), t);
    gateway.expect_line("the operator API gave no reply", t);
    assert!(gateway.alive(), "the gateway runs on without the operator");

    // It comes back: so does the cell on OPC UA, by itself.
    rig.start_operator();
    w.take_line(&change("OperatorReachable", "True"), t);
    w.take_line(&change("PackMLState", "Idle"), t);
    gateway.expect_line("the operator answers again", t);

    // And the next order runs through the gateway to done.
    let mut o = crate::support::opcua::client_of("order", &url, &creds, &work, &[]);
    let e = step(&mut o, "ended", Duration::from_secs(180));
    assert_eq!(e["ended"], true, "{e}");
    assert_eq!(e["order_state"], "done", "{e}");
    let orders = rig.orders();
    assert_eq!(orders.len(), 1, "{orders:?}");
    assert_eq!(orders[0].state, falc_model::records::OrderState::Done);
    w.send("done");
}

/// A8: failed logins are throttled per client address: ten wrong
/// passwords for `console`, the first three answered at once, the next
/// ones only after a growing delay; then the address is locked (the right
/// password refused too, by the front) and logs in once the lockout is
/// over. The log names each refusal with the address, and the lock.
#[test]
fn failed_logins_are_slowed_then_locked_and_the_user_logs_in_after_the_lockout() {
    let cell = LaunchedCell::start("50");
    let t = Duration::from_secs(90);
    let (mut gateway, mut c, _) = own_gateway(
        &cell,
        "[[user]]\nname = \"console\"\nrole = \"operator\"\npassword = \"console-secret\"\n",
        &["--login-lockout-s", "3"],
        ("throttle", &["3"]),
        t,
    );
    let wrong = step(&mut c, "wrong", t);
    let ms: Vec<u64> = wrong["ms"]
        .as_array()
        .expect("ms")
        .iter()
        .filter_map(Value::as_u64)
        .collect();
    println!("ten wrong passwords answered after (ms): {ms:?}");
    assert!(
        wrong["refused"]
            .as_array()
            .is_some_and(|r| r.len() == 10 && r.iter().all(|r| r == "BadUserAccessDenied")),
        "{wrong}"
    );
    // Attempts 4 to 9 wait 0.25, 0.5, 1, 2, 4, 4 s more than the first.
    let base = ms[..3].iter().copied().max().unwrap_or(0);
    assert!(ms[3] >= base + 200, "{ms:?}");
    assert!(ms[7] >= base + 3_500 && ms[8] >= base + 3_500, "{ms:?}");
    assert!(ms[6] > ms[5] && ms[5] > ms[4] && ms[4] > ms[3], "{ms:?}");
    let locked = step(&mut c, "locked", t);
    println!("the right password while locked: {locked}");
    assert_eq!(
        locked["locked"], "BadUserAccessDenied",
        "the right password while locked is refused: {locked}"
    );
    assert_eq!(
        locked["after"],
        Value::Null,
        "logged in after the lockout: {locked}"
    );
    // The front refuses the locked address's connections, naming it.
    let line = gateway
        .wait_line("OPC UA client 127.0.0.1 refused: it failed 10 logins", t)
        .expect("the lock is logged");
    assert!(line.contains("refused for"), "{line}");
    let first = gateway
        .wait_line("refused: unknown user or wrong password (1 failed", t)
        .expect("the first failure is logged");
    assert!(first.contains("from 127.0.0.1"), "{first}");
    assert!(gateway
        .wait_line("OPC UA session authenticated", t)
        .is_some());
    // async-opcua writes an ERROR line of its own for each refused login:
    // rate-limited per call site (falc_node::library_log), one a window.
    let own = gateway.lines_containing("opcua_types::encoding: BadUserAccessDenied");
    println!("async-opcua's own refusal lines: {}", own.len());
    assert!((1..=2).contains(&own.len()), "{own:#?}");
}

/// A guesser locks out its own address, never the user: 300 wrong
/// passwords for `opcua` from a second loopback address (127.0.0.2) while
/// the real `opcua` logs in from 127.0.0.1 once a second. Each of the real
/// user's logins takes under a second; the guesser is slowed, then refused
/// by the front before any handshake, and its address is named in a few
/// log lines only. A third address holding the limit of connections open
/// is refused one more, with an OPC UA Error message saying why.
#[test]
fn a_guesser_from_one_address_never_locks_the_real_user_out_from_another() {
    let cell = LaunchedCell::start("50");
    let t = Duration::from_secs(180);
    let (mut gateway, mut c, listen) = own_gateway(
        &cell,
        "[[user]]\nname = \"opcua\"\nrole = \"operator\"\npassword = \"opcua-secret\"\n\
         [[user]]\nname = \"console\"\nrole = \"operator\"\npassword = \"console-secret\"\n",
        &[],
        ("siege", &["127.0.0.2", "300"]),
        t,
    );
    let s = step(&mut c, "siege", t);
    println!("siege: {s}");
    let attacker = s["attacker"].as_object().expect("attacker");
    let total: u64 = attacker.values().filter_map(Value::as_u64).sum();
    assert_eq!(total, 300, "{s}");
    assert_eq!(
        attacker.get("BadUserAccessDenied").and_then(Value::as_u64),
        Some(300),
        "every guess refused, by the server then by the front: {s}"
    );
    let ms: Vec<u64> = s["operator_ms"]
        .as_array()
        .expect("ms")
        .iter()
        .filter_map(Value::as_u64)
        .collect();
    assert_eq!(s["operator_failed"], serde_json::json!([]), "{s}");
    assert!(ms.len() >= 5, "{s}");
    assert!(
        ms.iter().all(|&m| m < 1_000),
        "every login within 1 s: {ms:?}"
    );
    let mut sorted = ms.clone();
    sorted.sort_unstable();
    println!(
        "the real user's {} logins during the siege: median {} ms, longest {} ms",
        ms.len(),
        sorted[sorted.len() / 2],
        sorted[sorted.len() - 1]
    );
    // Refused by the front once locked, and named a few times only.
    assert!(gateway
        .wait_line("OPC UA client 127.0.0.2 refused: it failed 10 logins", t)
        .is_some());
    let named = gateway.lines_containing("127.0.0.2");
    println!("log lines naming the guesser: {}", named.len());
    assert!((2..=6).contains(&named.len()), "{named:#?}");
    assert!(gateway.lines_containing("(address unknown)").is_empty());

    // A third address holding 10 connections open (the limit) is refused
    // an 11th before any handshake, told why in an OPC UA Error message.
    let refusal = held_open_then_one_more(&listen, "127.0.0.3", 10);
    assert_eq!(&refusal[..4], b"ERRF", "{refusal:?}");
    assert_eq!(
        refusal[8..12],
        0x807D_0000u32.to_le_bytes(),
        "BadTcpServerTooBusy"
    );
    let reason = String::from_utf8_lossy(&refusal[16..]);
    assert!(reason.contains("10 connections open"), "{reason}");
    assert!(gateway
        .wait_line(
            "OPC UA client 127.0.0.3 refused: it holds 10 connections open",
            t
        )
        .is_some());
}

/// Opens `n` TCP connections from `from` to the gateway at `listen`, held
/// open, then one more: what the gateway sends on that one.
fn held_open_then_one_more(listen: &str, from: &str, n: usize) -> Vec<u8> {
    use tokio::io::AsyncReadExt;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        let to: std::net::SocketAddr = listen.parse().expect("address");
        let open = || async {
            let s = tokio::net::TcpSocket::new_v4().expect("socket");
            s.bind(format!("{from}:0").parse().expect("source"))
                .expect("bind");
            s.connect(to).await.expect("connect")
        };
        let mut held = Vec::with_capacity(n);
        for _ in 0..n {
            held.push(open().await);
        }
        let mut over = open().await;
        let mut got = vec![0u8; 512];
        let len = tokio::time::timeout(Duration::from_secs(5), over.read(&mut got))
            .await
            .expect("answered within 5 s")
            .expect("read");
        got.truncate(len);
        drop(held);
        got
    })
}

/// Alarms & Conditions: the robot's emergency stop is an active,
/// unacknowledged `AlarmConditionType` condition of severity 1000 at a
/// subscribed client; a client that subscribes afterwards gets it by
/// ConditionRefresh; an observer's Acknowledge is refused, the operator's
/// acknowledges it in `falc alarms` (and a second is refused); released,
/// it is no longer retained; then an order runs to done.
#[test]
fn an_emergency_stop_is_a_condition_a_late_client_refreshes_and_the_operator_acknowledges() {
    let port = free_port();
    let listen = format!("127.0.0.1:{port}");
    let mut cell = LaunchedCell::start_with("50", &["--opcua", &listen]);
    let url = format!("opc.tcp://{listen}/");
    let mut c = client(&cell, "conditions", &url, &[]);
    let t = Duration::from_secs(60);

    step(&mut c, "listening", t);
    cell.launcher.send("rcm estop");
    cell.launcher
        .expect_line("[rcm-welding] ok estop", Duration::from_secs(10));
    let r = step(&mut c, "raised", t)["condition"].clone();
    println!("raised: {r}");
    assert_eq!(r["type"], "i=2915", "AlarmConditionType: {r}");
    assert_eq!(r["severity"], 1000, "a safety alarm: {r}");
    assert_eq!(r["class"], "Safety", "{r}");
    assert_eq!(r["source"], "welding", "{r}");
    assert_eq!(r["retain"], true, "{r}");
    assert_eq!(r["active"], true, "{r}");
    assert_eq!(r["acked"], false, "{r}");
    assert_eq!(r["active_text"], "Active", "{r}");
    let condition = r["condition"].as_str().expect("a ConditionId").to_string();
    assert!(condition.contains("s=FALC.Conditions."), "{condition}");

    let f = step(&mut c, "refreshed", t);
    println!("refreshed: {f}");
    assert_eq!(f["before"], 0, "nothing came before the refresh: {f}");
    assert_eq!(f["condition"]["condition"], condition.as_str(), "{f}");
    assert_eq!(f["condition"]["active"], true, "{f}");
    assert_eq!(f["condition"]["acked"], false, "{f}");
    let o = step(&mut c, "observer_ack", t);
    assert_eq!(o["refused"], "BadUserAccessDenied", "{o}");
    let (_, alarms) = cell.falc_as("observer", &["alarms"]);
    assert!(
        alarms.contains("needs ack"),
        "not acknowledged by the observer: {alarms}"
    );

    c.send("acknowledge");
    let a = step(&mut c, "acknowledged", t);
    println!("acknowledged: {a}");
    assert_eq!(a["refused"], Value::Null, "{a}");
    assert_eq!(a["condition"]["acked"], true, "{a}");
    assert_eq!(
        a["condition"]["active"], true,
        "the stop is still pressed: {a}"
    );
    assert_eq!(a["condition"]["retain"], true, "{a}");
    assert_eq!(a["again"], "BadConditionBranchAlreadyAcked", "{a}");
    let (_, alarms) = cell.falc_as("observer", &["alarms"]);
    assert!(
        alarms.contains("acknowledged by opcua"),
        "the operator's view: {alarms}"
    );

    // The way back: released, the condition is no longer retained, and
    // the next order runs to done.
    cell.launcher.send("rcm estop-clear");
    cell.launcher
        .expect_line("[rcm-welding] ok estop-clear", Duration::from_secs(10));
    c.send("released");
    let g = step(&mut c, "released", t);
    assert_eq!(g["condition"]["retain"], false, "{g}");
    assert_eq!(g["condition"]["active"], false, "{g}");
    let e = step(&mut c, "ended", Duration::from_secs(180));
    assert_eq!(e["order_state"], "done", "{e}");
}

/// The cell as a machine of OPC 40001-1 Machinery, found by a client by
/// browse names and type definitions in the DI and Machinery namespaces
/// (never by FALC's node ids): its Identification from the topology's
/// `[identification]` (the manufacturer left to its default, FALC's
/// version as its software revision), its MachineryItemState and
/// MachineryOperationMode following the cell's mode and state.
#[test]
fn the_cell_is_a_machinery_machine_with_its_identification_and_states() {
    let port = free_port();
    let listen = format!("127.0.0.1:{port}");
    let cell = LaunchedCell::start_with("50", &["--opcua", &listen]);
    let url = format!("opc.tcp://{listen}/");
    let mut c = client(&cell, "machinery", &url, &[]);
    let t = Duration::from_secs(60);
    let m = step(&mut c, "machines-0", t);
    println!("machines: {m}");
    let falc1 = &m["machines"]["falc1"];
    assert_eq!(falc1["identification_is_machinery_type"], true, "{m}");
    let id = &falc1["identification"];
    assert_eq!(id["Manufacturer"], "FALC", "{m}");
    assert_eq!(id["Model"], "FALC welding and assembly cell", "{m}");
    assert_eq!(id["SerialNumber"], "FALC-1992-0001", "{m}");
    assert_eq!(id["SoftwareRevision"], env!("CARGO_PKG_VERSION"), "{m}");
    assert!(
        id["ProductInstanceUri"]
            .as_str()
            .is_some_and(|u| u.ends_with("FALC-1992-0001")),
        "{m}"
    );
    let states = &falc1["states"];
    assert_eq!(states["item"]["state"], "NotExecuting", "{m}");
    assert_eq!(states["item"]["id_in_machinery"], true, "{m}");
    assert_eq!(states["mode"]["state"], "Processing", "{m}");
    assert_eq!(states["mode"]["id_in_machinery"], true, "{m}");

    // Step mode is Setup, maintenance OutOfService and Maintenance; back in
    // auto, Processing again. Each read again until it shows.
    let mut n = 0;
    let mut until = |want: (&str, &str)| {
        for _ in 0..50 {
            n += 1;
            std::thread::sleep(Duration::from_millis(100));
            c.send("again");
            let m = step(&mut c, &format!("machines-{n}"), t);
            let s = &m["machines"]["falc1"]["states"];
            if s["item"]["state"] == want.0 && s["mode"]["state"] == want.1 {
                return;
            }
        }
        panic!("the machine's states never became {want:?}");
    };
    for (mode, want) in [
        ("step", ("NotExecuting", "Setup")),
        ("maintenance", ("OutOfService", "Maintenance")),
        ("auto", ("NotExecuting", "Processing")),
    ] {
        let (code, out) = cell.falc_as("console", &["mode", mode]);
        assert_eq!(code, 0, "{out}");
        until(want);
    }
}

/// A job order's states through JobOrderControl's commands on the one
/// cell (OPC 10031-4's state machine over FALC's orders), and the way
/// back after an Abort: the next job order runs to Ended.
#[test]
fn job_orders_are_stored_cancelled_paused_aborted_and_the_next_one_ends() {
    let port = free_port();
    let listen = format!("127.0.0.1:{port}");
    let cell = LaunchedCell::start_with("50", &["--opcua", &listen]);
    let url = format!("opc.tcp://{listen}/");
    let mut c = client(&cell, "job-states", &url, &["falc1"]);
    let t = Duration::from_secs(60);
    let ok = serde_json::json!(["Good", 1]);
    let s = step(&mut c, "stored", t);
    // Two Stores of one JobOrderID at once: the gateway takes them one at
    // a time, so one is taken and the other refused (16).
    assert_eq!(
        s["twins"],
        serde_json::json!([ok, ["Uncertain", 16]]),
        "{s}"
    );
    assert_eq!(s["twin_cancelled"], ok, "{s}");
    assert_eq!(s["calls"], serde_json::json!([ok, ok]), "{s}");
    assert_eq!(
        s["listed"],
        serde_json::json!({"J-1": "NotAllowedToStart", "J-2": "NotAllowedToStart"}),
        "{s}"
    );
    // Cancelled, J-2 is gone: starting it is an unknown job order.
    let s = step(&mut c, "cancelled", t);
    assert_eq!(s["calls"], serde_json::json!([ok, ["Uncertain", 2]]), "{s}");
    assert_eq!(
        s["listed"],
        serde_json::json!({"J-1": "NotAllowedToStart"}),
        "{s}"
    );
    // Started it runs; paused, the cell is in step mode and the job order
    // Interrupted; a second Pause is refused (invalid state).
    let s = step(&mut c, "paused", Duration::from_secs(120));
    assert_eq!(s["calls"], serde_json::json!([ok, ok]), "{s}");
    assert_eq!(
        (s["running"].as_bool(), s["interrupted"].as_bool()),
        (Some(true), Some(true)),
        "{s}"
    );
    assert_eq!(s["pause_again"], serde_json::json!(["Uncertain", 8]), "{s}");
    let (code, out) = cell.falc_as("console", &["status"]);
    assert_eq!(code, 0, "{out}");
    assert!(out.contains("mode: step"), "Pause is step mode: {out}");
    c.send("resume");
    // Resumed it runs again; aborted, it is Aborted, and a Cancel of it
    // is refused.
    let s = step(&mut c, "aborted", Duration::from_secs(120));
    assert_eq!(s["calls"], serde_json::json!([ok, ok]), "{s}");
    assert_eq!(
        (s["running"].as_bool(), s["aborted"].as_bool()),
        (Some(true), Some(true)),
        "{s}"
    );
    assert_eq!(
        s["cancel_ended"],
        serde_json::json!(["Uncertain", 8]),
        "{s}"
    );
    // The way back: the next job order runs to Ended, and is cleared.
    let s = step(&mut c, "ended", Duration::from_secs(240));
    assert_eq!(s["calls"], serde_json::json!([ok, ok]), "{s}");
    assert_eq!(s["ended"], true, "{s}");
    assert_eq!(s["listed"], serde_json::json!({"J-1": "Aborted"}), "{s}");
    let orders = cell.falc_as("console", &["order", "list"]).1;
    assert!(
        orders.contains("job order J-3") && orders.contains("done"),
        "{orders}"
    );
}
