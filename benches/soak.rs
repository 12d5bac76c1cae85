//! The soak: the whole cell on the secure transport (QUIC with mutual TLS)
//! on this machine, dikdroog orders back to back for `FALC_SOAK_MINUTES`
//! (default 30), while a console asks the operator for the cell's status
//! as fast as it is answered (sustained traffic through the router beside
//! the orders). Prints the orders done and failed, the status calls
//! answered, and the links dropped: every alarm the cell raised and every
//! look at the status that found a station off the bus. Not part of CI.
//!
//! Run: `cargo bench --bench soak` (`FALC_SOAK_MINUTES=2` for a short one).

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

use falc_model::console::{ApiRequest, OrderState};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use support::rig::rig_secure;

fn main() {
    let minutes: u64 = std::env::var("FALC_SOAK_MINUTES")
        .ok()
        .and_then(|m| m.parse().ok())
        .unwrap_or(30);
    let rig = rig_secure("20");
    let settings = rig.cell.settings("console");
    let operator = rig.cell.topology.root().name.clone();
    let stop = Arc::new(AtomicBool::new(false));
    let (answered, unanswered, off_bus) = (
        Arc::new(AtomicU64::new(0)),
        Arc::new(AtomicU64::new(0)),
        Arc::new(AtomicU64::new(0)),
    );
    let load = {
        let (stop, answered, unanswered, off_bus) = (
            stop.clone(),
            answered.clone(),
            unanswered.clone(),
            off_bus.clone(),
        );
        std::thread::spawn(move || {
            let rt = tokio::runtime::Runtime::new().expect("runtime");
            rt.block_on(async move {
                let bus = falc_bus::Bus::open(settings).await.expect("console");
                while !stop.load(Ordering::Relaxed) {
                    match bus
                        .api(&operator, ApiRequest::Status, Duration::from_secs(5))
                        .await
                    {
                        Ok(falc_model::console::ApiReply::Status(s)) => {
                            answered.fetch_add(1, Ordering::Relaxed);
                            if s.stations.iter().any(|v| !v.connected) {
                                off_bus.fetch_add(1, Ordering::Relaxed);
                            }
                        }
                        _ => {
                            unanswered.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                }
            })
        })
    };
    let end = Instant::now() + Duration::from_secs(minutes * 60);
    let begin = Instant::now();
    let (mut done, mut failed) = (0u64, 0u64);
    while Instant::now() < end {
        rig.cell.falc(&["order", "add", "dikdroog"]);
        rig.cell.falc(&["start"]);
        rig.work_list("ja", Duration::from_secs(180));
        match rig.orders().last().map(|o| o.state) {
            Some(OrderState::Done) => done += 1,
            _ => {
                failed += 1;
                rig.cell.falc(&["ack"]);
            }
        }
    }
    stop.store(true, Ordering::Relaxed);
    load.join().expect("the console's load");
    let alarms = rig.status().alarms.len();
    let lost = rig.cell.router.lines_containing("refused login").len();
    println!(
        "soak over quic for {:.1} min: {done} orders done, {failed} failed; {} status calls answered, {} unanswered; links dropped: {alarms} alarms raised, {} looks with a station off the bus; {lost} refused logins",
        begin.elapsed().as_secs_f64() / 60.0,
        answered.load(Ordering::Relaxed),
        unanswered.load(Ordering::Relaxed),
        off_bus.load(Ordering::Relaxed),
    );
}
