//! The figures a plant keeps, by ISO 22400-2, as the operator answers
//! them (`falc figures`), planned against the shift calendar
//! ([`crate::calendar`]):
//! the time elements of each period, what was produced, and the KPIs
//! derived from them. Everything on the wire is a whole number
//! (milliseconds, counts); the ratios are computed from it
//! ([`Period::availability`] …), so a reader can check every one.
//! The computation is `falc_factory::figures`.

use crate::alarm::AlarmClass;
use serde::{Deserialize, Serialize};
use std::fmt;

/// What `falc figures` asks: a range, and planned run times set by hand
/// (recipe → seconds; a recipe not named has the median of its done
/// orders' run times in the range).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct FigureQuery {
    /// From (ms since the Unix epoch).
    pub since_ms: i64,
    /// Until (ms since the Unix epoch; None: now).
    pub until_ms: Option<i64>,
    /// Planned run time per recipe, in seconds.
    pub planned: Vec<(String, u32)>,
}

/// ISO 22400-2's time elements of one period, in milliseconds: a
/// partition of the planned busy time, each instant counted once, in this
/// order of precedence: maintenance mode, step mode (setup), an order
/// running (production), an alarm holding the cell (down, by class), idle.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TimeElements {
    /// PBT: planned busy time.
    pub planned_busy_ms: i64,
    /// APT: actual production time (an order runs, not in step or
    /// maintenance mode).
    pub production_ms: i64,
    /// ADOT: actual unit down time, by the strictest alarm class holding
    /// the cell at each instant (no order running).
    pub down_ms: Vec<(AlarmClass, i64)>,
    /// AUST: actual unit setup time (step mode).
    pub setup_ms: i64,
    /// Maintenance mode.
    pub maintenance_ms: i64,
    /// The rest: waiting for an order, an answer, a start.
    pub idle_ms: i64,
}

impl TimeElements {
    /// All down time.
    pub fn down_total_ms(&self) -> i64 {
        self.down_ms.iter().map(|(_, ms)| ms).sum()
    }
}

/// What one period produced.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Quantities {
    /// PQ: orders that ended with a product (done, or failed).
    pub produced: u64,
    /// GQ: orders done.
    pub good: u64,
    /// Orders failed (a bad product, an alarm): scrap or rework.
    pub failed: u64,
    /// Orders stopped by an operator or interrupted (no product).
    pub stopped: u64,
    /// Σ planned run time (PRI) of the produced orders, ms.
    pub planned_run_ms: i64,
}

/// One period's figures.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Period {
    /// What it is (`2026-11-25 early`, `2026-11-25`, `total`).
    pub label: String,
    /// From (ms since the Unix epoch).
    pub start_ms: i64,
    /// Until.
    pub end_ms: i64,
    /// Its time elements.
    pub time: TimeElements,
    /// What it produced.
    pub quantities: Quantities,
}

fn ratio(a: i64, b: i64) -> Option<f64> {
    (b > 0).then(|| a as f64 / b as f64)
}

impl Period {
    /// Availability = APT / PBT.
    pub fn availability(&self) -> Option<f64> {
        ratio(self.time.production_ms, self.time.planned_busy_ms)
    }
    /// Effectiveness = PRI × PQ / APT.
    pub fn effectiveness(&self) -> Option<f64> {
        ratio(self.quantities.planned_run_ms, self.time.production_ms)
    }
    /// Quality ratio = GQ / PQ.
    pub fn quality(&self) -> Option<f64> {
        ratio(self.quantities.good as i64, self.quantities.produced as i64)
    }
    /// OEE = availability × effectiveness × quality ratio.
    pub fn oee(&self) -> Option<f64> {
        Some(self.availability()? * self.effectiveness()? * self.quality()?)
    }
}

/// Cycle times of one recipe (or one station's job), ms.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct CycleTime {
    /// The recipe.
    pub recipe: String,
    /// How many done runs.
    pub count: u64,
    /// Median.
    pub p50_ms: i64,
    /// 95th percentile (nearest rank).
    pub p95_ms: i64,
    /// Planned run time (PRI) used for effectiveness.
    pub planned_ms: i64,
    /// Whether PRI was set (else learned: the median).
    pub planned_set: bool,
    /// Each done run's time, oldest first (for a histogram).
    pub runs_ms: Vec<i64>,
}

/// One station's failures.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Reliability {
    /// The station.
    pub station: String,
    /// Alarms it raised (not warnings).
    pub failures: u64,
    /// MTBF: production time per failure, ms (None: no failure).
    pub mtbf_ms: Option<i64>,
    /// MTTR: mean time from an alarm to its being gone (acknowledged and
    /// cleared), ms, of those that are gone.
    pub mttr_ms: Option<i64>,
}

/// One line of the alarm Pareto.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ParetoLine {
    /// The station that raised them.
    pub station: String,
    /// Their class.
    pub class: AlarmClass,
    /// How many.
    pub count: u64,
    /// How long they lasted within planned busy time, together, ms.
    pub ms: i64,
}

/// One order run, for the Gantt chart.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RunBar {
    /// The order.
    pub order: i64,
    /// Its recipe.
    pub recipe: String,
    /// From, until (ms since the Unix epoch).
    pub start_ms: i64,
    /// Until (the range's end while it runs).
    pub end_ms: i64,
    /// How it ended (`done`, `failed`, …; `running`).
    pub state: String,
}

/// How many runs of a recipe ended one way.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RunCount {
    /// The recipe (lower case).
    pub recipe: String,
    /// How they ended (`done`, `failed`, `stopped`, `interrupted`).
    pub result: String,
    /// How many ended in the range.
    pub count: u64,
}

/// The most periods (shifts, or days) one reply of figures gives per cell:
/// three shifts a day for about a year.
pub const MAX_PERIODS: usize = 1_100;

/// One cell's figures.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct CellFigures {
    /// The cell.
    pub cell: String,
    /// The runs that ended in the range, by recipe and result.
    pub ended: Vec<RunCount>,
    /// The whole range.
    pub total: Period,
    /// Each shift (each day with no shift calendar), from the cell's first
    /// record on: at most [`MAX_PERIODS`], the oldest.
    pub periods: Vec<Period>,
    /// How many periods of the range came after those (a reply stays a
    /// page: ask for a shorter range to see them).
    #[serde(default)]
    pub periods_left_out: u64,
    /// Cycle time per recipe.
    pub cycle: Vec<CycleTime>,
    /// MTBF and MTTR per station.
    pub reliability: Vec<Reliability>,
    /// Alarms per station and class, most down time first.
    pub pareto: Vec<ParetoLine>,
    /// The newest order runs (at most 50), oldest first.
    pub runs: Vec<RunBar>,
}

/// What the planned busy time was taken from.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum PlannedBy {
    /// The shift calendar's shifts.
    #[default]
    Calendar,
    /// No shift calendar: the time the cell was meant to work, its order
    /// list running (or stopped by an alarm until it was acknowledged),
    /// and every order's run.
    ListWorking,
}

impl PlannedBy {
    /// The rule in words, for the text form.
    pub fn describe(self) -> &'static str {
        match self {
            Self::Calendar => "planned busy time: the shift calendar's shifts",
            Self::ListWorking => {
                "planned busy time: while the order list ran or an alarm held it, and every \
                 order's run (no shift calendar: `[[shift]]` in the topology sets one)"
            }
        }
    }
}

/// `falc figures`: each cell's.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Figures {
    /// From (ms since the Unix epoch).
    pub since_ms: i64,
    /// Until.
    pub until_ms: i64,
    /// Each cell with records in the range.
    pub cells: Vec<CellFigures>,
    /// What the planned busy time was taken from.
    #[serde(default)]
    pub planned_by: PlannedBy,
}

/// A ratio as a percentage with one decimal, or `-` where undefined.
pub struct Percent(pub Option<f64>);

impl fmt::Display for Percent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            Some(r) => write!(f, "{:.1}%", r * 100.0),
            None => f.write_str("-"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_kpis_are_the_ratios_of_the_elements() {
        let p = Period {
            label: "total".into(),
            start_ms: 0,
            end_ms: 1000,
            time: TimeElements {
                planned_busy_ms: 1000,
                production_ms: 800,
                ..Default::default()
            },
            quantities: Quantities {
                produced: 4,
                good: 3,
                failed: 1,
                stopped: 0,
                planned_run_ms: 600,
            },
        };
        assert_eq!(p.availability(), Some(0.8));
        assert_eq!(p.effectiveness(), Some(0.75));
        assert_eq!(p.quality(), Some(0.75));
        assert!((p.oee().expect("oee") - 0.45).abs() < 1e-12);
        assert_eq!(Percent(p.oee()).to_string(), "45.0%");
        assert_eq!(Percent(None).to_string(), "-");
    }
}
