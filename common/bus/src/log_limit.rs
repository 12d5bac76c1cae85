//! Log lines that others cause, rate-limited per source (sans-I/O, the
//! clock passed in): in each window the first line from each source is
//! logged in full, for at most so many sources; the rest are counted and
//! summed up in one line when the window ends. A mistyped password, or one
//! malformed request, is one line; a stranger's flood is a handful. The
//! router's refused logins and the nodes' warnings about callers both go
//! through it ([`warn`]).

use std::collections::{HashMap, HashSet};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// What to log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Report<T> {
    /// An item logged in full.
    Logged {
        /// Where it came from.
        source: String,
        /// The item.
        item: T,
    },
    /// The items of a window that were not logged one by one.
    HeldBack {
        /// How many.
        count: u64,
        /// From how many sources.
        sources: usize,
        /// The source most of them came from, and its count.
        busiest: (String, u64),
    },
}

impl<T> Report<T> {
    /// The one line of a [`Report::HeldBack`]: "`count` more `what` from
    /// `sources` `source_kind`(s) in the last `window` s not logged one by
    /// one; most from `busiest` (`n`)"; None for an item logged in full.
    pub fn summary(&self, what: &str, source_kind: &str, window: Duration) -> Option<String> {
        match self {
            Report::Logged { .. } => None,
            Report::HeldBack {
                count,
                sources,
                busiest: (busiest, most),
            } => Some(format!(
                "{count} more {what} from {sources} {source_kind}(s) in the last {} s not logged one by one; most from {busiest} ({most})",
                window.as_secs()
            )),
        }
    }
}

struct Window {
    start: Instant,
    logged: HashSet<String>,
    held_back: HashMap<String, u64>,
}

/// The rate limit: items in, reports out.
pub struct LogLimit {
    window: Duration,
    per_window: usize,
    current: Option<Window>,
}

impl LogLimit {
    /// A limit of `per_window` sources logged in full in each `window`.
    pub fn new(window: Duration, per_window: usize) -> Self {
        Self {
            window,
            per_window,
            current: None,
        }
    }

    fn window(&mut self, now: Instant) -> &mut Window {
        self.current.get_or_insert_with(|| Window {
            start: now,
            logged: HashSet::new(),
            held_back: HashMap::new(),
        })
    }

    /// An item from `source` at `now`: the summary of a window that is
    /// over, if any, then the item if it is to be logged.
    pub fn offer<T>(&mut self, now: Instant, source: String, item: T) -> Vec<Report<T>> {
        let mut out: Vec<Report<T>> = self.poll(now).into_iter().collect();
        let per_window = self.per_window;
        let window = self.window(now);
        if window.logged.len() < per_window && window.logged.insert(source.clone()) {
            out.push(Report::Logged { source, item });
        } else {
            *window.held_back.entry(source).or_default() += 1;
        }
        out
    }

    /// `count` items whose details were lost (a queue was full).
    pub fn lost<T>(&mut self, now: Instant, count: u64) -> Vec<Report<T>> {
        let out: Vec<Report<T>> = self.poll(now).into_iter().collect();
        *self
            .window(now)
            .held_back
            .entry("unknown".into())
            .or_default() += count;
        out
    }

    /// Ends the window if it is over: its summary, if anything was held back.
    pub fn poll<T>(&mut self, now: Instant) -> Option<Report<T>> {
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
            sources: window.held_back.len(),
            busiest,
        })
    }

    /// When the current window ends.
    pub fn deadline(&self) -> Option<Instant> {
        self.current.as_ref().map(|w| w.start + self.window)
    }
}

/// The window of [`warn`].
pub const WARN_WINDOW: Duration = Duration::from_secs(10);
/// How many callers per window [`warn`] logs in full.
pub const WARN_SOURCES: usize = 10;

static WARNINGS: Mutex<Option<LogLimit>> = Mutex::new(None);

/// A warning a caller caused (a malformed request, a refused call), logged
/// at WARN rate-limited per `source` (the caller's key or user): one line
/// per source per [`WARN_WINDOW`], the rest summed up in one line with the
/// next warning after the window.
pub fn warn(source: &str, text: &str) {
    let reports = match WARNINGS.lock() {
        Ok(mut limit) => limit
            .get_or_insert_with(|| LogLimit::new(WARN_WINDOW, WARN_SOURCES))
            .offer(Instant::now(), source.to_string(), ()),
        // A poisoned lock: log it all rather than lose it.
        Err(_) => vec![Report::Logged {
            source: source.to_string(),
            item: (),
        }],
    };
    for r in reports {
        match r.summary("warnings", "caller", WARN_WINDOW) {
            None => tracing::warn!(source, "{text}"),
            Some(line) => tracing::warn!("{line}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn logged<T>(reports: &[Report<T>]) -> Vec<String> {
        reports
            .iter()
            .filter_map(|r| match r {
                Report::Logged { source, .. } => Some(source.clone()),
                Report::HeldBack { .. } => None,
            })
            .collect()
    }

    #[test]
    fn one_line_per_source_per_window_then_a_summary() {
        let t0 = Instant::now();
        let mut log = LogLimit::new(Duration::from_secs(10), 3);
        let first = log.offer(t0, "127.0.0.1".into(), 1000);
        assert_eq!(logged(&first), ["127.0.0.1"]);
        for i in 1..500u64 {
            let r = log.offer(t0 + Duration::from_millis(i), "127.0.0.1".into(), 1000 + i);
            assert!(r.is_empty(), "refusal {i}: {r:?}");
        }
        assert_eq!(log.poll::<u64>(t0 + Duration::from_secs(9)), None);
        assert_eq!(log.deadline(), Some(t0 + Duration::from_secs(10)));
        assert_eq!(
            log.poll::<u64>(t0 + Duration::from_secs(10)),
            Some(Report::HeldBack {
                count: 499,
                sources: 1,
                busiest: ("127.0.0.1".into(), 499)
            })
        );
        assert_eq!(log.deadline(), None, "the window is over");
        // The next window logs the host again.
        let again = log.offer(t0 + Duration::from_secs(11), "127.0.0.1".into(), 2);
        assert_eq!(logged(&again), ["127.0.0.1"]);
    }

    #[test]
    fn many_sources_get_at_most_the_limit_of_lines() {
        let t0 = Instant::now();
        let mut log = LogLimit::new(Duration::from_secs(10), 3);
        let mut lines = Vec::new();
        for i in 1..=20 {
            lines.extend(logged(&log.offer(t0, format!("10.0.0.{i}"), 5)));
        }
        lines.extend(logged(&log.offer(t0, "10.0.0.20".into(), 6)));
        assert_eq!(lines, ["10.0.0.1", "10.0.0.2", "10.0.0.3"]);
        // A window that is over is summed up by the next refusal too.
        let next = log.offer(t0 + Duration::from_secs(10), "10.0.0.9".into(), 5);
        assert_eq!(
            next,
            vec![
                Report::HeldBack {
                    count: 18,
                    sources: 17,
                    busiest: ("10.0.0.20".into(), 2)
                },
                Report::Logged {
                    source: "10.0.0.9".into(),
                    item: 5
                }
            ]
        );
    }

    #[test]
    fn a_window_with_nothing_held_back_ends_silently() {
        let t0 = Instant::now();
        let mut log = LogLimit::new(Duration::from_secs(10), 3);
        assert_eq!(logged(&log.offer(t0, "10.0.0.1".into(), 1)).len(), 1);
        assert_eq!(log.poll::<u64>(t0 + Duration::from_secs(10)), None);
        assert_eq!(log.deadline(), None);
    }

    #[test]
    fn lost_items_are_counted() {
        let t0 = Instant::now();
        let mut log = LogLimit::new(Duration::from_secs(10), 3);
        assert!(log.lost::<u64>(t0, 7).is_empty());
        assert_eq!(
            log.poll::<u64>(t0 + Duration::from_secs(10)),
            Some(Report::HeldBack {
                count: 7,
                sources: 1,
                busiest: ("unknown".into(), 7)
            })
        );
    }

    #[test]
    fn a_summary_is_one_line_naming_the_busiest_source() {
        let held: Report<()> = Report::HeldBack {
            count: 499,
            sources: 1,
            busiest: ("unreported".into(), 499),
        };
        assert_eq!(
            held.summary("refusals", "host", Duration::from_secs(10)).as_deref(),
            Some("499 more refusals from 1 host(s) in the last 10 s not logged one by one; most from unreported (499)")
        );
        let logged = Report::Logged {
            source: "a".into(),
            item: (),
        };
        assert_eq!(
            logged.summary("refusals", "host", Duration::from_secs(10)),
            None
        );
    }
}
