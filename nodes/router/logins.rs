//! Refused logins, logged at WARN, rate-limited. zenoh 1.10 reports the
//! links it refuses in its own log lines, on several targets and levels:
//!
//! | target | level | what |
//! |---|---|---|
//! | `zenoh_link_commons::quic…` | WARN, ERROR | a QUIC handshake that failed: another CA, no client certificate, a time-out |
//! | `zenoh_transport::unicast::establishment::accept` | DEBUG, ERROR | a zenoh login refused: a wrong user or password, a broken handshake |
//! | `zenoh_transport::unicast::manager` | DEBUG, TRACE | a login not finished within the accept time-out, too many pending |
//!
//! [`classify`] picks those out of everything those targets log; this
//! module listens to them alone and turns them into one kind of line.
//! zenoh names the remote address in few of them (upstream issue
//! eclipse-zenoh/zenoh#2712): where it does, the line names it; where not,
//! the source is `unreported` and the router's firewall log rule
//! (`falc-router firewall`) names the addresses that knocked.
//!
//! The rate limit ([`falc_bus::log_limit::LogLimit`], keyed by source
//! host): in each window of [`WINDOW`] the first refusal from each source
//! host is logged in full, for at most [`HOSTS_PER_WINDOW`] hosts; the rest
//! are counted and summed up in one line when the window ends. So a
//! mistyped password is one line, and 500 strangers are a handful of
//! lines, not 500.

use falc_bus::log_limit::{LogLimit, Report};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::mpsc::{channel, Receiver, Sender};
use tracing::field::{Field, Visit};
use tracing_subscriber::filter::Targets;
use tracing_subscriber::layer::Context;
use tracing_subscriber::Layer;

/// What a refusal's source is called when zenoh did not name it.
pub const UNREPORTED: &str = "unreported";
/// The length of one rate-limit window.
pub const WINDOW: Duration = Duration::from_secs(10);
/// How many source hosts per window get a line of their own.
pub const HOSTS_PER_WINDOW: usize = 10;
/// The longest remote or reason text logged (both may come from a stranger).
const MAX_TEXT: usize = 200;
/// Refusals queued between zenoh's tasks and the reporter; beyond this they
/// are only counted.
const QUEUE: usize = 4096;

/// One link zenoh refused.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Refusal {
    /// The remote's socket address, where zenoh's line names it.
    pub remote: Option<SocketAddr>,
    /// Why zenoh refused it.
    pub reason: String,
}

impl Refusal {
    /// The remote's host (its IP address), the unit of the rate limit;
    /// [`UNREPORTED`] when zenoh did not name it.
    pub fn host(&self) -> String {
        self.remote
            .map_or_else(|| UNREPORTED.to_string(), |a| a.ip().to_string())
    }
}

/// Whether zenoh's log line `message` on `target` reports a refused link,
/// and if so the refusal, with the remote address where the line names one.
pub fn classify(target: &str, message: &str) -> Option<Refusal> {
    let quic =
        target.starts_with("zenoh_link_commons::quic") || target.starts_with("zenoh_link_quic");
    let refused = if quic {
        message.contains("QUIC acceptor failed") || message.starts_with("Cannot accept QUIC")
    } else if target == "zenoh_transport::unicast::establishment::accept" {
        !message.starts_with("New transport link accepted")
            && !message.starts_with("Establishment Accept")
    } else if target == "zenoh_transport::unicast::manager" {
        message.starts_with("Failed to accept link before deadline")
            || message.starts_with("Closing link for preventing potential DoS")
    } else {
        false
    };
    if !refused {
        return None;
    }
    let reason = message
        .split(" Hint: increase the system open file limit")
        .next()
        .unwrap_or(message);
    Some(Refusal {
        remote: remote_in(message),
        reason: printable(without_location(reason.trim_end())),
    })
}

/// The remote address in a zenoh line: a link shown as `local => remote`
/// or as `… dst: remote …`.
fn remote_in(message: &str) -> Option<SocketAddr> {
    ["=> ", "dst: "].iter().find_map(|marker| {
        let (_, after) = message.split_once(marker)?;
        let token: String = after
            .chars()
            .take_while(|c| !c.is_whitespace() && !matches!(c, ',' | ')' | '}' | '"'))
            .collect();
        let token = token.split_once('/').map_or(token.as_str(), |(_, a)| a);
        token.trim_end_matches('.').parse().ok()
    })
}

/// Refusals as zenoh reported them, for [`report`].
pub struct Refusals {
    rx: Receiver<Refusal>,
    lost: Arc<AtomicU64>,
}

struct RefusalLayer {
    tx: Sender<Refusal>,
    lost: Arc<AtomicU64>,
}

/// The message of one zenoh event.
#[derive(Default)]
struct Message(String);

impl Visit for Message {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            self.0 = format!("{value:?}");
        }
    }
    fn record_str(&mut self, field: &Field, value: &str) {
        if field.name() == "message" {
            self.0 = value.to_string();
        }
    }
}

impl<S: tracing::Subscriber> Layer<S> for RefusalLayer {
    fn on_event(&self, event: &tracing::Event<'_>, _ctx: Context<'_, S>) {
        let mut m = Message::default();
        event.record(&mut m);
        let Some(refusal) = classify(event.metadata().target(), &m.0) else {
            return;
        };
        if self.tx.try_send(refusal).is_err() {
            self.lost.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The layer that collects zenoh's reports of refused links (listening to
/// the targets of [`classify`] alone), and the receiving end for [`report`].
pub fn layer<S>() -> (impl Layer<S>, Refusals)
where
    S: tracing::Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
{
    use tracing::Level;
    let (tx, rx) = channel(QUEUE);
    let lost = Arc::new(AtomicU64::new(0));
    let layer = RefusalLayer {
        tx,
        lost: lost.clone(),
    }
    .with_filter(
        Targets::new()
            .with_target("zenoh_link_commons::quic", Level::WARN)
            .with_target("zenoh_link_quic", Level::WARN)
            .with_target(
                "zenoh_transport::unicast::establishment::accept",
                Level::DEBUG,
            )
            .with_target("zenoh_transport::unicast::manager", Level::TRACE),
    );
    (layer, Refusals { rx, lost })
}

/// Logs refused logins at WARN, rate-limited by [`LogLimit`], until the
/// layer is gone.
pub async fn report(mut refusals: Refusals) {
    let mut log = LogLimit::new(WINDOW, HOSTS_PER_WINDOW);
    loop {
        let deadline = log.deadline().map(tokio::time::Instant::from_std);
        let reports = tokio::select! {
            next = refusals.rx.recv() => match next {
                Some(refusal) => {
                    let now = Instant::now();
                    let mut out = log.offer(now, refusal.host(), refusal);
                    let lost = refusals.lost.swap(0, Ordering::Relaxed);
                    if lost > 0 {
                        out.extend(log.lost(now, lost));
                    }
                    out
                }
                None => return,
            },
            () = sleep_until(deadline) => log.poll(Instant::now()).into_iter().collect(),
        };
        for r in reports {
            emit(&r);
        }
    }
}

async fn sleep_until(deadline: Option<tokio::time::Instant>) {
    match deadline {
        Some(d) => tokio::time::sleep_until(d).await,
        None => std::future::pending().await,
    }
}

fn emit(report: &Report<Refusal>) {
    match report {
        Report::Logged {
            source: host,
            item: refusal,
        } if refusal.remote.is_none() => tracing::warn!(
            target: "falc_router::logins",
            source = %host,
            "refused login (zenoh names no source address, zenoh#2712; the firewall's log \
             rule does): {}",
            refusal.reason
        ),
        Report::Logged {
            source: host,
            item: refusal,
        } => tracing::warn!(
            target: "falc_router::logins",
            source = %host,
            "refused login from {host}: {}",
            refusal.reason
        ),
        held @ Report::HeldBack { .. } => {
            if let Some(line) = held.summary("refusals", "host", WINDOW) {
                tracing::warn!(target: "falc_router::logins", "refused logins: {line}");
            }
        }
    }
}

/// A zenoh error's text without the source location zenoh appends
/// (" at src/…/usrpwd.rs:426.").
fn without_location(text: &str) -> &str {
    match text.rsplit_once(" at ") {
        Some((head, tail)) if tail.trim_end_matches('.').rsplit_once(".rs:").is_some() => head,
        _ => text,
    }
}

/// `text` cut to [`MAX_TEXT`] characters with control characters escaped:
/// what a stranger sends must not forge log lines.
fn printable(text: &str) -> String {
    let mut out = String::new();
    for (i, c) in text.chars().enumerate() {
        if i == MAX_TEXT {
            out.push('…');
            break;
        }
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn refusal(remote: &str) -> Refusal {
        Refusal {
            remote: remote_in(&format!("=> {remote}")),
            reason: "UsrPwd extension - Recv OpenSyn. Invalid password.".into(),
        }
    }

    #[test]
    fn the_host_is_the_ip_of_the_remote_or_unreported() {
        assert_eq!(refusal("10.77.0.5:50312").host(), "10.77.0.5");
        assert_eq!(refusal("[::1]:7447").host(), "::1");
        assert_eq!(refusal("quic/127.0.0.1:9").host(), "127.0.0.1");
        assert_eq!(refusal("ttyS0").host(), UNREPORTED);
    }

    #[test]
    fn zenohs_refusals_are_picked_out_of_its_lines() {
        let accept = "zenoh_transport::unicast::establishment::accept";
        let r = classify(
            accept,
            "UsrPwd extension - Recv OpenSyn. Invalid password. at /x/zenoh-transport-1.10.2/src/unicast/establishment/ext/auth/usrpwd.rs:424.",
        )
        .expect("a wrong password is a refusal");
        assert_eq!(
            r.reason,
            "UsrPwd extension - Recv OpenSyn. Invalid password."
        );
        assert_eq!(r.host(), UNREPORTED);
        assert_eq!(
            classify(accept, "New transport link accepted from a to b: x"),
            None
        );
        let quic = classify(
            "zenoh_link_commons::quic::unicast",
            "QUIC acceptor failed: ConnectionLost(TransportError(Error { code: Code::crypto(30) })) Hint: increase the system open file limit.",
        )
        .expect("a failed QUIC handshake is a refusal");
        assert!(!quic.reason.contains("Hint"), "{}", quic.reason);
        let manager = "zenoh_transport::unicast::manager";
        let dos = classify(
            manager,
            "Closing link for preventing potential DoS: 10.0.0.1:7447 => 10.0.0.7:40112",
        )
        .expect("too many pending");
        assert_eq!(dos.host(), "10.0.0.7");
        assert!(classify(manager, "Failed to accept link before deadline (3000ms)").is_some());
        assert_eq!(classify(manager, "Will use Universal transport!"), None);
        assert_eq!(classify("zenoh::net::routing", "Invalid password."), None);
        let debug = classify(
            accept,
            "Received a close message (reason INVALID) instead of an OpenSyn on: Quic { src: 10.0.0.1:7447, dst: 10.0.0.8:5000 }",
        )
        .expect("a broken handshake");
        assert_eq!(debug.host(), "10.0.0.8");
    }

    #[test]
    fn zenoh_source_locations_are_cut() {
        assert_eq!(
            without_location("UsrPwd extension - Recv OpenSyn. Invalid password. at /r/zenoh-transport-1.10.2/src/unicast/establishment/ext/auth/usrpwd.rs:424."),
            "UsrPwd extension - Recv OpenSyn. Invalid password."
        );
        assert_eq!(
            without_location("received fatal alert: UnknownCA"),
            "received fatal alert: UnknownCA"
        );
        assert_eq!(
            without_location("no handshake at all"),
            "no handshake at all"
        );
    }

    #[test]
    fn stranger_text_cannot_forge_lines() {
        assert_eq!(printable("a\nWARN forged"), "a\\nWARN forged");
        let long = "x".repeat(500);
        assert_eq!(printable(&long).chars().count(), MAX_TEXT + 1);
    }
}
