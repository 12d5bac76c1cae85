//! The operator's OpenMetrics endpoint (`--metrics HOST:PORT`, `GET
//! /metrics`) for the plant's monitoring: every scrape reads the records
//! on a connection of its own and computes the figures of all time
//! (`falc_factory::figures`), then writes them with the
//! `prometheus-client` crate:
//!
//! - `falc_orders_total{cell,recipe,result}`: order runs by how they
//!   ended (a restarted order counts each run);
//! - `falc_cycle_time_seconds{cell,recipe}`: a histogram of the done runs;
//! - `falc_alarms_total{cell,station,class}`;
//! - `falc_packml_state_seconds_total{cell,state}`: Execute (an order
//!   runs), Aborted (an alarm holds the cell), Idle, as the OPC UA
//!   gateway names the states; `falc_unit_mode_seconds_total{cell,mode}`:
//!   time in maintenance and step mode, which the states leave out.
//!
//! A tiny HTTP/1.1 server of its own: one request per connection, read
//! within [`READ_LIMIT`] and at most [`MAX_REQUEST`] bytes; anything but
//! `GET /metrics` is answered 404 or 400, never fails the node.

use crate::database::Database;
use falc_factory::figures;
use falc_factory::records::Records;
use falc_model::calendar::Calendar;
use falc_model::figures::{FigureQuery, Figures};
use prometheus_client::encoding::text::encode;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::histogram::Histogram;
use prometheus_client::registry::Registry;
use std::path::Path;
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

/// How long a client may take to send its request.
const READ_LIMIT: Duration = Duration::from_secs(5);
/// The largest request read.
const MAX_REQUEST: usize = 8192;
/// The cycle-time histogram's buckets, seconds.
const BUCKETS: [f64; 12] = [
    5.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 90.0, 120.0, 180.0, 300.0, 600.0,
];
const CONTENT_TYPE: &str = "application/openmetrics-text; version=1.0.0; charset=utf-8";

type Labels = Vec<(String, String)>;

fn labels(pairs: &[(&str, &str)]) -> Labels {
    pairs
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
}

/// `f` as OpenMetrics text.
pub fn render(f: &Figures) -> Result<String, std::fmt::Error> {
    let orders = Family::<Labels, Counter>::default();
    let cycle = Family::<Labels, Histogram>::new_with_constructor(|| {
        Histogram::new(BUCKETS.iter().copied())
    });
    let alarms = Family::<Labels, Counter>::default();
    let states = Family::<Labels, Counter<f64, AtomicU64>>::default();
    let modes = Family::<Labels, Counter<f64, AtomicU64>>::default();
    for c in &f.cells {
        let cell = c.cell.as_str();
        for e in &c.ended {
            orders
                .get_or_create(&labels(&[
                    ("cell", cell),
                    ("recipe", &e.recipe),
                    ("result", &e.result),
                ]))
                .inc_by(e.count);
        }
        for ct in &c.cycle {
            let h = cycle.get_or_create(&labels(&[("cell", cell), ("recipe", &ct.recipe)]));
            for ms in &ct.runs_ms {
                h.observe(*ms as f64 / 1000.0);
            }
        }
        for l in &c.pareto {
            alarms
                .get_or_create(&labels(&[
                    ("cell", cell),
                    ("station", &l.station),
                    ("class", l.class.as_str()),
                ]))
                .inc_by(l.count);
        }
        let t = &c.total.time;
        let seconds = |ms: i64| ms as f64 / 1000.0;
        for (state, ms) in [
            ("Execute", t.production_ms),
            ("Aborted", t.down_total_ms()),
            ("Idle", t.idle_ms),
        ] {
            states
                .get_or_create(&labels(&[("cell", cell), ("state", state)]))
                .inc_by(seconds(ms));
        }
        for (mode, ms) in [("maintenance", t.maintenance_ms), ("step", t.setup_ms)] {
            modes
                .get_or_create(&labels(&[("cell", cell), ("mode", mode)]))
                .inc_by(seconds(ms));
        }
    }
    let mut registry = Registry::with_prefix("falc");
    registry.register(
        "orders",
        "Order runs by how they ended (a restarted order counts each run)",
        orders,
    );
    registry.register(
        "cycle_time_seconds",
        "Run time of the done order runs",
        cycle,
    );
    registry.register("alarms", "Alarms raised, by station and class", alarms);
    registry.register(
        "packml_state_seconds",
        "Planned busy time in each PackML state: Execute (an order runs), Aborted (an alarm holds the cell), Idle",
        states,
    );
    registry.register(
        "unit_mode_seconds",
        "Planned busy time in maintenance and in step mode (left out of the states)",
        modes,
    );
    let mut out = String::new();
    encode(&mut out, &registry)?;
    Ok(out)
}

/// What a scrape reads: the records, on a connection of the endpoint's.
pub struct Source {
    db: Mutex<Database>,
    calendar: Calendar,
    cells: Vec<String>,
}

impl Source {
    /// Opens its own connection to the records at `path`.
    pub fn open(path: &Path, calendar: Calendar, cells: Vec<String>) -> anyhow::Result<Self> {
        let first = cells.first().cloned().unwrap_or_default();
        Ok(Self {
            db: Mutex::new(Database::open(path, &first)?),
            calendar,
            cells,
        })
    }

    /// The metrics of all time until now.
    fn scrape(&self) -> Result<String, String> {
        let db = self
            .db
            .lock()
            .map_err(|_| "the records connection failed earlier".to_string())?;
        // A reader with a connection of its own: the system's time.
        let now = crate::database::now_ms();
        let inputs = db.figure_inputs(0, now).map_err(|e| e.to_string())?;
        let cells: Vec<&str> = self.cells.iter().map(String::as_str).collect();
        let query = FigureQuery {
            since_ms: 0,
            until_ms: Some(now),
            planned: Vec::new(),
        };
        let f = figures::compute(&inputs, &self.calendar, &cells, &query, now);
        render(&f).map_err(|e| format!("cannot write the metrics: {e}"))
    }
}

/// Serves `GET /metrics` on `listener` until the node stops.
pub async fn serve(listener: TcpListener, source: Arc<Source>) {
    loop {
        let (stream, peer) = match listener.accept().await {
            Ok(c) => c,
            Err(e) => {
                tracing::warn!("metrics endpoint: cannot accept: {e}");
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let source = source.clone();
        tokio::spawn(async move {
            if let Err(e) = answer(stream, source).await {
                tracing::debug!(%peer, "metrics endpoint: {e}");
            }
        });
    }
}

/// The request line of what `stream` sent, read within the limits.
async fn request_line(stream: &mut TcpStream) -> Result<String, String> {
    let mut buf = Vec::new();
    let mut chunk = [0u8; 1024];
    let read = async {
        while !buf.windows(4).any(|w| w == b"\r\n\r\n") {
            let n = stream
                .read(&mut chunk)
                .await
                .map_err(|e| format!("read: {e}"))?;
            if n == 0 {
                return Err("closed before the request ended".to_string());
            }
            buf.extend_from_slice(&chunk[..n]);
            if buf.len() > MAX_REQUEST {
                return Err(format!("a request of more than {MAX_REQUEST} bytes"));
            }
        }
        Ok(())
    };
    tokio::time::timeout(READ_LIMIT, read)
        .await
        .map_err(|_| format!("no whole request within {READ_LIMIT:?}"))??;
    let text = String::from_utf8_lossy(&buf);
    Ok(text.lines().next().unwrap_or_default().to_string())
}

async fn answer(mut stream: TcpStream, source: Arc<Source>) -> Result<(), String> {
    let (status, kind, body) = match request_line(&mut stream).await {
        Err(e) => ("400 Bad Request", "text/plain", format!("{e}\n")),
        Ok(line) => {
            let mut parts = line.split_whitespace();
            match (parts.next(), parts.next()) {
                (Some("GET"), Some("/metrics")) => {
                    let scraped = tokio::task::spawn_blocking(move || source.scrape())
                        .await
                        .map_err(|e| format!("the scrape failed: {e}"))
                        .and_then(|r| r);
                    match scraped {
                        Ok(body) => ("200 OK", CONTENT_TYPE, body),
                        Err(e) => {
                            tracing::error!("metrics endpoint: {e}");
                            ("500 Internal Server Error", "text/plain", format!("{e}\n"))
                        }
                    }
                }
                (Some("GET"), _) => (
                    "404 Not Found",
                    "text/plain",
                    "only /metrics is served here\n".to_string(),
                ),
                _ => (
                    "400 Bad Request",
                    "text/plain",
                    "only GET /metrics is served here\n".to_string(),
                ),
            }
        }
    };
    let head = format!(
        "HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
        body.len()
    );
    stream
        .write_all(head.as_bytes())
        .await
        .and(stream.write_all(body.as_bytes()).await)
        .and(stream.shutdown().await)
        .map_err(|e| format!("write: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_factory::figures::{AlarmSpan, FigureInputs, RunSpan};
    use falc_model::alarm::AlarmClass;
    use falc_model::records::OrderState;

    #[test]
    fn the_figures_become_openmetrics_counters_a_histogram_and_state_seconds() {
        let run = |order, start, end, state| RunSpan {
            order,
            recipe: "dikdroog".into(),
            cell: "falc1".into(),
            start_ms: start,
            end_ms: Some(end),
            state,
        };
        let inputs = FigureInputs {
            runs: vec![
                run(1, 0, 12_000, OrderState::Done),
                run(2, 20_000, 27_000, OrderState::Failed),
            ],
            alarms: vec![AlarmSpan {
                cell: "falc1".into(),
                station: "welding".into(),
                class: AlarmClass::Safety,
                raised_ms: 27_000,
                gone_ms: Some(30_000),
            }],
            modes: Vec::new(),
            // The list worked all along (no shift calendar: planned).
            lists: vec![falc_factory::figures::ListChange {
                cell: "falc1".into(),
                at_ms: 0,
                working: true,
            }],
        };
        let query = FigureQuery {
            since_ms: 0,
            until_ms: Some(40_000),
            planned: Vec::new(),
        };
        let f = figures::compute(&inputs, &Calendar::default(), &["falc1"], &query, 40_000);
        let text = render(&f).expect("text");
        for line in [
            "falc_orders_total{cell=\"falc1\",recipe=\"dikdroog\",result=\"done\"} 1",
            "falc_orders_total{cell=\"falc1\",recipe=\"dikdroog\",result=\"failed\"} 1",
            "falc_cycle_time_seconds_count{cell=\"falc1\",recipe=\"dikdroog\"} 1",
            "falc_cycle_time_seconds_bucket{le=\"15.0\",cell=\"falc1\",recipe=\"dikdroog\"} 1",
            "falc_alarms_total{cell=\"falc1\",station=\"welding\",class=\"safety\"} 1",
            "falc_packml_state_seconds_total{cell=\"falc1\",state=\"Execute\"} 19.0",
            "falc_packml_state_seconds_total{cell=\"falc1\",state=\"Aborted\"} 3.0",
            "falc_packml_state_seconds_total{cell=\"falc1\",state=\"Idle\"} 18.0",
        ] {
            assert!(text.contains(line), "no `{line}` in\n{text}");
        }
        assert!(text.ends_with("# EOF\n"), "{text}");
    }
}
