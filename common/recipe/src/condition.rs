//! Pre- and postconditions of a transport recipe (`#PRE`, `#POST` lines
//! beside its `#NAME`): what its station must observe before a Start is
//! taken, and after the job ended, for the job to be done. A condition is
//! a list of terms that must all hold, each an input of the station's
//! equipment at a level, written as people say it:
//!
//! | term | holds when |
//! |---|---|
//! | `place 3 occupied` / `place 3 empty` | the place's sensor is on / off |
//! | `line K running` / `line K stopped` | the line's running lamp is on / off |
//! | `station 3 busy` / `station 3 free` | the station's busy lamp is on / off |
//! | `input door_closed on` / `… off` | a plain input is on / off |
//!
//! and a welding recipe's over the robot's facts, as its DNC link tells
//! them:
//!
//! | term | holds when |
//! |---|---|
//! | `robot ready` / `robot unready` | the line open, the robot answering, in automatic-external mode (AUE) |
//! | `robot idle` / `robot running` | no robot program runs / one runs |
//!
//! Terms are separated by commas: `#PRE place 2 occupied, place 3 empty`.
//! This module reads and prints them; the checker puts them in the
//! [`crate::check::Program`] (a transport recipe's conveyor terms, a
//! welding recipe's robot terms), the equipment file says whether the
//! station has what they name, and the controller asks its device whether
//! they hold.

use crate::check::{line_letter, Signal};
use falc_model::ids::{excerpt, IoName, Place, PlcStation};
use std::fmt;

/// What a robot's DNC link tells of it, for a welding recipe's terms.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum RobotFact {
    /// It takes DNC commands: the line open, the robot answering, in
    /// automatic-external mode.
    Ready,
    /// A robot program runs.
    Running,
}

/// What a term is about: a conveyor input, or a fact of the robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Fact {
    /// An input of the conveyor's equipment (transport recipes).
    Signal(Signal),
    /// A fact of the robot (welding recipes).
    Robot(RobotFact),
}

/// One term: a fact at a level.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Condition {
    /// What it is about.
    pub fact: Fact,
    /// The level it must show.
    pub level: bool,
}

/// A condition of a recipe: its terms and the line they are on.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Conditions {
    /// Every term, all of which must hold.
    pub terms: Vec<Condition>,
    /// Its 1-based line in the recipe file.
    pub line: usize,
}

impl fmt::Display for Condition {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (what, on, off) = match self.fact {
            Fact::Signal(Signal::Place(p)) => (format!("place {p}"), "occupied", "empty"),
            Fact::Signal(Signal::Line(l)) => (format!("line {l}"), "running", "stopped"),
            Fact::Signal(Signal::Station(s)) => (format!("station {s}"), "busy", "free"),
            Fact::Signal(Signal::Input(n)) => (format!("input {n}"), "on", "off"),
            Fact::Robot(RobotFact::Ready) => ("robot".to_string(), "ready", "unready"),
            Fact::Robot(RobotFact::Running) => ("robot".to_string(), "running", "idle"),
        };
        write!(f, "{what} {}", if self.level { on } else { off })
    }
}

impl fmt::Display for Conditions {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let terms: Vec<String> = self.terms.iter().map(|t| t.to_string()).collect();
        f.write_str(&terms.join(", "))
    }
}

/// Reads one term (`place 3 empty`).
pub fn parse_term(text: &str) -> Result<Condition, String> {
    let lower = text.trim().to_ascii_lowercase();
    let words: Vec<&str> = lower.split_whitespace().collect();
    let (fact, level) = match words.as_slice() {
        ["place", n, state @ ("occupied" | "empty")] => (
            Fact::Signal(Signal::Place(Place::parse(n)?)),
            *state == "occupied",
        ),
        ["line", l, state @ ("running" | "stopped")] => (
            Fact::Signal(Signal::Line(line_letter(l)?)),
            *state == "running",
        ),
        ["station", n, state @ ("busy" | "free")] => (
            Fact::Signal(Signal::Station(PlcStation::parse(n)?)),
            *state == "busy",
        ),
        ["input", n, state @ ("on" | "off")] => (
            Fact::Signal(Signal::Input(IoName::parse(n)?)),
            *state == "on",
        ),
        ["robot", state @ ("ready" | "unready")] => {
            (Fact::Robot(RobotFact::Ready), *state == "ready")
        }
        ["robot", state @ ("running" | "idle")] => {
            (Fact::Robot(RobotFact::Running), *state == "running")
        }
        _ => {
            return Err(format!(
                "`{}` is not a condition: write `place N occupied|empty`, `line L \
                 running|stopped`, `station N busy|free`, `input NAME on|off`, `robot \
                 ready|unready` or `robot idle|running`",
                excerpt(text.trim())
            ))
        }
    };
    Ok(Condition { fact, level })
}

/// Reads a comma-separated list of terms; the error names the first that
/// is not one.
pub fn parse_terms(text: &str) -> Result<Vec<Condition>, String> {
    if text.trim().is_empty() {
        return Err("a condition needs at least one term (`place 2 occupied`)".into());
    }
    text.split(',').map(parse_term).collect()
}

/// The terms of `conditions` that `observe` says do not hold (an input it
/// cannot observe does not hold), as printed.
pub fn unmet(conditions: &[Condition], observe: impl Fn(Fact) -> Option<bool>) -> Vec<String> {
    conditions
        .iter()
        .filter(|c| observe(c.fact) != Some(c.level))
        .map(|c| c.to_string())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn terms_read_as_people_say_them_and_print_the_same() {
        let text =
            "place 2 occupied, Place 3 EMPTY, line k stopped, station 3 free, input door_closed on";
        let terms = parse_terms(text).expect("terms");
        assert_eq!(
            terms[0],
            Condition {
                fact: Fact::Signal(Signal::Place(Place::of(2))),
                level: true
            }
        );
        assert_eq!(
            terms[2],
            Condition {
                fact: Fact::Signal(Signal::Line('K')),
                level: false
            }
        );
        let printed = Conditions { terms, line: 2 }.to_string();
        assert_eq!(
            printed,
            "place 2 occupied, place 3 empty, line K stopped, station 3 free, input door_closed on"
        );
        assert_eq!(parse_terms(&printed).map(|t| t.len()), Ok(5));
    }

    #[test]
    fn a_term_that_is_none_is_named() {
        let e = parse_terms("place 2 occupied, place 3 full").unwrap_err();
        assert!(e.starts_with("`place 3 full` is not a condition"), "{e}");
        let e = parse_terms("line I running").unwrap_err();
        assert!(e.contains("not a conveyor line"), "{e}");
        assert!(parse_terms("  ").is_err());
    }

    #[test]
    fn unmet_terms_are_those_not_observed_at_their_level() {
        let terms = parse_terms("place 2 occupied, place 3 empty, input door on").expect("terms");
        let seen = |s: Fact| match s {
            Fact::Signal(Signal::Place(p)) => Some(p.number() == 2 || p.number() == 3),
            _ => None,
        };
        assert_eq!(unmet(&terms, seen), ["place 3 empty", "input door on"]);
        let robot = parse_terms("robot ready, robot idle").expect("robot terms");
        assert_eq!(robot[1].to_string(), "robot idle");
        let seen = |s: Fact| (s == Fact::Robot(RobotFact::Ready)).then_some(true);
        assert_eq!(unmet(&robot, seen), ["robot idle"]);
        let running = |s: Fact| Some(s == Fact::Robot(RobotFact::Ready));
        assert!(unmet(&robot, running).is_empty());
    }
}
