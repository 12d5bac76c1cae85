//! Foundation benchmark: one run through a real `falc-router` with ACL and
//! authentication on. Prints, measured side by side (interleaved):
//! - the round trip of a confirmed Status via FALC (typed request,
//!   envelope, typed confirm) to a demo-station process. The bus answers
//!   Status itself, inside the zenoh callback, from the station's status
//!   board: this is the binding's cost, not the node's;
//! - the round trip of an Identify, which goes through the station's event
//!   loop (the bus hands the indication to the node, the node answers):
//!   what a service costs that the node itself serves;
//! - a bare zenoh `get` of the Status bytes to a bare queryable in another
//!   process, on the same router and session;
//! - the time from SIGKILL of an associated station to its abort indication.
//!
//! Run: `cargo bench --bench foundation`. Prints figures; asserts nothing
//! about time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

use falc_bus::{BusEvent, DEFAULT_DEADLINE};
use falc_model::envelope;
use falc_model::mms::pdu::{Request, Response};
use falc_model::mms::vmd::VmdStatus;
use std::process::Command;
use std::time::{Duration, Instant};
use support::stats::{median, percentile, tail};
use support::{st, Proc, TestCell};
use zenoh::query::{ConsolidationMode, QueryTarget};
use zenoh::Wait;

const ROUNDS: usize = 2000;
const WARMUP: usize = 200;
const KILLS: usize = 20;

fn main() {
    if std::env::var("FALC_BENCH_ROLE").as_deref() == Ok("bare-server") {
        bare_server();
        return;
    }
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => panic!("no tokio runtime: {e}"),
    };
    rt.block_on(run());
}

/// A bare zenoh queryable on the transport's status key, answering with the
/// bytes a station would send, straight from the callback.
fn bare_server() {
    let endpoint = std::env::var("FALC_BENCH_ENDPOINT").expect("endpoint");
    let creds_path = std::env::var("FALC_BENCH_CREDENTIALS").expect("credentials");
    let creds = falc_bus::credentials::load(std::path::Path::new(&creds_path)).expect("creds");
    let cfg = falc_bus::config::client(
        &endpoint,
        Duration::from_secs(1),
        Some(&creds),
        None,
        Duration::ZERO,
    )
    .expect("config");
    let session = zenoh::open(cfg).wait().expect("bare session");
    let key = "falc/falc1/transport/svc/status";
    let reply = envelope::encode(&Response::Status(VmdStatus::default()));
    let _q = session
        .declare_queryable(key)
        .callback(move |q| {
            let _ = q.reply(key, reply.clone()).wait();
        })
        .wait()
        .expect("queryable");
    println!("bare-server ready");
    loop {
        std::thread::sleep(Duration::from_secs(3600));
    }
}

fn us(d: Duration) -> f64 {
    d.as_secs_f64() * 1e6
}

async fn run() {
    let cell = TestCell::start();
    let _welding = cell.demo_station("welding");
    let mut bare_cmd = Command::new(std::env::current_exe().expect("own path"));
    bare_cmd
        .env("FALC_BENCH_ROLE", "bare-server")
        .env("FALC_BENCH_ENDPOINT", &cell.endpoint)
        .env(
            "FALC_BENCH_CREDENTIALS",
            cell.credentials_dir().join("transport.toml"),
        );
    let mut bare = Proc::spawn("bare-server", bare_cmd);
    bare.expect_line("bare-server ready", Duration::from_secs(20));
    let bus = cell.bus("cell").await.expect("cell session");
    let welding = st("welding");
    let bare_key = "falc/falc1/transport/svc/status";
    let request_bytes = envelope::encode(&Request::Status);

    let typed = || async {
        let t = Instant::now();
        let r = bus
            .request(&welding, &Request::Status, DEFAULT_DEADLINE)
            .await;
        assert!(matches!(r, Ok(Response::Status(_))), "status failed: {r:?}");
        t.elapsed()
    };
    let through_loop = || async {
        let t = Instant::now();
        let r = bus
            .request(&welding, &Request::Identify, DEFAULT_DEADLINE)
            .await;
        assert!(
            matches!(r, Ok(Response::Identify(_))),
            "identify failed: {r:?}"
        );
        t.elapsed()
    };
    let raw = || async {
        let t = Instant::now();
        let replies = bus
            .session()
            .get(bare_key)
            .payload(request_bytes.clone())
            .target(QueryTarget::BestMatching)
            .consolidation(ConsolidationMode::None)
            .timeout(DEFAULT_DEADLINE)
            .await
            .expect("get sent");
        let reply = replies.recv_async().await.expect("bare reply");
        assert!(reply.result().is_ok());
        t.elapsed()
    };
    for _ in 0..WARMUP {
        typed().await;
        through_loop().await;
        raw().await;
    }
    let (mut a, mut b, mut c) = (
        Vec::with_capacity(ROUNDS),
        Vec::with_capacity(ROUNDS),
        Vec::with_capacity(ROUNDS),
    );
    for i in 0..ROUNDS {
        // Rotate which goes first, so none always gets a warm cache.
        match i % 3 {
            0 => {
                a.push(typed().await);
                c.push(through_loop().await);
                b.push(raw().await);
            }
            1 => {
                b.push(raw().await);
                a.push(typed().await);
                c.push(through_loop().await);
            }
            _ => {
                c.push(through_loop().await);
                b.push(raw().await);
                a.push(typed().await);
            }
        }
    }
    let (a50, a99, b50, b99) = (
        percentile(&a, 0.5),
        percentile(&a, 0.99),
        percentile(&b, 0.5),
        percentile(&b, 0.99),
    );
    let (c50, c99) = (percentile(&c, 0.5), percentile(&c, 0.99));
    println!("confirmed service round trip through falc-router (ACL + usrpwd on), n={ROUNDS} each, interleaved:");
    println!(
        "  FALC Status request→confirm : p50 {:8.1} µs   p99 {:8.1} µs",
        us(a50),
        us(a99)
    );
    println!(
        "  FALC Identify (node's loop) : p50 {:8.1} µs   p99 {:8.1} µs",
        us(c50),
        us(c99)
    );
    println!(
        "  bare zenoh get, same bytes  : p50 {:8.1} µs   p99 {:8.1} µs",
        us(b50),
        us(b99)
    );
    println!(
        "  ratio FALC/bare             : p50 {:.3}        p99 {:.3}   (goal: p50 ≤ 1.10)",
        us(a50) / us(b50),
        us(a99) / us(b99)
    );

    // SIGKILL → abort indication: a fresh welding station each time,
    // associated with this session, its token watched as the cell does.
    drop(_welding);
    let mut kills = Vec::with_capacity(KILLS);
    for _ in 0..KILLS {
        let mut victim = cell.demo_station("welding");
        let initiate = Request::Initiate {
            calling: bus.me().clone(),
        };
        let peer = match bus.request(&welding, &initiate, DEFAULT_DEADLINE).await {
            Ok(Response::Initiate { responding }) => responding,
            other => panic!("initiate failed: {other:?}"),
        };
        let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
        let watch = bus.watch(&peer, tx).await.expect("watch");
        let t = Instant::now();
        victim.kill();
        match tokio::time::timeout(Duration::from_secs(10), rx.recv()).await {
            Ok(Some(BusEvent::PeerLost { .. })) => kills.push(t.elapsed()),
            other => panic!("no abort indication: {other:?}"),
        }
        drop(watch);
    }
    let (tail_name, tail_value) = tail(&kills);
    println!("SIGKILL of an associated station → abort indication, n={KILLS}:");
    println!(
        "  p50 {:8.2} ms   {tail_name} {:8.2} ms   (goal: p50 < 20 ms)",
        us(median(&kills)) / 1000.0,
        us(tail_value) / 1000.0
    );
}
