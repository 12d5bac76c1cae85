//! A station's status change as a plant's OPC UA client sees it, next to
//! the same change seen by `falc status --watch`, in one run: the
//! all-in-one cell with `falc-opcua`, an asyncua client subscribed to the
//! transport station's Mode (tests/opcua_client.py `watch`) and `falc
//! --json status --watch`, both watching while the operator switches the
//! cell between auto and step (the mode travels operator → cell →
//! workstations, whose status publications carry it back up). Each change
//! is timed from the moment `falc mode` is issued to the moment each
//! watcher has it; prints p50 and the tail of both, and their ratio.
//!
//! Run: `cargo bench --bench opcua` (needs Python with asyncua, as the
//! tests: `.ci/test` makes target/opcua-venv; FALC_PYTHON names it).
//! Prints figures; asserts nothing about time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

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
    let mut watch = Proc::spawn("falc status --watch", {
        let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_falc"));
        c.args(cell.falc_args("observer"))
            .args(["--json", "status", "--watch"]);
        c
    });
    let (mut by_ua, mut by_watch) = (Vec::new(), Vec::new());
    for i in 0..CHANGES {
        let mode = if i % 2 == 0 { "step" } else { "auto" };
        // Out of step with both watchers' periods.
        std::thread::sleep(Duration::from_millis(rand::random::<u64>() % 300));
        let t0 = now();
        let (code, out) = run_falc(&cell.falc_args("console"), &["mode", mode]);
        assert_eq!(code, 0, "{out}");
        let seen_watch = until(&mut watch, mode, watched_mode);
        let seen_ua = until(&mut ua, mode, notified);
        by_ua.push((seen_ua - t0) * 1e3);
        by_watch.push((seen_watch - t0) * 1e3);
    }
    ua.send("");
    let (ua50, w50) = (median(&by_ua), median(&by_watch));
    let (name, ua_tail) = tail(&by_ua);
    let (_, w_tail) = tail(&by_watch);
    println!(
        "station status change (falc mode → the transport station's mode), n={CHANGES}, debug build, time scale 50"
    );
    println!("  OPC UA data-change notification (falc-opcua, on the operator's `changed`, publish 20 ms): p50 {ua50:.1} ms, {name} {ua_tail:.1} ms");
    println!("  falc status --watch (on the operator's `changed`):                        p50 {w50:.1} ms, {name} {w_tail:.1} ms");
    println!("  ratio OPC UA / watch (p50): {:.2}", ua50 / w50);
}
