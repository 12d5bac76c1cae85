//! Transport benchmark: the reaction time of a running transport recipe,
//! from an input change in the PLC to the next coil write, measured by the
//! PLC twin itself (the time between the carrier reaching place 3 and the
//! `reset k` of STORE arriving as a coil write), through a real router,
//! `falc-plc-sim` on Modbus TCP and `falc-transport`. Printed next to the
//! poll period, for the default 10 ms and for 1 ms, with the bare Modbus
//! read round trip to the same twin as the floor.
//!
//! Run: `cargo bench --bench transport`. Prints figures; asserts nothing
//! about time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

use falc_model::mms::pdu::JobEvent;
use std::time::{Duration, Instant};
use support::stats::{median, tail};
use support::{twin, Commander, Proc, TestCell};
use tokio_modbus::client::Reader;

const ROUNDS: usize = 40;

fn store() -> String {
    std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/recipes/transport/store.rcp"
    ))
    .expect("shipped recipe")
}

/// Runs STORE `ROUNDS` times with the node polling every `poll_ms`;
/// returns the reaction times in ms.
async fn reactions(cell: &TestCell, plc: &mut Proc, address: &str, poll_ms: u64) -> Vec<f64> {
    let poll = poll_ms.to_string();
    let mut node = cell.start_node(
        env!("CARGO_BIN_EXE_falc-transport"),
        "transport",
        &["--plc", address, "--poll-ms", &poll],
    );
    node.expect_line("EVENT plc-ready", Duration::from_secs(20));
    let mut commander = Commander::associate(cell, "transport").await;
    commander.load("store", &store()).await;
    let mut out = Vec::new();
    for _ in 0..ROUNDS {
        plc.control("layout W2 W2");
        // A random phase against the poll period: without it every start
        // follows the last run's final poll by the same few ms, and so
        // does every arrival (travel times are whole poll periods).
        let phase = Duration::from_secs_f64(rand::random::<f64>() * 0.02);
        tokio::time::sleep(phase).await;
        commander.start("store").await;
        assert_eq!(commander.job(Duration::from_secs(30)).await, JobEvent::Done);
        let line = plc.take_line("coil button line K 0 reaction_us=", Duration::from_secs(5));
        let us: f64 = line
            .rsplit('=')
            .next()
            .and_then(|v| v.parse().ok())
            .expect("reaction in µs");
        out.push(us / 1000.0);
    }
    drop(commander);
    node.kill();
    out
}

#[tokio::main]
async fn main() {
    let cell = TestCell::start();
    let (mut plc, address) = twin(
        env!("CARGO_BIN_EXE_falc-plc-sim"),
        &["--listen", "127.0.0.1:0", "--time-scale", "40"],
        "listening on ",
    );

    // The floor: a bare Modbus read of the map's inputs, same twin.
    let sock = address.parse().expect("socket address");
    let mut ctx = tokio_modbus::client::tcp::connect(sock)
        .await
        .expect("connect");
    let mut rtt = Vec::new();
    for _ in 0..500 {
        let t = Instant::now();
        let _ = ctx
            .read_discrete_inputs(0, falc_equipment::Equipment::conveyor_1992().input_span().1)
            .await
            .expect("read");
        rtt.push(t.elapsed().as_secs_f64() * 1000.0);
    }
    drop(ctx);

    println!("Transport: input change in the PLC → next coil write by a running recipe");
    println!(
        "(STORE: carrier reaches place 3 → `reset k`; measured by the twin), n={ROUNDS} each:"
    );
    for poll in [10u64, 1] {
        let r = reactions(&cell, &mut plc, &address, poll).await;
        let (p50, (tail_name, tail_value)) = (median(&r), tail(&r));
        println!(
            "  poll period {poll:>2} ms : reaction p50 {p50:6.2} ms, {tail_name} {tail_value:6.2} ms; p50 / poll period {:.2} (half a period expected from polling alone)",
            p50 / poll as f64
        );
    }
    let (p50, p99) = (median(&rtt), tail(&rtt).1);
    println!("  bare Modbus read round trip (n=500): p50 {p50:6.3} ms, p99 {p99:6.3} ms");
}
