//! What floods of strangers do to logins when nothing but zenoh stands
//! between them and the router: a router on this machine, no firewall, a
//! console logging in (its session opened, allowed up to 60 s) while
//! strangers hold the port. Side by side in one run:
//! - `quic/…` with no flood, with 300 silent QUIC handshakes held open, and
//!   during 100 failing QUIC handshakes a second for 30 s (a login every
//!   5 s);
//! - `tcp/…` with no flood and with 300 silent TCP connections held open.
//!
//! This is why the router's PC runs `falc-router firewall` (the flood test
//! in `tests/hosts.rs` shows a console getting in behind it). Run:
//! `cargo bench --bench flood`. Prints figures; asserts nothing about time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

use std::net::SocketAddr;
use std::time::{Duration, Instant};
use support::{flood, TestCell};

/// A console's login: its time, or the error after the 60 s allowed.
fn login(cell: &TestCell) -> String {
    let mut settings = cell.settings("console");
    settings.connect_timeout = Duration::from_secs(60);
    let rt = tokio::runtime::Runtime::new().expect("runtime");
    rt.block_on(async move {
        let begin = Instant::now();
        match falc_bus::Bus::open(settings).await {
            Ok(bus) => {
                let took = begin.elapsed();
                let _ = bus.session().close().await;
                format!("{:.1} ms", took.as_secs_f64() * 1000.0)
            }
            Err(_) => format!("no login within {:.0} s", begin.elapsed().as_secs_f64()),
        }
    })
}

fn address(cell: &TestCell) -> SocketAddr {
    cell.endpoint
        .split_once('/')
        .and_then(|(_, a)| a.parse().ok())
        .expect("a socket address")
}

fn main() {
    let quic = TestCell::start_secure();
    let router = address(&quic);
    println!("quic, no flood: console login {}", login(&quic));
    let held = flood::silent_handshakes(router, 300);
    println!(
        "quic, 300 silent handshakes held: console login {}",
        login(&quic)
    );
    drop(held);
    // Let the router's queue drain before the next case.
    std::thread::sleep(Duration::from_secs(35));
    println!(
        "quic, after the silent ones left: console login {}",
        login(&quic)
    );
    let strangers =
        std::thread::spawn(move || flood::failing_handshakes(router, 100, Duration::from_secs(30)));
    let mut logins = Vec::new();
    for _ in 0..5 {
        std::thread::sleep(Duration::from_secs(5));
        logins.push(login(&quic));
    }
    let failed = strangers.join().expect("strangers");
    println!(
        "quic, 100 failing handshakes a second for 30 s ({} begun, {} answered by the router): console logins {logins:?}",
        failed.begun, failed.answered
    );

    let tcp = TestCell::start();
    let at = address(&tcp);
    println!("tcp, no flood: console login {}", login(&tcp));
    let held: Vec<_> = (0..300)
        .filter_map(|_| std::net::TcpStream::connect(at).ok())
        .collect();
    println!(
        "tcp, {} silent connections held: console login {}",
        held.len(),
        login(&tcp)
    );
}
