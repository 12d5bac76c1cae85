//! Alarms as the cell manages them: the class an alarm gets where it is
//! raised (a robot alarm code, a PLC input, a lost link, a recipe's own
//! `alarm` state), the cause that travels up with it, and the operator's
//! record of each alarm (raised, acknowledged, cleared).
//!
//! No I/O: the operator keeps the list (`nodes/operator/alarms.rs`) and
//! stores it; the stations only classify.

use crate::ids::StationName;
use serde::{Deserialize, Serialize};
use std::fmt;

/// What kind of fault an alarm is; sets its priority and whether it needs
/// an acknowledgement before the cell may start again.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AlarmClass {
    /// People or machine at risk: emergency stop, a hardware limit switch.
    Safety,
    /// A link is gone: a node, the DNC line, the PLC connection.
    Communication,
    /// A device cannot work: PLC not ready, a robot alarm, a disk that
    /// cannot be written.
    Device,
    /// The production went wrong: a recipe's alarm state, a time limit,
    /// a bad product, an order that could not start.
    Process,
    /// For a person to look at; needs no acknowledgement (a person in the
    /// robot's area, a program found running that no job owned).
    Warning,
}

impl AlarmClass {
    /// Every class, highest priority first.
    pub const ALL: [AlarmClass; 5] = [
        Self::Safety,
        Self::Communication,
        Self::Device,
        Self::Process,
        Self::Warning,
    ];

    /// 1 is the highest.
    pub fn priority(self) -> u8 {
        match self {
            Self::Safety => 1,
            Self::Communication => 2,
            Self::Device => 3,
            Self::Process => 4,
            Self::Warning => 5,
        }
    }

    /// Whether `start` is refused until it is acknowledged.
    pub fn needs_ack(self) -> bool {
        self != Self::Warning
    }

    /// Its word (`safety`, `communication` …).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Safety => "safety",
            Self::Communication => "communication",
            Self::Device => "device",
            Self::Process => "process",
            Self::Warning => "warning",
        }
    }

    /// The class named by `word`.
    pub fn parse(word: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.as_str() == word)
    }
}

impl fmt::Display for AlarmClass {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Why a job or a station is in alarm: the class set where it was raised
/// and the words for a person. Passed up unchanged in class as each level
/// adds its context to the words.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Cause {
    /// The class.
    pub class: AlarmClass,
    /// What happened.
    pub text: String,
}

impl Cause {
    /// A cause of `class`.
    pub fn new(class: AlarmClass, text: impl Into<String>) -> Self {
        Self {
            class,
            text: text.into(),
        }
    }

    /// A process alarm (a recipe's own alarm state, a time limit).
    pub fn process(text: impl Into<String>) -> Self {
        Self::new(AlarmClass::Process, text)
    }

    /// The same class, the words put in context: `f(text)`.
    pub fn map(&self, f: impl FnOnce(&str) -> String) -> Self {
        Self::new(self.class, f(&self.text))
    }

    /// Whether the words contain `needle`.
    pub fn contains(&self, needle: &str) -> bool {
        self.text.contains(needle)
    }

    /// The same alarm as a commander passes it on: "alarm from `from`:
    /// text" (read back by [`passed_on_from`]).
    pub fn passed_on(&self, from: &str) -> Self {
        self.map(|t| format!("alarm from {from}: {t}"))
    }
}

/// The text of the alarm `text` passes on from station `from`, if it is
/// one ([`Cause::passed_on`]).
pub fn passed_on_from<'a>(text: &'a str, from: &str) -> Option<&'a str> {
    text.strip_prefix("alarm from ")?
        .strip_prefix(from)?
        .strip_prefix(": ")
}

impl fmt::Display for Cause {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.text)
    }
}

/// The first number of an alarm the database could not keep (a full
/// disk): such alarms live in the operator's memory, numbered from here
/// on, positive like every alarm (`falc ack 1000000001`) and far above any
/// number the database gives.
pub const UNSTORED_ALARM_IDS: i64 = 1_000_000_000;

/// Where an alarm stands (ISA-18.2's states, folded for a cell): active
/// until acknowledged or its condition clears; it leaves the list once it
/// is both acknowledged and cleared.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AlarmState {
    /// The condition is present and nobody acknowledged it.
    Active,
    /// Acknowledged; the condition is still present.
    Acknowledged,
    /// The condition cleared; not acknowledged yet.
    Cleared,
}

impl AlarmState {
    /// Its word.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Active => "active",
            Self::Acknowledged => "acknowledged",
            Self::Cleared => "cleared",
        }
    }
}

impl fmt::Display for AlarmState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One alarm in the operator's list.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Alarm {
    /// Its number (`falc ack N`).
    pub id: i64,
    /// The station that raised it (`welding`, `cell`, `operator` …).
    pub station: StationName,
    /// Its class.
    pub class: AlarmClass,
    /// What happened.
    pub text: String,
    /// The order it belongs to, if one ran.
    pub order: Option<i64>,
    /// When it was raised (ms since the Unix epoch).
    pub raised_ms: i64,
    /// Who acknowledged it and when.
    pub acked: Option<(String, i64)>,
    /// When its condition cleared.
    pub cleared_ms: Option<i64>,
}

impl Alarm {
    /// Its state.
    pub fn state(&self) -> AlarmState {
        match (&self.acked, self.cleared_ms) {
            (None, None) => AlarmState::Active,
            (Some(_), _) => AlarmState::Acknowledged,
            (None, Some(_)) => AlarmState::Cleared,
        }
    }

    /// Whether it still holds the cell back: it needs an acknowledgement
    /// and has none.
    pub fn blocks_start(&self) -> bool {
        self.class.needs_ack() && self.acked.is_none()
    }

    /// Whether it is still in the list: not both acknowledged and cleared
    /// (a warning too stays listed until someone acknowledged it, though
    /// it never holds the cell back).
    pub fn listed(&self) -> bool {
        !(self.acked.is_some() && self.cleared_ms.is_some())
    }

    /// When it stopped holding the cell: its condition cleared and, if
    /// it needs one, acknowledged. None while it holds.
    pub fn gone_ms(&self) -> Option<i64> {
        let cleared = self.cleared_ms?;
        if !self.class.needs_ack() {
            return Some(cleared);
        }
        let (_, acked) = self.acked.as_ref()?;
        Some(cleared.max(*acked))
    }

    /// One line: `#3 safety welding: RCM message 24: emergency stop`.
    pub fn line(&self) -> String {
        format!(
            "#{} {} {}: {}",
            self.id, self.class, self.station, self.text
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn alarm(class: AlarmClass) -> Alarm {
        Alarm {
            id: 1,
            station: StationName::new("welding").expect("name"),
            class,
            text: "RCM message 24: emergency stop".into(),
            order: Some(1),
            raised_ms: 0,
            acked: None,
            cleared_ms: None,
        }
    }

    #[test]
    fn an_alarm_leaves_the_list_once_acknowledged_and_cleared() {
        let mut a = alarm(AlarmClass::Safety);
        assert_eq!(a.state(), AlarmState::Active);
        assert!(a.blocks_start() && a.listed());
        a.cleared_ms = Some(5);
        assert_eq!(a.state(), AlarmState::Cleared);
        assert_eq!(a.gone_ms(), None, "cleared, not yet acknowledged");
        assert!(a.blocks_start(), "cleared is not acknowledged");
        a.acked = Some(("ann".into(), 6));
        assert!(!a.blocks_start() && !a.listed());
        let mut a = alarm(AlarmClass::Safety);
        a.acked = Some(("ann".into(), 6));
        assert_eq!(a.state(), AlarmState::Acknowledged);
        assert!(a.listed(), "the estop is still pressed");
    }

    #[test]
    fn a_warning_needs_no_acknowledgement() {
        let mut w = alarm(AlarmClass::Warning);
        assert!(!w.blocks_start());
        assert!(w.listed());
        w.cleared_ms = Some(1);
        assert!(w.listed(), "shown until someone has seen it");
        w.acked = Some(("ann".into(), 2));
        assert!(!w.listed());
    }

    #[test]
    fn classes_by_priority_and_word() {
        let p: Vec<u8> = AlarmClass::ALL.iter().map(|c| c.priority()).collect();
        assert_eq!(p, vec![1, 2, 3, 4, 5]);
        for c in AlarmClass::ALL {
            assert_eq!(AlarmClass::parse(c.as_str()), Some(c));
        }
        let c = Cause::new(AlarmClass::Safety, "emergency stop").passed_on("welding");
        assert_eq!(c.class, AlarmClass::Safety);
        assert_eq!(c.to_string(), "alarm from welding: emergency stop");
        assert_eq!(passed_on_from(&c.text, "welding"), Some("emergency stop"));
        assert_eq!(passed_on_from(&c.text, "weld"), None);
        assert_eq!(passed_on_from("emergency stop", "welding"), None);
    }
}
