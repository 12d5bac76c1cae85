//! TCP against the secure transport (QUIC with mutual TLS), side by side in
//! one run (interleaved): two routers on this machine, one `tcp/…`, one
//! `quic/…`, each with a demo
//! station, the same requests alternating between them. Prints:
//! - the confirmed-service round trip answered by the bus (Status: typed
//!   request, envelope, the router, the confirm);
//! - the round trip through the station's event loop (Identify), the
//!   per-step cost of a recipe step that is one request and its confirm
//!   (the cell's `start`, `output`, `input` steps);
//! - the time for a console to open its session (the TCP or QUIC
//!   handshake, TLS 1.3 inside QUIC, and zenoh's login).
//!
//! Run: `cargo bench --bench secure`. Prints figures; asserts nothing about
//! time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

use falc_bus::DEFAULT_DEADLINE;
use falc_model::mms::pdu::{Request, Response};
use std::time::{Duration, Instant};
use support::stats::{median, tail};
use support::{st, TestCell};

const ROUNDS: usize = 2000;
const WARMUP: usize = 200;
const OPENS: usize = 30;

fn us(d: Duration) -> f64 {
    d.as_secs_f64() * 1e6
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let cells = [TestCell::start(), TestCell::start_secure()];
    let _stations: Vec<_> = cells.iter().map(|c| c.demo_station("welding")).collect();
    let mut buses = Vec::new();
    for c in &cells {
        buses.push(c.bus("cell").await.expect("cell session"));
    }
    let welding = st("welding");
    let mut status = [Vec::new(), Vec::new()];
    let mut identify = [Vec::new(), Vec::new()];
    for round in 0..WARMUP + ROUNDS {
        for (i, bus) in buses.iter().enumerate() {
            let t = Instant::now();
            let r = bus
                .request(&welding, &Request::Status, DEFAULT_DEADLINE)
                .await;
            let s = t.elapsed();
            assert!(matches!(r, Ok(Response::Status(_))), "{r:?}");
            let t = Instant::now();
            let r = bus
                .request(&welding, &Request::Identify, DEFAULT_DEADLINE)
                .await;
            let d = t.elapsed();
            assert!(matches!(r, Ok(Response::Identify(_))), "{r:?}");
            if round >= WARMUP {
                status[i].push(us(s));
                identify[i].push(us(d));
            }
        }
    }
    let mut opens = [Vec::new(), Vec::new()];
    for _ in 0..OPENS {
        for (i, c) in cells.iter().enumerate() {
            let t = Instant::now();
            let bus = c.bus("console").await.expect("console session");
            opens[i].push(t.elapsed().as_secs_f64() * 1000.0);
            drop(bus);
        }
    }
    let line = |what: &str, unit: &str, v: &[Vec<f64>; 2]| {
        let (tn, tt) = tail(&v[0]);
        let (_, lt) = tail(&v[1]);
        println!(
            "{what}: tcp median {:.0} {unit} ({tn} {:.0}), quic median {:.0} {unit} ({tn} {:.0}); quic/tcp {:.2} (n={})",
            median(&v[0]),
            tt,
            median(&v[1]),
            lt,
            median(&v[1]) / median(&v[0]),
            v[0].len()
        );
    };
    line(
        "confirmed service, answered by the bus (Status)",
        "µs",
        &status,
    );
    line(
        "per step: one request through the station's loop and its confirm (Identify)",
        "µs",
        &identify,
    );
    line("a console's session opened", "ms", &opens);
}
