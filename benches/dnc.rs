//! DNC benchmark over a real pty with the twin emulating a 9600 baud line
//! (each byte takes 10 bit times, both ways). Prints, side by side with the
//! twin's modelled wire time of the same bytes (the time the twin's own
//! model of a 9600 baud line gives them, not a measurement of a wire):
//! - the select + start round trip (S064 → ack, G → ack);
//! - the program-end notification latency (end telegram on the wire, from
//!   the moment the program's time is up to the driver's event).
//!
//! Run: `cargo bench --bench dnc`. Prints figures; asserts nothing about
//! time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

use falc_dnc::procedure::{frame, Link, LinkEvent, Priority, Timing};
use falc_dnc::telegram::Telegram;
use falc_model::ids::RobotProgram;
use falc_node::dnc_link::{self, DncHandle, LineSettings};
use std::time::{Duration, Instant};
use support::stats::median;

const BAUD: u32 = 9600;
const ROUNDS: usize = 20;
const TIME_SCALE: f64 = 100.0;

/// Bytes on the wire for one telegram: STX, DLE, the block, DLE.
fn wire_bytes(t: &Telegram) -> usize {
    1 + 1 + frame(&t.encode()).len() + 1
}

fn wire_time(bytes: usize) -> Duration {
    Duration::from_secs_f64(bytes as f64 * 10.0 / f64::from(BAUD))
}

async fn next(h: &mut DncHandle) -> Telegram {
    loop {
        match tokio::time::timeout(Duration::from_secs(20), h.events.recv()).await {
            Ok(Some(LinkEvent::Received(t))) => return Telegram::decode(&t).expect("valid"),
            Ok(Some(LinkEvent::Sent(_) | LinkEvent::Refused(_) | LinkEvent::Silent(_))) => continue,
            other => panic!("no telegram: {other:?}"),
        }
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

#[tokio::main]
async fn main() {
    let (_rcm, path) = support::twin(
        env!("CARGO_BIN_EXE_falc-rcm-sim"),
        &[
            "--wire-baud",
            &BAUD.to_string(),
            "--time-scale",
            &TIME_SCALE.to_string(),
        ],
        "serial port: ",
    );
    let port = dnc_link::open_serial(&LineSettings {
        path,
        baud: BAUD,
        parity: "none".into(),
    })
    .expect("pty");
    let mut h = dnc_link::spawn(
        port,
        Link::new(Priority::Low, Timing::default()).awaiting_answers(),
    );
    let p64 = RobotProgram::of(64);
    let duration = Duration::from_secs(60).div_f64(TIME_SCALE);
    let ack = |of| Telegram::Ack { of, error: None };
    let select_start_wire = wire_time(
        wire_bytes(&Telegram::SelectProgram(p64))
            + wire_bytes(&ack(b'S'))
            + wire_bytes(&Telegram::StartProgram)
            + wire_bytes(&ack(b'G')),
    );
    let end = Telegram::ProgramEnd {
        program: p64,
        result: falc_dnc::telegram::EndResult::Complete,
    };
    let end_wire = wire_time(wire_bytes(&end));
    let (mut rtt, mut end_lat) = (Vec::new(), Vec::new());
    for _ in 0..ROUNDS {
        let t = Instant::now();
        h.send
            .send(Telegram::SelectProgram(p64).encode())
            .expect("driver");
        assert_eq!(next(&mut h).await, ack(b'S'));
        h.send
            .send(Telegram::StartProgram.encode())
            .expect("driver");
        assert_eq!(next(&mut h).await, ack(b'G'));
        let started = Instant::now();
        rtt.push(started - t);
        // The twin's status telegram follows the ack; then the end.
        loop {
            match next(&mut h).await {
                Telegram::ProgramEnd { .. } => break,
                _ => continue,
            }
        }
        // The program ran from the twin's start (about when its ack left,
        // one ack's wire time before we had it) for `duration`.
        let due = started - wire_time(wire_bytes(&ack(b'G'))) + duration;
        end_lat.push(Instant::now().saturating_duration_since(due));
    }
    let (r, e) = (median(&rtt), median(&end_lat));
    println!("DNC over a pty, twin at {BAUD} baud wire timing, n={ROUNDS}:");
    println!(
        "  select + start round trip : median {:7.2} ms; the twin's modelled wire time {:7.2} ms; ratio {:.3} (goal ≤ 1.2)",
        ms(r),
        ms(select_start_wire),
        ms(r) / ms(select_start_wire)
    );
    println!(
        "  program-end notification  : median {:7.2} ms; the twin's modelled wire time {:7.2} ms; ratio {:.3} (goal ≤ 1.2)",
        ms(e),
        ms(end_wire),
        ms(e) / ms(end_wire)
    );
}
