//! The cell's operating modes (docs/the-1992-cell.md §7: automatic, step and
//! maintenance) and the manual operations maintenance mode allows, as they
//! travel between the levels: the operator sets the mode at the cell, the
//! cell passes it to every workstation, so a workstation itself refuses a
//! manual operation unless the cell is in maintenance.

use crate::ids::StationName;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// How the cell works.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CellMode {
    /// Orders run by themselves (the default, and what a restarted node
    /// comes back in).
    #[default]
    Auto,
    /// Orders run, but each recipe step waits for `falc step` before it is
    /// carried out (commissioning).
    Step,
    /// No order runs; a maintainer operates buttons, lines and the robot
    /// by hand and runs a station's home recipe.
    Maintenance,
}

impl CellMode {
    /// Every mode.
    pub const ALL: [CellMode; 3] = [Self::Auto, Self::Step, Self::Maintenance];

    /// The word shown and typed.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Step => "step",
            Self::Maintenance => "maintenance",
        }
    }

    /// Whether an order may run in this mode.
    pub fn runs_orders(self) -> bool {
        self != Self::Maintenance
    }

    /// Whether the mode may change from `self` to `to` while an order runs
    /// (only auto ↔ step: maintenance needs the cell idle).
    pub fn may_change_running(self, to: CellMode) -> bool {
        self.runs_orders() && to.runs_orders()
    }
}

impl fmt::Display for CellMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for CellMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|m| m.as_str().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| format!("unknown mode `{s}` (auto, step, maintenance)"))
    }
}

/// The mode as one level gets it: the cell's mode, and which stations
/// step (in step mode; the cell and, chosen per workstation, workstations).
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct ModeSetting {
    /// The cell's mode.
    pub mode: CellMode,
    /// The stations whose recipes wait before each step (step mode only).
    pub stepping: Vec<StationName>,
}

impl ModeSetting {
    /// Whether `station`'s recipes wait before each step.
    pub fn steps(&self, station: &StationName) -> bool {
        self.mode == CellMode::Step && self.stepping.contains(station)
    }
}

impl fmt::Display for ModeSetting {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.mode.as_str())?;
        if self.mode == CellMode::Step && !self.stepping.is_empty() {
            let names: Vec<&str> = self.stepping.iter().map(|s| s.as_str()).collect();
            write!(f, " ({})", names.join(", "))?;
        }
        Ok(())
    }
}

/// A recipe step waiting for confirmation (step mode): shown before it is
/// carried out.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct HeldStep {
    /// The state about to be carried out.
    pub state: u16,
    /// Its command, as the recipe gives it (`start transport store`).
    pub command: String,
}

/// A manual operation on a workstation (maintenance mode only). Buttons,
/// lines and recipe names travel as typed; the workstation reads them and
/// names what it cannot.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum ManualAction {
    /// Press a conveyor button (coil): a line (a letter) or a station (a
    /// number), of the station's equipment.
    Press(String),
    /// Release a conveyor button.
    Release(String),
    /// Run one conveyor line for a number of seconds (press, then release).
    RunLine {
        /// The line (a letter).
        line: String,
        /// For how long, 1–600 s.
        seconds: u32,
    },
    /// Select a robot program by number (1–999).
    SelectProgram(u16),
    /// Start the selected robot program.
    StartProgram,
    /// Stop the robot program.
    StopProgram,
    /// Confirm (reset) the robot's alarm.
    ConfirmAlarm,
    /// Run one of the station's own recipes (its `home` recipe brings it
    /// to the starting layout).
    RunRecipe(String),
    /// Bring the station's equipment to one of its named states (a
    /// conveyor's `home`), from the state its inputs show.
    Goto(String),
}

impl fmt::Display for ManualAction {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Press(b) => write!(f, "press {b}"),
            Self::Release(b) => write!(f, "release {b}"),
            Self::RunLine { line, seconds } => write!(f, "run line {line} for {seconds} s"),
            Self::SelectProgram(p) => write!(f, "select robot program {p}"),
            Self::StartProgram => f.write_str("start the robot program"),
            Self::StopProgram => f.write_str("stop the robot program"),
            Self::ConfirmAlarm => f.write_str("confirm the robot alarm"),
            Self::RunRecipe(r) => write!(f, "run recipe {r}"),
            Self::Goto(s) => write!(f, "go to state {s}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modes_read_as_typed_and_only_auto_and_step_change_while_running() {
        assert_eq!("Step".parse::<CellMode>(), Ok(CellMode::Step));
        assert!("manual".parse::<CellMode>().unwrap_err().contains("auto"));
        assert!(CellMode::Auto.may_change_running(CellMode::Step));
        assert!(CellMode::Step.may_change_running(CellMode::Auto));
        assert!(!CellMode::Auto.may_change_running(CellMode::Maintenance));
        assert!(!CellMode::Maintenance.may_change_running(CellMode::Auto));
    }

    #[test]
    fn only_the_chosen_stations_step_and_only_in_step_mode() {
        let cell = StationName::new("cell").unwrap();
        let welding = StationName::new("welding").unwrap();
        let mut m = ModeSetting {
            mode: CellMode::Step,
            stepping: vec![cell.clone()],
        };
        assert!(m.steps(&cell));
        assert!(!m.steps(&welding));
        assert_eq!(m.to_string(), "step (cell)");
        m.mode = CellMode::Auto;
        assert!(!m.steps(&cell));
        assert_eq!(m.to_string(), "auto");
    }
}
