//! What the operator keeps durably, as the API shows it: each order with
//! its state, and the journal's entries (what happened, who said it, in
//! which cell).

use serde::{Deserialize, Serialize};
use std::fmt;

/// Where an order is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OrderState {
    /// Waiting in the list.
    Queued,
    /// Its recipe runs in the cell.
    Running,
    /// Ended normally.
    Done,
    /// Ended in alarm or with a failure criterion.
    Failed,
    /// Stopped by an operator.
    Stopped,
    /// Was running when the operator node died; never re-run by itself.
    Interrupted,
}

impl OrderState {
    /// The word stored and shown.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Queued => "queued",
            Self::Running => "running",
            Self::Done => "done",
            Self::Failed => "failed",
            Self::Stopped => "stopped",
            Self::Interrupted => "interrupted",
        }
    }

    /// Parses the stored word.
    pub fn parse(word: &str) -> Option<Self> {
        [
            Self::Queued,
            Self::Running,
            Self::Done,
            Self::Failed,
            Self::Stopped,
            Self::Interrupted,
        ]
        .into_iter()
        .find(|s| s.as_str() == word)
    }
}

impl fmt::Display for OrderState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One order.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Order {
    /// Its id (also its position: lower runs first).
    pub id: i64,
    /// The cell recipe.
    pub recipe: String,
    /// Where it is.
    pub state: OrderState,
    /// Who added it.
    pub added_by: String,
    /// When it started (ms since the Unix epoch).
    pub started_ms: Option<i64>,
    /// When it ended (ms since the Unix epoch).
    pub ended_ms: Option<i64>,
    /// How it ended, in words.
    pub result: Option<String>,
    /// The cell it runs (ran) on; None while queued.
    pub cell: Option<String>,
    /// The only cell it may run on, if it was added for one.
    pub wanted: Option<String>,
    /// Its priority (higher runs first).
    pub priority: i32,
    /// When it is due (ms since the Unix epoch), if it is.
    pub due_ms: Option<i64>,
    /// The job order of a manufacturing execution system it carries out
    /// (its ISA-95 JobOrderID), if it was added for one.
    #[serde(default)]
    pub job_order: Option<String>,
}

impl Order {
    /// Its place among the queued orders: the smallest runs first (the
    /// highest priority, then the one due first, one with no due time
    /// after every one with, then the one added first).
    pub fn dispatch_key(&self) -> (std::cmp::Reverse<i32>, bool, Option<i64>, i64) {
        (
            std::cmp::Reverse(self.priority),
            self.due_ms.is_none(),
            self.due_ms,
            self.id,
        )
    }

    /// Whether cell `cell` may run it.
    pub fn may_run_on(&self, cell: &str) -> bool {
        self.wanted.as_deref().map_or(true, |w| w == cell)
    }
}

/// What a journal entry records.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum EntryKind {
    /// An order started or ended.
    Order,
    /// An alarm.
    Alarm,
    /// A line the cell showed the operator (`output`).
    Message,
    /// A question the cell asked (`input`).
    Question,
    /// The answer given.
    Answer,
    /// A report from a station.
    Report,
    /// An operator's action.
    Action,
    /// The operator node itself (start, recovery, recipes).
    System,
}

impl EntryKind {
    /// Every kind.
    pub const ALL: [EntryKind; 8] = [
        Self::Order,
        Self::Alarm,
        Self::Message,
        Self::Question,
        Self::Answer,
        Self::Report,
        Self::Action,
        Self::System,
    ];

    /// The word stored and shown.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Order => "order",
            Self::Alarm => "alarm",
            Self::Message => "message",
            Self::Question => "question",
            Self::Answer => "answer",
            Self::Report => "report",
            Self::Action => "action",
            Self::System => "system",
        }
    }

    /// Parses the stored word.
    pub fn parse(word: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.as_str() == word)
    }

    /// Whether `falc messages` shows it (what the 1992 message screen showed).
    pub fn is_message(self) -> bool {
        matches!(
            self,
            Self::Alarm | Self::Message | Self::Question | Self::Answer | Self::Report
        )
    }
}

/// One journal entry.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Entry {
    /// Its id (increasing).
    pub id: i64,
    /// When (ms since the Unix epoch).
    pub at_ms: i64,
    /// The order it belongs to.
    pub order: Option<i64>,
    /// What it records.
    pub kind: EntryKind,
    /// Who: a console user, or the station that reported.
    pub who: String,
    /// What, for a person.
    pub text: String,
    /// The cell it happened in (None: written before entries had one).
    #[serde(default)]
    pub cell: Option<String>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn states_and_kinds_are_read_back_from_their_words() {
        for k in EntryKind::ALL {
            assert_eq!(EntryKind::parse(k.as_str()), Some(k));
        }
        assert_eq!(
            OrderState::parse("interrupted"),
            Some(OrderState::Interrupted)
        );
        assert_eq!(OrderState::parse("lost"), None);
    }
}
