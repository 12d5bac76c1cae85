//! A station's kept reports (an MMS journal, sans-I/O): every report and
//! job event it publishes gets the next number of its run and is kept,
//! the last [`KEPT`] of them, so that a reader who missed some while a
//! link was down can read them again ([`ReportLog::after`]). What fell out
//! of the buffer is counted in the answer ([`KeptReports::lost_after`]).
//!
//! The reader's half (noticing a gap, asking, filing what comes back in
//! order) is the operator's order list (`falc_factory::order_list`).

use super::pdu::Unconfirmed;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// How many reports a station keeps.
pub const KEPT: usize = 1_000;

/// A report's place in its station's run: which run of the node (its
/// session), its number in that run (from 1), and when it was made (ms
/// since the Unix epoch, the station's clock).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Stamp {
    /// The run of the station's node (its bus session id): numbers start
    /// at 1 again in a new run.
    pub run: String,
    /// Its number in the run.
    pub no: u64,
    /// When it was made.
    pub at_ms: i64,
}

/// What a station puts on its `status` and `report` keys: the message,
/// numbered if it is a report or job event (a status is not: the latest
/// one is all that counts, and it is published again on association).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Publication {
    /// Its number, for a report or job event.
    pub stamp: Option<Stamp>,
    /// The message.
    pub message: Unconfirmed,
}

/// A reader asks for the reports after number `after` of the station's
/// current run (0: all it kept).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ReportsAsked {
    /// The last number the reader has of the run it knows.
    pub after: u64,
}

/// What a station answers: the reports it kept after the number asked,
/// oldest first, and where its buffer begins.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct KeptReports {
    /// The station's run.
    pub run: String,
    /// The number of the oldest report still kept (the next number to be
    /// given if none is kept).
    pub first: u64,
    /// The reports, oldest first.
    pub reports: Vec<(Stamp, Unconfirmed)>,
}

impl KeptReports {
    /// How many reports after number `last` of this run the reader can no
    /// longer have: they fell out of the buffer before it asked.
    pub fn lost_after(&self, last: u64) -> u64 {
        self.first.saturating_sub(last.saturating_add(1))
    }
}

/// The station's half: numbers and keeps.
#[derive(Debug)]
pub struct ReportLog {
    run: String,
    next: u64,
    kept: VecDeque<(Stamp, Unconfirmed)>,
    capacity: usize,
}

impl ReportLog {
    /// An empty log of run `run`, keeping [`KEPT`] reports.
    pub fn new(run: impl Into<String>) -> Self {
        Self::with_capacity(run, KEPT)
    }

    /// The same keeping `capacity` reports (at least one).
    pub fn with_capacity(run: impl Into<String>, capacity: usize) -> Self {
        let capacity = capacity.max(1);
        Self {
            run: run.into(),
            next: 1,
            kept: VecDeque::with_capacity(capacity.min(KEPT)),
            capacity,
        }
    }

    /// Numbers `message` if it is a report or job event, made at `at_ms`,
    /// and keeps it (the oldest kept falls out when the buffer is full);
    /// what to publish.
    pub fn publication(&mut self, at_ms: i64, message: Unconfirmed) -> Publication {
        let stamp = match message {
            Unconfirmed::Status { .. } => None,
            Unconfirmed::Report { .. } | Unconfirmed::Job { .. } => {
                let stamp = Stamp {
                    run: self.run.clone(),
                    no: self.next,
                    at_ms,
                };
                self.next += 1;
                if self.kept.len() == self.capacity {
                    self.kept.pop_front();
                }
                self.kept.push_back((stamp.clone(), message.clone()));
                Some(stamp)
            }
        };
        Publication { stamp, message }
    }

    /// The run the numbers are of.
    pub fn run(&self) -> &str {
        &self.run
    }

    /// The number of the last report made (0: none yet).
    pub fn last(&self) -> u64 {
        self.next - 1
    }

    /// The answer to a reader who has everything up to number `after`.
    pub fn after(&self, asked: ReportsAsked) -> KeptReports {
        let first = self.kept.front().map_or(self.next, |(s, _)| s.no);
        KeptReports {
            run: self.run.clone(),
            first,
            reports: self
                .kept
                .iter()
                .filter(|(s, _)| s.no > asked.after)
                .cloned()
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ids::StationName;
    use crate::mms::pdu::Severity;

    fn report(text: &str) -> Unconfirmed {
        Unconfirmed::Report {
            station: StationName::new("welding").expect("valid"),
            severity: Severity::Info,
            text: text.into(),
        }
    }

    fn numbers(k: &KeptReports) -> Vec<u64> {
        k.reports.iter().map(|(s, _)| s.no).collect()
    }

    #[test]
    fn reports_are_numbered_from_one_and_statuses_are_not() {
        let mut log = ReportLog::new("run-a");
        let status = Unconfirmed::Status {
            station: StationName::new("welding").expect("valid"),
            status: crate::mms::vmd::VmdStatus::default(),
        };
        assert_eq!(log.publication(5, status).stamp, None);
        let a = log.publication(10, report("a"));
        let b = log.publication(11, report("b"));
        assert_eq!(a.stamp.as_ref().map(|s| (s.no, s.at_ms)), Some((1, 10)));
        assert_eq!(b.stamp.as_ref().map(|s| s.no), Some(2));
        assert_eq!(a.stamp.map(|s| s.run), Some("run-a".to_string()));
        let all = log.after(ReportsAsked { after: 0 });
        assert_eq!((all.first, numbers(&all)), (1, vec![1, 2]));
        assert_eq!(all.lost_after(0), 0);
        let since = log.after(ReportsAsked { after: 1 });
        assert_eq!(
            since.reports,
            vec![(b.stamp.expect("numbered"), report("b"))]
        );
    }

    #[test]
    fn a_full_buffer_forgets_the_oldest_and_the_answer_counts_what_is_lost() {
        let mut log = ReportLog::with_capacity("r", 3);
        for i in 0..10 {
            log.publication(i, report(&format!("r{i}")));
        }
        let k = log.after(ReportsAsked { after: 2 });
        assert_eq!((k.first, numbers(&k)), (8, vec![8, 9, 10]));
        // The reader had 1 and 2: 3 to 7 are gone.
        assert_eq!(k.lost_after(2), 5);
        // A reader with everything: nothing lost, nothing sent.
        let k = log.after(ReportsAsked { after: 10 });
        assert_eq!((k.lost_after(10), k.reports.len()), (0, 0));
    }

    #[test]
    fn an_empty_log_answers_nothing_lost() {
        let log = ReportLog::new("r");
        let k = log.after(ReportsAsked { after: 0 });
        assert_eq!((k.first, k.reports.len(), k.lost_after(0)), (1, 0, 0));
        assert_eq!(k.lost_after(u64::MAX), 0);
    }
}
