//! The operator API (docs/architecture.md, "Key space"; docs/operator-guide.md): what a console (`falc`) asks the
//! operator node, and what it answers. One zenoh key per call and user,
//! `falc/<cell>/operator/api/<call>/<user>`, so the router's ACL grants
//! calls per role ([`Call::role`]) and each user speaks only in its own
//! name. The transport is in `bus::api`; the operator node owns the
//! behaviour.

use crate::figures::{FigureQuery, Figures};
use crate::ids::{CellId, StationName};
use crate::mms::vmd::VmdStatus;
use crate::mode::{CellMode, ManualAction};
use crate::product::{OrderRecord, RecipeVersion, MAX_VERSION_MESSAGE_CHARS};
use crate::recipe_file::{RecipeFile, RecipeInfo, RecipeText, MAX_RECIPE_BYTES};
use crate::records::{Entry, Order};
use crate::topology::Role;
use serde::{Deserialize, Serialize};
use std::fmt;

macro_rules! calls {
    ($($variant:ident = $key:literal, $role:ident;)+) => {
        /// One operator API call: a key chunk, and the least role allowed it.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
        pub enum Call { $(#[doc = concat!("The call `", $key, "`, for role ", stringify!($role), " and up.")] $variant),+ }

        impl Call {
            /// Every call.
            pub const ALL: &'static [Call] = &[$(Call::$variant),+];

            /// The key chunk (`order-add`).
            pub fn as_str(self) -> &'static str {
                match self { $(Call::$variant => $key),+ }
            }

            /// The least role that may make this call.
            pub fn role(self) -> Role {
                match self { $(Call::$variant => Role::$role),+ }
            }
        }
    };
}

calls! {
    Status = "status", Observer;
    OrderList = "order-list", Observer;
    Messages = "messages", Observer;
    Journal = "journal", Observer;
    OrderAdd = "order-add", Operator;
    OrderRemove = "order-rm", Operator;
    Start = "start", Operator;
    Stop = "stop", Operator;
    Ack = "ack", Operator;
    Answer = "answer", Operator;
    Shutdown = "shutdown", Operator;
    RecipeList = "recipe-list", Observer;
    RecipeGet = "recipe-get", Observer;
    RecipePut = "recipe-put", Engineer;
    RecipeHistory = "recipe-history", Observer;
    RecipeVersion = "recipe-version", Observer;
    RecipeRollback = "recipe-rollback", Engineer;
    OrderShow = "order-show", Observer;
    Figures = "figures", Observer;
    Mode = "mode", Operator;
    Step = "step", Operator;
    Restart = "restart", Operator;
    Manual = "manual", Maintainer;
}

impl fmt::Display for Call {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A console's request.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum ApiRequest {
    /// The cell at a glance.
    Status,
    /// The order list (queued, running and the ended ones).
    OrderList,
    /// Messages (operator outputs, questions, reports, alarms) after an id.
    Messages {
        /// Only entries with a larger id.
        after: i64,
        /// Only the newest this many of them (still oldest first; at most
        /// a page); None: the oldest page of them.
        #[serde(default)]
        last: Option<u16>,
    },
    /// The journal after an id, optionally of one order.
    Journal {
        /// Only this order's entries.
        order: Option<i64>,
        /// Only entries with a larger id.
        after: i64,
        /// Only the newest this many of them (still oldest first; at most
        /// a page); None: the oldest page of them.
        #[serde(default)]
        last: Option<u16>,
    },
    /// Adds `count` orders for a cell recipe, placed as `placement` says
    /// (by default at the end of the list, on any cell that has it).
    OrderAdd {
        /// The cell recipe's name.
        recipe: String,
        /// Which cell, how urgent, by when.
        placement: Placement,
        /// How many orders (1 to [`MAX_ORDERS_PER_ADD`]).
        count: u16,
    },
    /// Removes a queued order.
    OrderRemove {
        /// The order id.
        id: i64,
    },
    /// Starts (or resumes) working through the list.
    Start,
    /// Stops the running order and the list.
    Stop,
    /// Acknowledges one alarm of the list, or every one (`None`).
    Ack {
        /// The alarm's number.
        id: Option<i64>,
    },
    /// Answers the waiting operator question.
    Answer {
        /// The answer (`ja`, `nee`, …).
        text: String,
    },
    /// Shuts the cell down once the list is done.
    Shutdown,
    /// Every recipe file in the recipe store.
    RecipeList,
    /// One recipe file's text.
    RecipeGet {
        /// Which file.
        file: RecipeFile,
    },
    /// Replaces (or creates) one recipe file: checked with the whole set
    /// first, saved only when clean; the cell gets it at the next start.
    RecipePut {
        /// Which file.
        file: RecipeFile,
        /// The new text.
        text: String,
        /// The content hash of the text the edit started from (None for a
        /// new file): refused if the file changed meanwhile.
        base: Option<u64>,
        /// Why, for the version's record (may be empty).
        #[serde(default)]
        message: String,
    },
    /// Every saved version of one recipe file, oldest first.
    RecipeHistory {
        /// Which file.
        file: RecipeFile,
    },
    /// One saved version of a recipe file, with its text.
    RecipeVersion {
        /// Which file.
        file: RecipeFile,
        /// Its version number.
        version: u32,
    },
    /// Saves an earlier version's text as the file's newest version:
    /// checked with the whole set like a save; the cell gets it at the
    /// next start.
    RecipeRollback {
        /// Which file.
        file: RecipeFile,
        /// The version whose text comes back.
        version: u32,
        /// Why, for the version's record (may be empty).
        #[serde(default)]
        message: String,
    },
    /// What the records say of one order: its runs with the recipe
    /// versions, its journal and its alarms.
    OrderShow {
        /// The order id.
        id: i64,
    },
    /// The ISO 22400-2 figures of a range.
    Figures(FigureQuery),
    /// Sets the cell's mode (auto ↔ step also while an order runs).
    Mode {
        /// The mode.
        mode: CellMode,
        /// In step mode, the workstations that step as well as the cell.
        stations: Vec<StationName>,
    },
    /// Step mode: carries out the step that waits (on the cell, or on a
    /// workstation that steps), or the steps up to state `to`.
    Step {
        /// The workstation (None: the cell).
        station: Option<StationName>,
        /// Go on until this state waits.
        to: Option<u16>,
    },
    /// Runs a failed, stopped or interrupted order again: from state
    /// `from` of its cell recipe, or (None) a stopped order where it
    /// stopped, else from its first state.
    Restart {
        /// The order.
        order: i64,
        /// The state to begin at.
        from: Option<u16>,
    },
    /// A manual operation on a workstation (maintainer, maintenance mode).
    Manual {
        /// The workstation.
        station: StationName,
        /// What.
        action: ManualAction,
    },
}

/// The most bytes one API request may carry on the wire (a recipe text
/// and its envelope); a larger one is refused before it is decoded.
pub const MAX_REQUEST_BYTES: usize = MAX_RECIPE_BYTES + 4096;
/// The longest answer to an operator question, in characters.
pub const MAX_ANSWER_CHARS: usize = 200;
/// The longest line the cell may show the operator (`output`), or ask
/// (`input`), in characters; a longer one is refused.
pub const MAX_OUTPUT_CHARS: usize = 4096;
/// The most lines one `output` may carry.
pub const MAX_OUTPUT_LINES: usize = 100;
/// How many of the lines shown since the last question go with the next
/// question into the status (all of them are in the journal).
pub const QUESTION_WINDOW_LINES: usize = 20;
/// How many orders may wait in the order list by default (queued, not yet
/// run); one more is refused (`falc-operator --max-queued-orders`).
pub const MAX_QUEUED_ORDERS: usize = 1000;

/// At most this many orders are added by one `order add --count N`.
pub const MAX_ORDERS_PER_ADD: u16 = 100;

/// An order's priority lies within ± this (default 0; higher runs first).
pub const MAX_PRIORITY: i32 = 99;

/// Where and when an order should run: what the dispatch goes by. Of the
/// queued orders a cell may run, the highest priority runs first, of
/// equal priority the one due first (one with no due time after every one
/// with), then the one added first.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Placement {
    /// Only this cell may run it (None: any cell that has the recipe).
    pub cell: Option<CellId>,
    /// Higher runs first (within ±[`MAX_PRIORITY`], default 0).
    pub priority: i32,
    /// When it is due (ms since the Unix epoch), if it is.
    pub due_ms: Option<i64>,
    /// The job order of a manufacturing execution system it carries out
    /// (its ISA-95 JobOrderID, at most [`MAX_JOB_ORDER_CHARS`]), kept in
    /// the order's record.
    #[serde(default)]
    pub job_order: Option<String>,
}
/// The longest job order id an order may carry, in characters.
pub const MAX_JOB_ORDER_CHARS: usize = 64;
/// The longest cell recipe name an order may name, in characters.
pub const MAX_RECIPE_NAME_CHARS: usize = 32;
/// The latest time a `figures` range may reach: 2100-01-01 UTC (the
/// calendar is laid out day by day over the range).
pub const LATEST_FIGURES_MS: i64 = 4_102_444_800_000;
/// The most planned run times one `figures` request may set.
pub const MAX_PLANNED_RECIPES: usize = 100;
impl ApiRequest {
    /// Refuses a text beyond its limit (or an answer with control
    /// characters), quoting only a short excerpt of it.
    pub fn check_limits(&self) -> Result<(), String> {
        use crate::ids::excerpt;
        match self {
            Self::Answer { text } => {
                let n = text.chars().count();
                if n > MAX_ANSWER_CHARS {
                    return Err(format!(
                        "answer \"{}\" is longer than {MAX_ANSWER_CHARS} characters: refused",
                        excerpt(text)
                    ));
                }
                if text.chars().any(crate::ids::unprintable) {
                    return Err(format!(
                        "answer \"{}\" holds a control character (a line break?) or a \
                         bidirectional override: refused",
                        excerpt(text)
                    ));
                }
            }
            Self::OrderAdd { recipe, .. } if recipe.chars().count() > MAX_RECIPE_NAME_CHARS => {
                return Err(format!(
                    "recipe name \"{}\" is longer than {MAX_RECIPE_NAME_CHARS} characters: refused",
                    excerpt(recipe)
                ));
            }
            Self::OrderAdd { count, .. } if !(1..=MAX_ORDERS_PER_ADD).contains(count) => {
                return Err(format!(
                    "{count} orders at once: give 1 to {MAX_ORDERS_PER_ADD}"
                ));
            }
            // Not `abs()`: i32::MIN has none.
            Self::OrderAdd { placement, .. }
                if !(-MAX_PRIORITY..=MAX_PRIORITY).contains(&placement.priority) =>
            {
                return Err(format!(
                    "priority {} is outside -{MAX_PRIORITY} to {MAX_PRIORITY}",
                    placement.priority
                ));
            }
            Self::OrderAdd { placement, .. }
                if placement.job_order.as_ref().is_some_and(|j| {
                    j.is_empty()
                        || j.chars().count() > MAX_JOB_ORDER_CHARS
                        || j.chars().any(crate::ids::unprintable)
                }) =>
            {
                return Err(format!(
                    "job order id \"{}\" is empty, longer than {MAX_JOB_ORDER_CHARS} characters \
                     or holds a control character: refused",
                    excerpt(placement.job_order.as_deref().unwrap_or_default())
                ));
            }
            Self::RecipePut { message, .. } | Self::RecipeRollback { message, .. }
                if message.chars().count() > MAX_VERSION_MESSAGE_CHARS
                    || message.chars().any(crate::ids::unprintable) =>
            {
                return Err(format!(
                    "version message \"{}\" is longer than {MAX_VERSION_MESSAGE_CHARS} characters \
                     or holds a control character: refused",
                    excerpt(message)
                ));
            }
            Self::Figures(q) if q.planned.len() > MAX_PLANNED_RECIPES => {
                return Err(format!(
                    "{} planned run times: give at most {MAX_PLANNED_RECIPES}",
                    q.planned.len()
                ));
            }
            Self::Figures(q) if q.until_ms.is_some_and(|u| u < q.since_ms) => {
                return Err("the range ends before it begins: refused".into());
            }
            Self::Figures(q)
                if !(0..=LATEST_FIGURES_MS).contains(&q.since_ms)
                    || q.until_ms.is_some_and(|u| u > LATEST_FIGURES_MS) =>
            {
                return Err(
                    "a range of figures lies between 1970 and 2100 (ms since the Unix epoch): refused"
                        .into(),
                );
            }
            Self::RecipePut { file, text, .. } if text.len() > MAX_RECIPE_BYTES => {
                return Err(format!(
                    "recipe {file} is {} bytes, more than the {MAX_RECIPE_BYTES} a recipe may have: refused",
                    text.len()
                ));
            }
            _ => {}
        }
        Ok(())
    }

    /// One order for `recipe`, at the end of the list, on any cell.
    pub fn order_add(recipe: &str) -> Self {
        Self::OrderAdd {
            recipe: recipe.to_string(),
            placement: Placement::default(),
            count: 1,
        }
    }

    /// The call (key) this request belongs to.
    pub fn call(&self) -> Call {
        match self {
            Self::Status => Call::Status,
            Self::OrderList => Call::OrderList,
            Self::Messages { .. } => Call::Messages,
            Self::Journal { .. } => Call::Journal,
            Self::OrderAdd { .. } => Call::OrderAdd,
            Self::OrderRemove { .. } => Call::OrderRemove,
            Self::Start => Call::Start,
            Self::Stop => Call::Stop,
            Self::Ack { .. } => Call::Ack,
            Self::Answer { .. } => Call::Answer,
            Self::Shutdown => Call::Shutdown,
            Self::RecipeList => Call::RecipeList,
            Self::RecipeGet { .. } => Call::RecipeGet,
            Self::RecipePut { .. } => Call::RecipePut,
            Self::RecipeHistory { .. } => Call::RecipeHistory,
            Self::RecipeVersion { .. } => Call::RecipeVersion,
            Self::RecipeRollback { .. } => Call::RecipeRollback,
            Self::OrderShow { .. } => Call::OrderShow,
            Self::Figures(_) => Call::Figures,
            Self::Mode { .. } => Call::Mode,
            Self::Step { .. } => Call::Step,
            Self::Restart { .. } => Call::Restart,
            Self::Manual { .. } => Call::Manual,
        }
    }
}

/// What the order list does.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ListState {
    /// Not working through the list.
    #[default]
    Idle,
    /// Working through the list.
    Running,
    /// Stopped by an alarm: `ack`, then `start`.
    Alarm,
}

impl ListState {
    /// The word shown (`idle`, `running`, `alarm`).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Idle => "idle",
            Self::Running => "running",
            Self::Alarm => "alarm",
        }
    }
}

/// A station as the operator sees it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct StationView {
    /// The station.
    pub name: StationName,
    /// Its last published status, if any.
    pub status: Option<VmdStatus>,
    /// Whether it is on the bus now (its status is the last it sent).
    pub connected: bool,
}

/// The cell at a glance (`falc status`); the default is an idle list
/// with nothing known.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CellStatus {
    /// The order list.
    pub list: ListState,
    /// Whether the cell is associated.
    pub cell_associated: bool,
    /// Why not, or what else is wrong (the last association refusal).
    pub problem: Option<String>,
    /// The alarm that holds `start` back (the highest priority of those
    /// waiting for `ack`), as one line.
    pub alarm: Option<String>,
    /// Every alarm in the list (not both acknowledged and cleared).
    pub alarms: Vec<crate::alarm::Alarm>,
    /// The running order.
    pub running: Option<Order>,
    /// Orders waiting.
    pub queued: usize,
    /// The question waiting for `answer`.
    pub question: Option<String>,
    /// Set when `shutdown` waits for the list to end.
    pub shutdown_pending: bool,
    /// The cell's mode, as its status last said (auto until seen).
    #[serde(default)]
    pub mode: CellMode,
    /// Every station below the operator.
    pub stations: Vec<StationView>,
    /// The newest journal entry's id: every order change and message
    /// moves it, so a console polls the rest only when it moved.
    pub journal_head: i64,
}

/// A positive answer.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum ApiReply {
    /// `status`.
    Status(CellStatus),
    /// `order list`.
    Orders(Vec<Order>),
    /// `order add`.
    Order(Order),
    /// `messages`, `journal`.
    Entries(Vec<Entry>),
    /// Done, with what happened in words.
    Done(String),
    /// `recipe list`.
    Recipes(Vec<RecipeInfo>),
    /// `recipe get`.
    Recipe(RecipeText),
    /// `status` of a plant of several cells: each cell at a glance.
    Plant(PlantStatus),
    /// `recipe history`: every version of one file, oldest first.
    Versions(Vec<RecipeVersion>),
    /// `recipe version`: one version and its text.
    RecipeAt {
        /// The version.
        version: RecipeVersion,
        /// Its text.
        text: String,
    },
    /// `order show`.
    OrderRecord(Box<OrderRecord>),
    /// `figures`.
    Figures(Box<Figures>),
}

/// A plant of several cells at a glance: each cell's status, in the
/// plant file's order.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct PlantStatus {
    /// Each cell's id and status.
    pub cells: Vec<(CellId, CellStatus)>,
}

/// The answer to a request: the reply, or why it was refused.
pub type ApiResult = Result<ApiReply, String>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_order_add_names_a_count_and_a_priority_within_their_limits() {
        let add = |count: u16, priority: i32| ApiRequest::OrderAdd {
            recipe: "dikdroog".into(),
            placement: Placement {
                cell: None,
                priority,
                due_ms: None,
                job_order: None,
            },
            count,
        };
        assert!(add(1, 0).check_limits().is_ok());
        assert!(add(MAX_ORDERS_PER_ADD, -MAX_PRIORITY)
            .check_limits()
            .is_ok());
        let e = add(0, 0).check_limits().expect_err("no order");
        assert!(e.contains("give 1 to 100"), "{e}");
        assert!(add(MAX_ORDERS_PER_ADD + 1, 0).check_limits().is_err());
        let e = add(1, 100).check_limits().expect_err("too high");
        assert!(e.contains("priority 100"), "{e}");
        // i32::MIN has no absolute value: refused, never journalled.
        for p in [i32::MIN, i32::MIN + 1, -100, i32::MAX] {
            let e = add(1, p).check_limits().expect_err("out of range");
            assert!(e.contains(&format!("priority {p}")), "{e}");
        }
        // A job order id: not empty, not too long, no control characters.
        let job = |id: &str| ApiRequest::OrderAdd {
            recipe: "dikdroog".into(),
            placement: Placement {
                job_order: Some(id.into()),
                ..Placement::default()
            },
            count: 1,
        };
        assert!(job("MES-4711").check_limits().is_ok());
        for bad in ["", "a\nb", &"x".repeat(MAX_JOB_ORDER_CHARS + 1)] {
            let e = job(bad).check_limits().expect_err("refused");
            assert!(e.contains("job order id"), "{e}");
        }
    }

    #[test]
    fn an_answer_with_a_bidirectional_override_is_refused() {
        for text in ["ja\u{202e}", "\u{2066}nee", "ja\u{9b}"] {
            let e = ApiRequest::Answer { text: text.into() }
                .check_limits()
                .expect_err("refused");
            assert!(e.contains("bidirectional"), "{e}");
        }
        assert!(ApiRequest::Answer { text: "jä".into() }
            .check_limits()
            .is_ok());
    }

    #[test]
    fn texts_beyond_their_limits_are_refused_quoting_a_short_excerpt() {
        let huge = "j".repeat(16 * 1024 * 1024);
        for r in [
            ApiRequest::Answer { text: huge.clone() },
            ApiRequest::order_add(&huge),
            ApiRequest::RecipePut {
                file: RecipeFile::new(StationName::new("cell").expect("valid"), "big.rcp")
                    .expect("valid"),
                text: huge.clone(),
                base: None,
                message: String::new(),
            },
            ApiRequest::RecipeRollback {
                file: RecipeFile::new(StationName::new("cell").expect("valid"), "big.rcp")
                    .expect("valid"),
                version: 1,
                message: huge.clone(),
            },
            ApiRequest::Figures(crate::figures::FigureQuery {
                since_ms: i64::MIN,
                until_ms: None,
                planned: Vec::new(),
            }),
            ApiRequest::Figures(crate::figures::FigureQuery {
                since_ms: 0,
                until_ms: Some(i64::MAX),
                planned: Vec::new(),
            }),
        ] {
            let e = r.check_limits().expect_err("refused");
            assert!(e.len() < 200, "{} bytes: {}", e.len(), &e[..200]);
            assert!(e.contains("refused"), "{e}");
        }
        let e = ApiRequest::Answer {
            text: "ja\nnee".into(),
        }
        .check_limits()
        .expect_err("a line break");
        assert!(e.contains("control character"), "{e}");
        assert_eq!(
            ApiRequest::Answer { text: "ja".into() }.check_limits(),
            Ok(())
        );
        let e =
            RecipeFile::new(StationName::new("cell").expect("valid"), &huge).expect_err("bad name");
        assert!(e.len() < 200, "{} bytes", e.len());
    }

    #[test]
    fn keys_are_unique_and_every_request_has_its_call() {
        let mut seen = std::collections::BTreeSet::new();
        for c in Call::ALL {
            assert!(seen.insert(c.as_str()), "{c}");
            assert!(!c.as_str().contains(['*', '/', '$', '?', '#']));
        }
        assert_eq!(ApiRequest::Start.call(), Call::Start);
        assert_eq!(Call::Status.role(), Role::Observer);
        assert_eq!(Call::Answer.role(), Role::Operator);
    }

    #[test]
    fn a_list_states_word_is_its_wire_name() {
        for l in [ListState::Idle, ListState::Running, ListState::Alarm] {
            let wire = serde_json::to_string(&l).expect("serializes");
            assert_eq!(wire, format!("\"{}\"", l.as_str()));
        }
    }
}
