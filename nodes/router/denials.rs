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
use tracing_subscriber::filter::Targets;
use tracing_subscriber::layer::Context;
use tracing_subscriber::Layer;

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

/// With `trace_acl`, the layer that counts denials on zenoh's ACL target
/// (listening to that target alone), and the receiving end for [`report`].
pub fn layer<S>(trace_acl: bool) -> (Option<impl Layer<S>>, Option<Denials>)
where
    S: tracing::Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
{
    if !trace_acl {
        return (None, None);
    }
    let (tx, rx) = unbounded_channel();
    let count = Arc::new(AtomicU64::new(0));
    let layer = DenialLayer {
        count: count.clone(),
        tx,
    }
    .with_filter(Targets::new().with_target(ACL_TARGET, tracing::Level::TRACE));
    (Some(layer), Some(Denials { count, rx }))
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
