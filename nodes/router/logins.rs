//! Refused logins, logged at WARN with their source address and
//! rate-limited. zenoh reports each inbound link it refuses before the link
//! became a session (a TLS handshake that failed or timed out, a wrong user
//! or password, a handshake not finished within the accept time-out, too
//! many handshakes pending) at DEBUG on [`REFUSED_LINK_TARGET`], with the
//! remote locator and the reason; that report is our patch of zenoh
//! (`patches/zenoh-transport`, `patches/zenoh-link-tls`), since zenoh 1.10.2
//! names no address. This module listens to that target alone and turns the
//! reports into log lines.
//!
//! The rate limit ([`RefusalLog`], sans-I/O with the clock passed in): in
//! each window of [`WINDOW`] the first refusal from each source host is
//! logged in full, for at most [`HOSTS_PER_WINDOW`] hosts; the rest are
//! counted and summed up in one line when the window ends. So a mistyped
//! password is one line, and 500 strangers are a handful of lines, not 500.

use std::collections::{HashMap, HashSet};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::mpsc::{channel, Receiver, Sender};
use tracing::field::{Field, Visit};
use tracing_subscriber::filter::Targets;
use tracing_subscriber::layer::Context;
use tracing_subscriber::Layer;

/// The target our zenoh patches report refused links on.
pub const REFUSED_LINK_TARGET: &str = "zenoh::refused_link";
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
    /// The remote locator, e.g. `tls/10.77.0.5:50312`.
    pub remote: String,
    /// Why zenoh refused it.
    pub reason: String,
}

impl Refusal {
    /// The remote's host (its IP address), the unit of the rate limit; the
    /// whole locator when it names no socket address.
    pub fn host(&self) -> String {
        let address = self
            .remote
            .split_once('/')
            .map_or(self.remote.as_str(), |(_, a)| a);
        let address = address.split_once('#').map_or(address, |(a, _)| a);
        address
            .parse::<SocketAddr>()
            .map_or_else(|_| address.to_string(), |a| a.ip().to_string())
    }
}

/// What to log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Report {
    /// A refusal logged in full.
    Refused {
        /// The source host.
        host: String,
        /// The refusal.
        refusal: Refusal,
    },
    /// The refusals of a window that were not logged one by one.
    HeldBack {
        /// How many.
        count: u64,
        /// From how many source hosts.
        hosts: usize,
        /// The host most of them came from, and its count.
        busiest: (String, u64),
    },
}

struct Window {
    start: Instant,
    logged: HashSet<String>,
    held_back: HashMap<String, u64>,
}

/// The rate limit: refusals in, reports out.
pub struct RefusalLog {
    window: Duration,
    hosts_per_window: usize,
    current: Option<Window>,
}

impl RefusalLog {
    /// A limit of `hosts_per_window` lines in each `window`.
    pub fn new(window: Duration, hosts_per_window: usize) -> Self {
        Self {
            window,
            hosts_per_window,
            current: None,
        }
    }

    /// A refusal at `now`: the summary of a window that is over, if any,
    /// then this refusal if it is to be logged.
    pub fn refused(&mut self, now: Instant, refusal: Refusal) -> Vec<Report> {
        let mut out: Vec<Report> = self.poll(now).into_iter().collect();
        let window = self.current.get_or_insert_with(|| Window {
            start: now,
            logged: HashSet::new(),
            held_back: HashMap::new(),
        });
        let host = refusal.host();
        if window.logged.len() < self.hosts_per_window && window.logged.insert(host.clone()) {
            out.push(Report::Refused { host, refusal });
        } else {
            *window.held_back.entry(host).or_default() += 1;
        }
        out
    }

    /// `count` refusals whose details were lost (the queue was full).
    pub fn lost(&mut self, now: Instant, count: u64) -> Vec<Report> {
        let out: Vec<Report> = self.poll(now).into_iter().collect();
        let window = self.current.get_or_insert_with(|| Window {
            start: now,
            logged: HashSet::new(),
            held_back: HashMap::new(),
        });
        *window.held_back.entry("unknown".into()).or_default() += count;
        out
    }

    /// Ends the window if it is over: its summary, if anything was held back.
    pub fn poll(&mut self, now: Instant) -> Option<Report> {
        let window = self.current.as_ref()?;
        if now < window.start + self.window {
            return None;
        }
        let window = self.current.take()?;
        let count = window.held_back.values().sum();
        let busiest = window
            .held_back
            .iter()
            .max_by(|a, b| a.1.cmp(b.1).then_with(|| b.0.cmp(a.0)))
            .map(|(h, n)| (h.clone(), *n))?;
        Some(Report::HeldBack {
            count,
            hosts: window.held_back.len(),
            busiest,
        })
    }

    /// When the current window ends.
    pub fn deadline(&self) -> Option<Instant> {
        self.current.as_ref().map(|w| w.start + self.window)
    }
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

#[derive(Default)]
struct Fields {
    remote: String,
    reason: String,
}

impl Visit for Fields {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        match field.name() {
            "remote" => self.remote = printable(&format!("{value:?}")),
            "reason" => self.reason = printable(without_location(&format!("{value:?}"))),
            _ => {}
        }
    }
    fn record_str(&mut self, field: &Field, value: &str) {
        match field.name() {
            "remote" => self.remote = printable(value),
            "reason" => self.reason = printable(without_location(value)),
            _ => {}
        }
    }
}

impl<S: tracing::Subscriber> Layer<S> for RefusalLayer {
    fn on_event(&self, event: &tracing::Event<'_>, _ctx: Context<'_, S>) {
        let mut f = Fields::default();
        event.record(&mut f);
        let refusal = Refusal {
            remote: f.remote,
            reason: f.reason,
        };
        if self.tx.try_send(refusal).is_err() {
            self.lost.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The layer that collects zenoh's refused-link reports (listening to that
/// target alone), and the receiving end for [`report`].
pub fn layer<S>() -> (impl Layer<S>, Refusals)
where
    S: tracing::Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
{
    let (tx, rx) = channel(QUEUE);
    let lost = Arc::new(AtomicU64::new(0));
    let layer = RefusalLayer {
        tx,
        lost: lost.clone(),
    }
    .with_filter(Targets::new().with_target(REFUSED_LINK_TARGET, tracing::Level::DEBUG));
    (layer, Refusals { rx, lost })
}

/// Logs refused logins at WARN, rate-limited by [`RefusalLog`], until the
/// layer is gone.
pub async fn report(mut refusals: Refusals) {
    let mut log = RefusalLog::new(WINDOW, HOSTS_PER_WINDOW);
    loop {
        let deadline = log.deadline().map(tokio::time::Instant::from_std);
        let reports = tokio::select! {
            next = refusals.rx.recv() => match next {
                Some(refusal) => {
                    let now = Instant::now();
                    let mut out = log.refused(now, refusal);
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

fn emit(report: &Report) {
    match report {
        Report::Refused { host, refusal } => tracing::warn!(
            target: "falc_router::logins",
            source = %host,
            link = %refusal.remote,
            "refused login from {host}: {}",
            refusal.reason
        ),
        Report::HeldBack {
            count,
            hosts,
            busiest: (busiest, most),
        } => tracing::warn!(
            target: "falc_router::logins",
            "refused logins: {count} more from {hosts} host(s) in the last {} s not logged one by one; most from {busiest} ({most})",
            WINDOW.as_secs()
        ),
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
            remote: remote.into(),
            reason: "UsrPwd extension - Recv OpenSyn. Invalid password for user \"console\"."
                .into(),
        }
    }

    fn logged(reports: &[Report]) -> Vec<String> {
        reports
            .iter()
            .filter_map(|r| match r {
                Report::Refused { host, .. } => Some(host.clone()),
                Report::HeldBack { .. } => None,
            })
            .collect()
    }

    #[test]
    fn the_host_is_the_ip_of_the_locator() {
        assert_eq!(refusal("tls/10.77.0.5:50312").host(), "10.77.0.5");
        assert_eq!(refusal("tcp/[::1]:7447").host(), "::1");
        assert_eq!(refusal("tcp/127.0.0.1:9#iface=lo").host(), "127.0.0.1");
        assert_eq!(refusal("serial/ttyS0").host(), "ttyS0");
    }

    #[test]
    fn one_line_per_host_per_window_then_a_summary() {
        let t0 = Instant::now();
        let mut log = RefusalLog::new(Duration::from_secs(10), 3);
        let first = log.refused(t0, refusal("tcp/127.0.0.1:1000"));
        assert_eq!(logged(&first), ["127.0.0.1"]);
        for i in 1..500u64 {
            let r = log.refused(
                t0 + Duration::from_millis(i),
                refusal(&format!("tcp/127.0.0.1:{}", 1000 + i)),
            );
            assert!(r.is_empty(), "refusal {i}: {r:?}");
        }
        assert_eq!(log.poll(t0 + Duration::from_secs(9)), None);
        assert_eq!(log.deadline(), Some(t0 + Duration::from_secs(10)));
        assert_eq!(
            log.poll(t0 + Duration::from_secs(10)),
            Some(Report::HeldBack {
                count: 499,
                hosts: 1,
                busiest: ("127.0.0.1".into(), 499)
            })
        );
        assert_eq!(log.deadline(), None, "the window is over");
        // The next window logs the host again.
        let again = log.refused(t0 + Duration::from_secs(11), refusal("tcp/127.0.0.1:2"));
        assert_eq!(logged(&again), ["127.0.0.1"]);
    }

    #[test]
    fn many_hosts_get_at_most_the_limit_of_lines() {
        let t0 = Instant::now();
        let mut log = RefusalLog::new(Duration::from_secs(10), 3);
        let mut lines = Vec::new();
        for i in 1..=20 {
            lines.extend(logged(
                &log.refused(t0, refusal(&format!("tls/10.0.0.{i}:5"))),
            ));
        }
        lines.extend(logged(&log.refused(t0, refusal("tls/10.0.0.20:6"))));
        assert_eq!(lines, ["10.0.0.1", "10.0.0.2", "10.0.0.3"]);
        // A window that is over is summed up by the next refusal too.
        let next = log.refused(t0 + Duration::from_secs(10), refusal("tls/10.0.0.9:5"));
        assert_eq!(
            next,
            vec![
                Report::HeldBack {
                    count: 18,
                    hosts: 17,
                    busiest: ("10.0.0.20".into(), 2)
                },
                Report::Refused {
                    host: "10.0.0.9".into(),
                    refusal: refusal("tls/10.0.0.9:5")
                }
            ]
        );
    }

    #[test]
    fn a_window_with_nothing_held_back_ends_silently() {
        let t0 = Instant::now();
        let mut log = RefusalLog::new(Duration::from_secs(10), 3);
        assert_eq!(logged(&log.refused(t0, refusal("tcp/10.0.0.1:1"))).len(), 1);
        assert_eq!(log.poll(t0 + Duration::from_secs(10)), None);
        assert_eq!(log.deadline(), None);
    }

    #[test]
    fn lost_refusals_are_counted() {
        let t0 = Instant::now();
        let mut log = RefusalLog::new(Duration::from_secs(10), 3);
        assert!(log.lost(t0, 7).is_empty());
        assert_eq!(
            log.poll(t0 + Duration::from_secs(10)),
            Some(Report::HeldBack {
                count: 7,
                hosts: 1,
                busiest: ("unknown".into(), 7)
            })
        );
    }

    #[test]
    fn zenoh_source_locations_are_cut() {
        assert_eq!(
            without_location("UsrPwd extension - Recv OpenSyn. Invalid password for user \"x\". at patches/zenoh-transport/src/unicast/establishment/ext/auth/usrpwd.rs:426."),
            "UsrPwd extension - Recv OpenSyn. Invalid password for user \"x\"."
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
