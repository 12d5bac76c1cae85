//! What bounded inputs cost and save (issue 27), side by side in one run:
//! - a `falc status` reply's size and time while the cell's question waits
//!   with 64 KB of output shown before it (sent with the cell's
//!   credentials as 16 lines of 4,000 characters, the most a line may
//!   hold), next to the same with no output;
//! - `falc status` on a tcp router while 1,000 silent TCP connections are
//!   held, next to none held;
//! - the bytes the operator logs for 10,000 malformed API calls from one
//!   console.
//!
//! Run: `cargo bench --bench hardening`. Prints figures; asserts nothing
//! about time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

use falc_model::mms::pdu::Request;
use std::time::{Duration, Instant};
use support::rig::rig;
use support::stats::median;

/// `falc --json status` `n` times: the reply's size and the median time.
fn status(rig: &support::rig::Rig, n: usize) -> (usize, f64) {
    let mut times = Vec::new();
    let mut size = 0;
    for _ in 0..n {
        let t = Instant::now();
        let out = rig.cell.falc(&["--json", "status"]);
        times.push(t.elapsed().as_secs_f64() * 1000.0);
        size = out.len();
    }
    (size, median(&times))
}

fn main() {
    let mut rig = rig("20");
    let rt = tokio::runtime::Runtime::new().expect("runtime");
    let operator = support::st("operator");

    // 1. The status with a question pending after 64 KB of output.
    let (quiet_size, quiet_ms) = status(&rig, 20);
    let cell = rt.block_on(rig.cell.bus("cell")).expect("a cell session");
    rt.block_on(async {
        for i in 0..16 {
            let line = format!("{i:02} {}", "x".repeat(3996));
            let r = cell
                .request(
                    &operator,
                    &Request::Output { lines: vec![line] },
                    falc_bus::DEFAULT_DEADLINE,
                )
                .await;
            assert!(r.is_ok(), "{r:?}");
        }
    });
    // The question waits (its query stays open) while the status is read.
    let asking = {
        let bus = cell.clone();
        let operator = operator.clone();
        rt.spawn(async move {
            let _ = bus
                .request(
                    &operator,
                    &Request::Input {
                        prompt: "klopt het (ja/nee)".into(),
                        timeout_s: Some(60),
                    },
                    Duration::from_secs(60),
                )
                .await;
        })
    };
    std::thread::sleep(Duration::from_millis(500));
    let (loud_size, loud_ms) = status(&rig, 20);
    asking.abort();
    println!(
        "status with a question after 64 KB of output: {loud_size} bytes, median {loud_ms:.1} ms; with nothing shown: {quiet_size} bytes, median {quiet_ms:.1} ms (n=20 each)"
    );

    // 2. falc status with 1,000 silent TCP connections held.
    let address = rig.cell.address();
    let (_, none_ms) = status(&rig, 20);
    let held: Vec<_> = (0..1000)
        .filter_map(|_| std::net::TcpStream::connect(address).ok())
        .collect();
    let mut times = Vec::new();
    let mut failed = 0;
    for _ in 0..20 {
        let t = Instant::now();
        let (code, _) = rig.cell.falc_as("console", &["status"]);
        times.push(t.elapsed().as_secs_f64() * 1000.0);
        failed += usize::from(code != 0);
    }
    println!(
        "falc status on tcp with {} silent connections held: median {:.1} ms, max {:.1} ms, {failed} of 20 failed; none held: median {none_ms:.1} ms",
        held.len(),
        median(&times),
        times.iter().cloned().fold(0.0, f64::max)
    );
    drop(held);

    // 3. Log bytes for 10,000 malformed API calls from one console.
    rig.operator = None;
    rig.start_operator_logged();
    let log_bytes =
        |p: &support::Proc| -> usize { p.lines_containing("").iter().map(|l| l.len() + 1).sum() };
    let before = log_bytes(rig.operator());
    let (_, answered) = rig.cell.malformed_api_calls(10_000);
    let _ = rig
        .operator()
        .wait_line("no such line", Duration::from_secs(2));
    let after = log_bytes(rig.operator());
    println!(
        "10,000 malformed API calls from one console ({answered} answered): {} bytes of operator log",
        after - before
    );
}
