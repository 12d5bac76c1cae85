//! A station's status change as a plant's OPC UA client sees it, next to
//! the same change seen by `falc status --watch`, in one run: the
//! all-in-one cell with `falc-opcua`, an asyncua client subscribed to the
//! transport station's Mode (tests/opcua_client.py `watch`) and `falc
//! --json status --watch`, both watching while the operator switches the
//! cell between auto and step (the mode travels operator → cell →
//! workstations, whose status publications carry it back up). Each change
//! is timed from the moment `falc mode` is issued to the moment each
//! watcher has it, and again from the moment the change was at the
//! operator: when its `changed` publication, after which its status shows
//! the new mode, reached a session of this process (an observer that
//! asks for the status after each `changed`). Prints p50 and the tail of
//! each, and their ratio.
//!
//! Run: `cargo bench --bench opcua` (needs Python with asyncua, as the
//! tests: `.ci/test` makes target/opcua-venv; FALC_PYTHON names it).
//! Prints figures; asserts nothing about time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

use falc_bus::Bus;
use falc_model::api::{ApiReply, ApiRequest};
use std::sync::mpsc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use support::opcua::{client, step};
use support::stats::{median, tail};
use support::{free_port, run_falc, LaunchedCell, Proc};

const CHANGES: usize = 100;

fn now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// The transport station's mode in one `falc --json status` line, and
/// when the line was read.
fn watched_mode(line: &str) -> Option<(String, f64)> {
    let v: serde_json::Value = serde_json::from_str(line).ok()?;
    let mode = v["stations"]
        .as_array()?
        .iter()
        .find(|s| s["name"] == "transport")?["status"]["mode"]
        .as_str()?;
    Some((mode.to_string(), now()))
}

/// The value of one data change the OPC UA client printed, and when the
/// client had it (its own clock, read in its notification callback).
fn notified(line: &str) -> Option<(String, f64)> {
    let v: serde_json::Value = serde_json::from_str(line).ok()?;
    if v["step"] != "change" {
        return None;
    }
    Some((v["value"].as_str()?.to_string(), v["at"].as_f64()?))
}

/// The operator's changes as an observer session of this process hears
/// them: for each `changed` publication, the transport station's mode in
/// the status asked for right after it, and when the publication came.
/// (Publications that come while a status call is under way are each
/// followed by a call of their own, later: a change is never dated
/// earlier than its publication.)
fn operator_changes(cell: &LaunchedCell) -> mpsc::Receiver<(String, f64)> {
    let settings = cell.settings("observer");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let rt = tokio::runtime::Runtime::new().expect("runtime");
        rt.block_on(async move {
            let bus = Bus::open(settings).await.expect("observer session");
            let operator = support::st("operator");
            let (heard, mut changes) = tokio::sync::mpsc::unbounded_channel();
            let _sub = bus
                .on_changed(&operator, move || {
                    let _ = heard.send(now());
                })
                .await
                .expect("subscriber");
            while let Some(at) = changes.recv().await {
                let reply = bus
                    .api(&operator, ApiRequest::Status, Duration::from_secs(2))
                    .await;
                let Ok(ApiReply::Status(status)) = reply else {
                    continue;
                };
                let mode = status
                    .stations
                    .iter()
                    .find(|s| s.name.as_str() == "transport")
                    .and_then(|s| s.status.as_ref())
                    .map(|s| s.mode.to_string());
                if let Some(mode) = mode {
                    if tx.send((mode, at)).is_err() {
                        break;
                    }
                }
            }
        });
    });
    rx
}

/// When the change to `want` issued at `t0` was at the operator: the
/// first `changed` after `t0` whose status shows it.
fn changed_at(changes: &mpsc::Receiver<(String, f64)>, want: &str, t0: f64) -> f64 {
    let end = Instant::now() + Duration::from_secs(10);
    loop {
        let left = end.saturating_duration_since(Instant::now());
        let (mode, at) = changes
            .recv_timeout(left)
            .unwrap_or_else(|_| panic!("the operator's change to {want} not heard within 10 s"));
        if mode == want && at >= t0 {
            return at;
        }
    }
}

/// Waits until `p` prints a line that `pick` reads as `want`; when it was
/// seen (s since the epoch).
fn until(p: &mut Proc, want: &str, pick: fn(&str) -> Option<(String, f64)>) -> f64 {
    let end = Instant::now() + Duration::from_secs(10);
    loop {
        let left = end.saturating_duration_since(Instant::now());
        assert!(!left.is_zero(), "{}: {want} not seen within 10 s", p.name);
        let line = p.next_line(left).expect("a line");
        if let Some((_, at)) = pick(&line).filter(|(v, _)| v == want) {
            return at;
        }
    }
}

fn main() {
    let listen = format!("127.0.0.1:{}", free_port());
    let cell = LaunchedCell::start_with("50", &["--opcua", &listen]);
    let url = format!("opc.tcp://{listen}/");
    let mut ua = client(&cell, "watch", &url, &["FALC.Stations.transport.Mode"]);
    step(&mut ua, "watching", Duration::from_secs(60));
    let changes = operator_changes(&cell);
    let mut watch = Proc::spawn("falc status --watch", {
        let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_falc"));
        c.args(cell.falc_args("observer"))
            .args(["--json", "status", "--watch"]);
        c
    });
    let (mut by_ua, mut by_watch) = (Vec::new(), Vec::new());
    let (mut ua_after, mut watch_after) = (Vec::new(), Vec::new());
    for i in 0..CHANGES {
        let mode = if i % 2 == 0 { "step" } else { "auto" };
        // Out of step with both watchers' periods.
        std::thread::sleep(Duration::from_millis(rand::random::<u64>() % 300));
        let t0 = now();
        let (code, out) = run_falc(&cell.falc_args("console"), &["mode", mode]);
        assert_eq!(code, 0, "{out}");
        let seen_watch = until(&mut watch, mode, watched_mode);
        let seen_ua = until(&mut ua, mode, notified);
        let at_operator = changed_at(&changes, mode, t0);
        by_ua.push((seen_ua - t0) * 1e3);
        by_watch.push((seen_watch - t0) * 1e3);
        ua_after.push((seen_ua - at_operator) * 1e3);
        watch_after.push((seen_watch - at_operator) * 1e3);
    }
    ua.send("");
    let (ua50, w50) = (median(&by_ua), median(&by_watch));
    let (name, ua_tail) = tail(&by_ua);
    let (_, w_tail) = tail(&by_watch);
    let build = if cfg!(debug_assertions) {
        "debug"
    } else {
        "release"
    };
    println!(
        "station status change (falc mode → the transport station's mode), n={CHANGES}, {build} build, time scale 50"
    );
    println!("from `falc mode`'s start (the command's own start-up included):");
    println!("  OPC UA data-change notification (falc-opcua, on the operator's `changed`, publish 20 ms): p50 {ua50:.1} ms, {name} {ua_tail:.1} ms");
    println!("  falc status --watch (on the operator's `changed`):                        p50 {w50:.1} ms, {name} {w_tail:.1} ms");
    println!("  ratio OPC UA / watch (p50): {:.2}", ua50 / w50);
    let (ua50, w50) = (median(&ua_after), median(&watch_after));
    let (_, ua_tail) = tail(&ua_after);
    let (_, w_tail) = tail(&watch_after);
    println!(
        "from the change at the operator (its `changed` heard, its status showing the new mode):"
    );
    println!("  OPC UA data-change notification: p50 {ua50:.1} ms, {name} {ua_tail:.1} ms");
    println!("  falc status --watch:             p50 {w50:.1} ms, {name} {w_tail:.1} ms");
    println!("  ratio OPC UA / watch (p50): {:.2}", ua50 / w50);
}
