//! Access-control diagnostics (`falc-router run --trace-acl`). zenoh logs its
//! ACL decisions only at TRACE, in its `access_control` interceptor; this
//! layer listens to that target alone (the normal log keeps its own level)
//! and logs each distinct denial once, with the running count.
//!
//! Caveat, measured with zenoh 1.10.2: for a key a node *declares* (its
//! queryables, tokens, publishers), zenoh evaluates every message kind once
//! ahead of time and caches the result, so it traces hypothetical denials
//! ("welding is unauthorized to Query (egress) on …/alive/welding/…") and
//! later denies real messages on that key from the cache without a trace.
//! Denials of undeclared keys (a forbidden `get`, a forged `put`) are traced
//! one by one. The count is therefore a diagnostic, not an audit; off by
//! default, so the hot path pays nothing.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use tokio::sync::mpsc::{unbounded_channel, UnboundedReceiver, UnboundedSender};
use tracing::field::{Field, Visit};
use tracing_subscriber::filter::{EnvFilter, Targets};
use tracing_subscriber::layer::{Context, SubscriberExt};
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::{Layer, Registry};

const ACL_TARGET: &str = "zenoh::net::routing::interceptor::access_control";

/// Denials seen, and their messages.
pub struct Denials {
    count: Arc<AtomicU64>,
    rx: UnboundedReceiver<String>,
}

struct DenialLayer {
    count: Arc<AtomicU64>,
    tx: UnboundedSender<String>,
}

struct Message(String);

impl Visit for Message {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            self.0 = format!("{value:?}");
        }
    }
}

impl<S: tracing::Subscriber> Layer<S> for DenialLayer {
    fn on_event(&self, event: &tracing::Event<'_>, _ctx: Context<'_, S>) {
        let mut m = Message(String::new());
        event.record(&mut m);
        if m.0.contains("unauthorized") || m.0.contains("authorization error") {
            self.count.fetch_add(1, Ordering::Relaxed);
            let _ = self.tx.send(m.0);
        }
    }
}

/// Installs logging: the normal log (RUST_LOG, default info) to stderr and,
/// with `trace_acl`, the denial counter on zenoh's ACL target.
pub fn init_tracing(trace_acl: bool) -> Option<Denials> {
    let (tx, rx) = unbounded_channel();
    let count = Arc::new(AtomicU64::new(0));
    let filter = EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| EnvFilter::new("info,zenoh=warn,zenoh_transport=warn"));
    let fmt = tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        .with_filter(filter);
    let denial = trace_acl.then(|| {
        DenialLayer {
            count: count.clone(),
            tx,
        }
        .with_filter(Targets::new().with_target(ACL_TARGET, tracing::Level::TRACE))
    });
    let _ = Registry::default().with(fmt).with(denial).try_init();
    trace_acl.then_some(Denials { count, rx })
}

/// Logs each distinct denial once, with the running count of all.
pub async fn report(mut denials: Denials) {
    let mut seen = std::collections::HashSet::new();
    while let Some(text) = denials.rx.recv().await {
        // Drop the session id prefix so one kind of denial is one line.
        let kind = text
            .split_once(" on ")
            .map_or(text.as_str(), |(_, k)| k)
            .to_string();
        if seen.insert(kind) {
            let total = denials.count.load(Ordering::Relaxed);
            tracing::warn!(target: "falc_router::acl", total, "denied: {text}");
        }
    }
}
