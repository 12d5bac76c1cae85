//! A defect found in a recipe: where (file, line, state), which category,
//! and why, printed as `file:line: state N: reason`.

use super::syntax::StateNo;
use std::fmt;

/// The categories of defect (the thesis' appendix J, and more).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ProblemKind {
    /// "wrong line structure": columns, numbers, report word, `#NAME`.
    MalformedLine,
    /// "state %d does not exist": a next state with no rows.
    UnknownState,
    /// "state %d has no criterion": a row of a command that needs one.
    NoCriterion,
    /// "state %d inconsistent": rows of one state with different commands.
    Inconsistent,
    /// "state %d has a wrong command": unknown for this controller.
    UnknownCommand,
    /// Arguments of the wrong number or kind.
    BadArgument,
    /// "state %d has a wrong criterion": not one of the command's.
    WrongCriterion,
    /// The same criterion twice in one state.
    DuplicateCriterion,
    /// A `start`/`wait` without its `timeout` branch, a `wait` without
    /// `done`, an `input` without `answer=*` …
    MissingBranch,
    /// A `wait` with no time limit, and no `start` of its target gives one.
    MissingTimeLimit,
    /// No path from the first state leads here.
    Unreachable,
    /// No path from here leads to state 0.
    NoPathToEnd,
    /// A cycle of states none of which waits: it would spin.
    LoopWithoutWait,
    /// A workstation recipe without its `#NAME`, or an empty recipe.
    MissingName,
    /// A cell recipe starts a workstation recipe that no workstation defines.
    UnknownRecipe,
}

/// One defect.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    /// The file.
    pub origin: String,
    /// The 1-based line.
    pub line: usize,
    /// The state, where one applies.
    pub state: Option<StateNo>,
    /// The category.
    pub kind: ProblemKind,
    /// Why, for a person.
    pub message: String,
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.state {
            Some(s) => write!(
                f,
                "{}:{}: state {s}: {}",
                self.origin, self.line, self.message
            ),
            None => write!(f, "{}:{}: {}", self.origin, self.line, self.message),
        }
    }
}
