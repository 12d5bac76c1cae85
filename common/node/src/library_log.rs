//! The libraries' own WARN and ERROR lines, rate-limited: zenoh's and
//! async-opcua's. Many of them are caused by a client (zenoh: a denied
//! declaration, a session in router mode; async-opcua: one ERROR line per
//! refused OPC UA login), and the library logs each one, so a client can
//! fill a node's log. Their lines do not name the client, so the unit of
//! the limit is the line's call site in the library (one kind of line):
//! through [`falc_bus::log_limit::LogLimit`], in each window of [`WINDOW`]
//! the first line of each call site is logged, for at most
//! [`SITES_PER_WINDOW`] sites; the rest are counted and summed up in one
//! line (target `falc_node::library_log`) when the window ends.
//!
//! The filter decides; a thread of its own writes the summaries, so no
//! line is logged from inside the logging of another.

use falc_bus::log_limit::{LogLimit, Report};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tracing::{Level, Metadata};
use tracing_subscriber::layer::{Context, Filter};

/// The length of one window.
pub const WINDOW: Duration = Duration::from_secs(10);
/// How many call sites per window get their lines through.
pub const SITES_PER_WINDOW: usize = 20;

/// The filter: lets everything through but the libraries' WARN and ERROR lines
/// beyond the limit.
pub struct LibraryLimit {
    limit: Arc<Mutex<LogLimit>>,
    /// Summaries of windows that ended at a line, for the thread.
    pending: Arc<Mutex<Vec<Report<()>>>>,
}

/// Whether a line of `meta` is one this filter limits.
fn limited(meta: &Metadata<'_>) -> bool {
    LIBRARIES.iter().any(|l| meta.target().starts_with(l)) && *meta.level() <= Level::WARN
}

/// The targets (crate-name prefixes) whose lines are limited.
pub const LIBRARIES: [&str; 2] = ["zenoh", "opcua"];

/// The call site a line comes from: the unit of the limit.
fn site(meta: &Metadata<'_>) -> String {
    format!(
        "{}:{}",
        meta.file().unwrap_or(meta.target()),
        meta.line().unwrap_or(0)
    )
}

/// Logs a window's summary.
fn summary(report: Report<()>) {
    if let Some(line) = report.summary(
        "library warnings and errors (zenoh, async-opcua)",
        "call site",
        WINDOW,
    ) {
        tracing::warn!("{line}");
    }
}

impl LibraryLimit {
    /// The filter, and the thread that writes its summaries.
    pub fn new() -> Self {
        let limit = Arc::new(Mutex::new(LogLimit::new(WINDOW, SITES_PER_WINDOW)));
        let pending = Arc::new(Mutex::new(Vec::new()));
        let ticks = Arc::downgrade(&limit);
        let kept = Arc::downgrade(&pending);
        let spawned = std::thread::Builder::new()
            .name("library-log-limit".into())
            .spawn(move || loop {
                std::thread::sleep(Duration::from_secs(1));
                let (Some(limit), Some(kept)) = (ticks.upgrade(), kept.upgrade()) else {
                    return;
                };
                let mut reports = match kept.lock() {
                    Ok(mut k) => std::mem::take(&mut *k),
                    Err(_) => return,
                };
                match limit.lock() {
                    Ok(mut l) => reports.extend(l.poll::<()>(Instant::now())),
                    Err(_) => return,
                }
                reports.into_iter().for_each(summary);
            });
        if let Err(e) = spawned {
            eprintln!("the libraries' log lines are limited, but their summaries are lost: {e}");
        }
        Self { limit, pending }
    }

    /// Whether a line of call site `site` at `now` is logged.
    fn admit(&self, now: Instant, site: String) -> bool {
        let reports = match self.limit.lock() {
            Ok(mut limit) => limit.offer(now, site, ()),
            Err(_) => return true,
        };
        let mut admitted = false;
        for r in reports {
            match r {
                Report::Logged { .. } => admitted = true,
                // The window before ended just now: its summary is kept
                // for the thread (never logged from inside a filter).
                held @ Report::HeldBack { .. } => {
                    if let Ok(mut p) = self.pending.lock() {
                        p.push(held);
                    }
                }
            }
        }
        admitted
    }
}

impl Default for LibraryLimit {
    fn default() -> Self {
        Self::new()
    }
}

impl<S> Filter<S> for LibraryLimit {
    fn enabled(&self, _meta: &Metadata<'_>, _cx: &Context<'_, S>) -> bool {
        true
    }

    fn event_enabled(&self, event: &tracing::Event<'_>, _cx: &Context<'_, S>) -> bool {
        let meta = event.metadata();
        !limited(meta) || self.admit(Instant::now(), site(meta))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flood_of_one_kind_of_line_is_one_line_a_window() {
        let f = LibraryLimit::new();
        let t0 = Instant::now();
        let admitted = (0..15_000)
            .filter(|_| f.admit(t0, "zenoh/src/net/routing/hat.rs:100".into()))
            .count();
        assert_eq!(admitted, 1);
        assert!(f.admit(t0, "zenoh/src/other.rs:7".into()), "another kind");
        // The next window: a line again, and the last one's summary kept.
        assert!(f.admit(t0 + WINDOW, "zenoh/src/net/routing/hat.rs:100".into()));
        let kept = f.pending.lock().expect("lock").clone();
        assert_eq!(
            kept,
            vec![Report::HeldBack {
                count: 14_999,
                sources: 1,
                busiest: ("zenoh/src/net/routing/hat.rs:100".into(), 14_999)
            }]
        );
    }
}
