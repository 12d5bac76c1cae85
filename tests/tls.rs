//! Mutual TLS and the hardened router on localhost (no root needed): the
//! whole cell runs orders over `tls/…`; a certificate from another CA, a
//! plain-tcp node and a node in router or peer mode are refused; and 500
//! silent connections held open do not keep a console out. The cell as
//! separate hosts in network namespaces is `hosts`.

use crate::support::rig::rig_tls;
use crate::support::{copy_dir, run_falc, TestCell};
use falc_model::console::{Call, OrderState};
use falc_model::keys::KeySpace;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// `falc` args for the cell's topology file `topology` and credentials in
/// `dir`, as the operator console user.
fn console_args(topology: &Path, dir: &Path) -> Vec<String> {
    vec![
        "--topology".into(),
        topology.display().to_string(),
        "--credentials-dir".into(),
        dir.display().to_string(),
        "--connect-timeout-ms".into(),
        "2000".into(),
    ]
}

/// The cell's credentials copied to `<cell dir>/stolen`, with `files`
/// (of `console.crt`, `console.key`, `ca.crt`) replaced by those of
/// another CA, made by `falc-router credentials` for the same topology.
fn with_foreign(cell: &TestCell, files: &[&str]) -> PathBuf {
    let dir = cell.dir.path();
    let foreign = dir.join("foreign-ca");
    if !foreign.exists() {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_falc-router"))
            .arg("--topology")
            .arg(&cell.topology_path)
            .arg("--credentials-dir")
            .arg(&foreign)
            .arg("credentials")
            .output()
            .expect("falc-router credentials");
        assert!(out.status.success(), "{out:?}");
    }
    let stolen = dir.join("stolen");
    copy_dir(&cell.credentials_dir(), &stolen);
    for f in files {
        std::fs::copy(foreign.join(f), stolen.join(f)).expect("copy");
    }
    stolen
}

#[test]
fn the_cell_runs_orders_over_mutual_tls_and_refuses_strangers() {
    let rig = rig_tls("20");
    rig.cell.falc(&["order", "add", "dikdroog"]);
    rig.cell.falc(&["order", "add", "dundroog"]);
    rig.cell.falc(&["start"]);
    rig.work_list("ja", Duration::from_secs(120));
    let orders = rig.orders();
    assert_eq!(
        orders.iter().map(|o| o.state).collect::<Vec<_>>(),
        vec![OrderState::Done; 2],
        "{orders:?}"
    );

    let cell = &rig.cell;
    let dir = cell.dir.path();
    let own = console_args(&cell.topology_path, &cell.credentials_dir());
    let (code, out) = run_falc(&own, &["status"]);
    assert_eq!(code, 0, "the cell's own console: {out}");

    // The console's password and name, but a certificate from another CA.
    let stolen = with_foreign(cell, &["console.crt", "console.key", "ca.crt"]);
    let (code, out) = run_falc(&console_args(&cell.topology_path, &stolen), &["status"]);
    assert_eq!(
        code, 2,
        "a certificate of another CA must be refused: {out}"
    );
    // Only the CA certificate swapped back: the router's certificate is
    // trusted again, but the console's own is still the foreign one.
    std::fs::copy(cell.credentials_dir().join("ca.crt"), stolen.join("ca.crt")).expect("copy");
    let (code, out) = run_falc(&console_args(&cell.topology_path, &stolen), &["status"]);
    assert_eq!(code, 2, "a client certificate of another CA: {out}");
    // The right certificate, but another user's: the router authenticates
    // `console` by password, yet the certificate's name is `observer`.
    for f in ["console.crt", "console.key"] {
        let from = cell
            .credentials_dir()
            .join(f.replace("console", "observer"));
        std::fs::copy(from, stolen.join(f)).expect("copy");
    }
    let (code, out) = run_falc(&console_args(&cell.topology_path, &stolen), &["status"]);
    assert_eq!(code, 2, "a certificate of another user: {out}");

    // A plain-tcp node on the TLS port.
    let plain = dir.join("plain.toml");
    std::fs::write(
        &plain,
        std::fs::read_to_string(&cell.topology_path)
            .expect("topology")
            .replace("tls/", "tcp/"),
    )
    .expect("write");
    let (code, out) = run_falc(&console_args(&plain, &cell.credentials_dir()), &["status"]);
    assert_eq!(code, 2, "plain tcp must be refused: {out}");

    // Valid credentials and certificate, but the session in router or peer
    // mode: no reply from the operator API, where a client gets one.
    let rt = tokio::runtime::Runtime::new().expect("runtime");
    let replies = |mode: &str| rt.block_on(api_replies(cell, mode));
    assert!(replies("client"), "control: a client session is answered");
    assert!(!replies("router"), "a node in router mode must be refused");
    assert!(!replies("peer"), "a node in peer mode must be refused");

    // The way back for a PC with a wrong bundle: the one `falc-router
    // bundle` makes, laid out as that PC's /etc/falc, and it connects.
    let bundle = |user: &str| {
        let out_dir = dir.join(format!("bundle-{user}"));
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_falc-router"))
            .arg("--topology")
            .arg(&cell.topology_path)
            .arg("--credentials-dir")
            .arg(cell.credentials_dir())
            .args(["bundle", user, "--out"])
            .arg(&out_dir)
            .output()
            .expect("falc-router bundle");
        assert!(out.status.success(), "{out:?}");
        out_dir
    };
    let console = bundle("console");
    let (code, out) = run_falc(
        &console_args(&console.join("cell.toml"), &console.join("credentials")),
        &["status"],
    );
    assert_eq!(code, 0, "the console's bundle: {out}");
    // A station called `cell`: its password file and the topology both
    // named cell.toml, each in its place; never the CA's key.
    let station = bundle("cell");
    let password = falc_bus::credentials::load(&station.join("credentials/cell.toml"))
        .expect("the cell's password file");
    assert_eq!(password.user, "cell");
    falc_model::topology::Topology::load(&station.join("cell.toml")).expect("the topology");
    let mut names: Vec<String> = std::fs::read_dir(station.join("credentials"))
        .expect("bundle")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["ca.crt", "cell.crt", "cell.key", "cell.toml"]);

    // And the cell still works for its own.
    let (code, out) = run_falc(&own, &["status"]);
    assert_eq!(code, 0, "{out}");
}

/// Whether a zenoh session of the console user in `mode` gets any reply
/// (even an error) from the operator API's `status` call.
async fn api_replies(cell: &TestCell, mode: &str) -> bool {
    let settings = cell.settings("console");
    let mut cfg = falc_bus::config::client(
        &settings.endpoint,
        settings.lease,
        settings.credentials.as_ref(),
        settings.tls.as_ref(),
        Duration::from_secs(2),
    )
    .expect("config");
    cfg.insert_json5("mode", &format!("\"{mode}\""))
        .expect("mode");
    cfg.insert_json5("listen/endpoints", "[]").expect("listen");
    let Ok(session) = zenoh::open(cfg).await else {
        return false;
    };
    // Time for the router to refuse the transport, if it does.
    tokio::time::sleep(Duration::from_millis(500)).await;
    let keys = KeySpace::new(cell.topology.cell().clone());
    let key = keys.api(&cell.topology.root().name, Call::Status, &settings.me);
    let replies = session
        .get(&key)
        .payload(b"not a request".to_vec())
        .timeout(Duration::from_secs(2))
        .await
        .expect("get");
    let answered = replies.recv_async().await.is_ok();
    let _ = session.close().await;
    answered
}

#[test]
fn silent_connections_do_not_keep_a_console_out() {
    for mut cell in [TestCell::start(), TestCell::start_tls()] {
        let address = cell
            .endpoint
            .split_once('/')
            .map(|(_, a)| a.to_string())
            .expect("address");
        // 500 strangers connect and say nothing.
        let held: Vec<std::net::TcpStream> = (0..500)
            .map(|_| std::net::TcpStream::connect(&address).expect("connect"))
            .collect();
        let rt = tokio::runtime::Runtime::new().expect("runtime");
        let begin = Instant::now();
        let mut settings = cell.settings("console");
        settings.connect_timeout = Duration::from_secs(2);
        let session = rt.block_on(falc_bus::Bus::open(settings));
        let took = begin.elapsed();
        assert!(
            session.is_ok(),
            "{}: a console could not connect within 2 s while 500 silent connections were held ({took:?}): {:?}",
            cell.endpoint,
            session.err()
        );
        println!(
            "{}: console connected in {:.1} ms with {} silent connections held",
            cell.endpoint,
            took.as_secs_f64() * 1000.0,
            held.len()
        );
        drop(held);
        // The router logged them refused, rate-limited: one line for the
        // host, then the rest summed up when the window ends.
        let router = &mut cell.router;
        let summary = router.expect_line("refused logins: ", Duration::from_secs(20));
        let held_back: u64 = summary
            .split("refused logins: ")
            .nth(1)
            .and_then(|s| s.split(' ').next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("a count in {summary:?}"));
        assert!(
            held_back >= 400 && summary.contains("most from 127.0.0.1"),
            "most of the 500 refusals are summed up, not logged one by one: {summary}"
        );
        let one_by_one = router.lines_containing("refused login from 127.0.0.1");
        assert_eq!(one_by_one.len(), 1, "{one_by_one:?}");
        println!(
            "{}: {held_back} refusals held back in one line",
            cell.endpoint
        );
    }
}

#[test]
fn refused_logins_are_logged_with_their_source() {
    // A wrong password, on the all-in-one tcp cell.
    let mut cell = TestCell::start();
    let dir = cell.dir.path().to_path_buf();
    let wrong = dir.join("wrong");
    copy_dir(&cell.credentials_dir(), &wrong);
    let file = wrong.join("console.toml");
    let text = std::fs::read_to_string(&file).expect("password file");
    let text: String = text
        .lines()
        .map(|l| {
            if l.starts_with("password") {
                "password = \"not-the-password\"".to_string()
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    std::fs::write(&file, text).expect("write");
    let (code, out) = run_falc(&console_args(&cell.topology_path, &wrong), &["status"]);
    assert_eq!(code, 2, "a wrong password: {out}");
    assert!(
        out.contains("the router logs `refused login from` this PC"),
        "the console says where to look: {out}"
    );
    let line = cell
        .router
        .expect_line("refused login from 127.0.0.1", Duration::from_secs(10));
    assert!(
        line.contains("WARN") && line.contains("Invalid password for user \"console\""),
        "{line}"
    );
    assert!(line.contains("link=tcp/127.0.0.1:"), "{line}");

    // A certificate of another CA, on a TLS cell.
    let mut cell = TestCell::start_tls();
    let stolen = with_foreign(&cell, &["console.crt", "console.key"]);
    let (code, out) = run_falc(&console_args(&cell.topology_path, &stolen), &["status"]);
    assert_eq!(code, 2, "a client certificate of another CA: {out}");
    let line = cell
        .router
        .expect_line("refused login from 127.0.0.1", Duration::from_secs(10));
    assert!(
        line.contains("WARN")
            && line.contains("certificate")
            && line.contains("link=tls/127.0.0.1:"),
        "{line}"
    );
    println!("{line}");
}
