//! What floods of strangers do to logins when nothing but zenoh stands
//! between them and the router: a router on this machine, no firewall, a
//! console logging in (its session opened, allowed up to 60 s) while
//! strangers hold the port. Side by side in one run:
//! - `quic/…` with no flood, with 300 silent QUIC handshakes held open, and
//!   during 20 and during 100 failing QUIC handshakes a second for 30 s (a
//!   login every 5 s, and one right after);
//! - `tcp/…` with no flood and with 1,000 silent TCP connections held
//!   open for 40 s, each the router drops opened again at once (a login
//!   every 1.3 s, 3 s allowed, and one right after).
//!
//! This is why the router's PC runs `falc-router firewall` (the flood test
//! in `tests/hosts.rs` shows a console getting in behind it). Run:
//! `cargo bench --bench flood [-- --only tcp|quic]`. Prints figures;
//! asserts nothing about time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

use std::net::SocketAddr;
use std::time::{Duration, Instant};
use support::{flood, TestCell};

/// A console's login: its time, or the error after the 60 s allowed.
fn login(cell: &TestCell) -> String {
    login_within(cell, Duration::from_secs(60))
}

/// A console's login given `limit`: its time, or the error after it.
fn login_within(cell: &TestCell, limit: Duration) -> String {
    let mut settings = cell.settings("console");
    settings.connect_timeout = limit;
    let rt = tokio::runtime::Runtime::new().expect("runtime");
    rt.block_on(async move {
        let begin = Instant::now();
        match falc_bus::Bus::open(settings).await {
            Ok(bus) => {
                let took = begin.elapsed();
                let _ = bus.session().close().await;
                format!("{:.1} ms", took.as_secs_f64() * 1000.0)
            }
            Err(e) => format!(
                "no login within {:.1} s ({e})",
                begin.elapsed().as_secs_f64()
            ),
        }
    })
}

/// Console logins every `every` during a stranger's flood that runs on
/// another thread for `lasting`, then one right after it: what each took.
fn logins_during(
    cell: &TestCell,
    every: Duration,
    lasting: Duration,
    flood: impl FnOnce() -> String + Send + 'static,
) -> (Vec<String>, String, String) {
    let strangers = std::thread::spawn(flood);
    let mut during = Vec::new();
    let end = Instant::now() + lasting;
    while Instant::now() + every < end {
        // A pace: a login every `every` while the flood lasts.
        std::thread::sleep(every);
        during.push(login(cell));
    }
    let what = strangers.join().expect("strangers");
    (during, login(cell), what)
}

fn main() {
    // `-- --only tcp` or `-- --only quic`: one transport's cases.
    let args: Vec<String> = std::env::args().collect();
    let only = args
        .iter()
        .position(|a| a == "--only")
        .and_then(|i| args.get(i + 1))
        .cloned();
    if only.as_deref() != Some("tcp") {
        quic_floods();
    }
    if only.as_deref() != Some("quic") {
        tcp_flood();
    }
}

fn quic_floods() {
    println!(
        "zenoh's QUIC accept throttle: {} µs after each failed handshake (.cargo/config.toml [env]; zenoh's default 100,000)",
        option_env!("QUIC_ACCEPT_THROTTLE_TIME").unwrap_or("100000 (zenoh's default)")
    );
    let quic = TestCell::start_secure();
    let router = quic.address();
    println!("quic, no flood: console login {}", login(&quic));
    let held = flood::silent_handshakes(router, 300);
    println!(
        "quic, 300 silent handshakes held: console login {} (a70706b: none for 61.3 s; QUIC's idle time-out bounds it now, zenoh#2719)",
        login(&quic)
    );
    drop(held);
    println!(
        "quic, right after the silent ones left: console login {}",
        login(&quic)
    );
    // Let the router's queue drain before the next case.
    std::thread::sleep(Duration::from_secs(35));
    // What a70706b (zenoh's 100 ms throttle) measured at each rate.
    let before = |per_second: u32| match per_second {
        20 => "no login until 62.6 s after the flood (the attack run)",
        _ => "4 of 5 logins none within 60 s, the fifth 41.7 s",
    };
    for per_second in [20, 100] {
        let (during, after, what) = logins_during(
            &quic,
            Duration::from_secs(5),
            Duration::from_secs(30),
            move || {
                let f = flood::failing_handshakes(router, per_second, Duration::from_secs(30));
                format!("{} begun, {} answered by the router", f.begun, f.answered)
            },
        );
        println!(
            "quic, {per_second} failing handshakes a second for 30 s ({what}): console logins during {during:?}, right after {after} (a70706b: {})",
            before(per_second)
        );
        std::thread::sleep(Duration::from_secs(35));
    }
}

fn tcp_flood() {
    let tcp = TestCell::start();
    let at = tcp.address();
    println!("tcp, no flood: console login {}", login(&tcp));
    // A thousand silent connections held for 40 s: each one the router
    // drops (its handshake timeout) opened again at once.
    let (during, after, what) = logins_within_during(&tcp, at);
    let failed = during.iter().filter(|l| l.starts_with("no login")).count();
    println!(
        "tcp, 1,000 silent connections held 40 s ({what}): {} console logins (3 s allowed each), {failed} failed, slowest {:.1} ms; right after {after} \
         (a70706b: 2 of 31 failed, slowest 4.9 s; with zenoh's one login thread: 5 of 19 failed, the slow ones 3.1–3.7 s)",
        during.len(),
        during
            .iter()
            .filter_map(|l| l.strip_suffix(" ms").and_then(|m| m.parse::<f64>().ok()))
            .fold(0.0_f64, f64::max)
    );
    for l in during.iter().filter(|l| l.starts_with("no login")) {
        println!("  {l}");
    }
}

/// Logins (3 s allowed) every 1.3 s while 1,000 silent TCP connections are
/// held open at `at` for 40 s, and one right after.
fn logins_within_during(cell: &TestCell, at: SocketAddr) -> (Vec<String>, String, String) {
    let stop = Instant::now() + Duration::from_secs(40);
    let strangers = std::thread::spawn(move || {
        let opened = flood::silent_tcp_connections(at, 1_000, stop);
        format!("{opened} connections opened")
    });
    let mut during = Vec::new();
    while Instant::now() + Duration::from_millis(1_300) < stop {
        // A pace: a login every 1.3 s while the flood lasts.
        std::thread::sleep(Duration::from_millis(1_300));
        during.push(login_within(cell, Duration::from_secs(3)));
    }
    let what = strangers.join().expect("strangers");
    (during, login(cell), what)
}
