//! The soak: the whole cell on the secure transport (QUIC with mutual TLS)
//! on this machine, dikdroog orders back to back for `FALC_SOAK_MINUTES`
//! (default 30), while a console asks the operator for the cell's status
//! as fast as it is answered (sustained traffic through the router beside
//! the orders). Prints the orders done and failed (each failure's cause;
//! the way back is the documented one: carriers set back, `ack`), the
//! status calls answered, and the links dropped: orders failed for a lost
//! station and looks at the status that found a station off the bus. Not
//! part of CI.
//!
//! Run: `cargo bench --bench soak` (`FALC_SOAK_MINUTES=2` for a short one).

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

use falc_model::api::ApiRequest;
use falc_model::records::OrderState;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use support::rig::rig_secure;

fn main() {
    let minutes: u64 = std::env::var("FALC_SOAK_MINUTES")
        .ok()
        .and_then(|m| m.parse().ok())
        .unwrap_or(30);
    let mut rig = rig_secure("20");
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
                        Ok(falc_model::api::ApiReply::Status(s)) => {
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
    let (mut done, mut failed, mut lost) = (0u64, 0u64, 0u64);
    while Instant::now() < end {
        rig.cell.falc(&["order", "add", "dikdroog"]);
        rig.cell.falc(&["start"]);
        rig.work_list("ja", Duration::from_secs(180));
        let last = rig.orders().pop();
        match last.as_ref().map(|o| o.state) {
            Some(OrderState::Done) => done += 1,
            _ => {
                failed += 1;
                let why = last.and_then(|o| o.result).unwrap_or_default();
                if why.contains("no connection") {
                    lost += 1;
                }
                println!("order failed: {why}");
                // The way back: carriers where an order starts, ack.
                rig.plc.control("layout W2 W2");
                rig.cell.falc(&["ack"]);
            }
        }
    }
    stop.store(true, Ordering::Relaxed);
    load.join().expect("the console's load");
    let refused = rig.cell.router.lines_containing("refused login").len();
    println!(
        "soak over quic for {:.1} min: {done} orders done, {failed} failed; {} status calls answered, {} unanswered; links dropped: {lost} orders failed for a lost station, {} looks with a station off the bus; {refused} refused logins",
        begin.elapsed().as_secs_f64() / 60.0,
        answered.load(Ordering::Relaxed),
        unanswered.load(Ordering::Relaxed),
        off_bus.load(Ordering::Relaxed),
    );
}
