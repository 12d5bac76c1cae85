//! The figures a plant keeps, by ISO 22400-2, as the operator answers
//! them (`falc figures`): the shift calendar they are planned against,
//! the time elements of each period, what was produced, and the KPIs
//! derived from them. Everything on the wire is a whole number
//! (milliseconds, counts); the ratios are computed from it
//! ([`Period::availability`] …), so a reader can check every one.
//! The computation is `falc_factory::figures`.

use crate::alarm::AlarmClass;
use serde::{Deserialize, Serialize};
use std::fmt;

const DAY_MS: i64 = 86_400_000;
const MINUTE_MS: i64 = 60_000;

/// The days of the week, Monday first (as `days` in a `[[shift]]`).
pub const WEEKDAYS: [&str; 7] = ["mon", "tue", "wed", "thu", "fri", "sat", "sun"];

/// One shift of the calendar, as written in the topology:
///
/// ```toml
/// utc_offset = "+01:00"
/// [[shift]]
/// name = "early"
/// start = "06:00"
/// end = "14:00"
/// days = ["mon", "tue", "wed", "thu", "fri"]
/// ```
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawShift {
    /// Its name (`early`).
    pub name: String,
    /// When it begins, `HH:MM` local time.
    pub start: String,
    /// When it ends, `HH:MM` (before `start`: the next day).
    pub end: String,
    /// The days it begins on (default: every day).
    #[serde(default)]
    pub days: Vec<String>,
}

/// One validated shift.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shift {
    /// Its name.
    pub name: String,
    /// Its start, minutes after local midnight.
    pub start_min: u16,
    /// Its length in minutes (1 to 1440).
    pub length_min: u16,
    /// The weekdays it begins on, Monday = 0.
    pub days: Vec<u8>,
}

/// When the cell is planned to work (ISO 22400's planned busy time):
/// the shifts, in local time at a fixed offset from UTC; no shift means
/// always.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Calendar {
    /// Local time minus UTC, in minutes.
    pub utc_offset_min: i16,
    /// The shifts (none: planned busy all the time).
    pub shifts: Vec<Shift>,
}

fn minutes_of(text: &str, what: &str) -> Result<u16, String> {
    let bad = || format!("{what} = \"{text}\" is not a time of day HH:MM");
    let (h, m) = text.split_once(':').ok_or_else(bad)?;
    let (h, m): (u16, u16) = (h.parse().map_err(|_| bad())?, m.parse().map_err(|_| bad())?);
    if h > 24 || m > 59 || (h == 24 && m > 0) || text.len() != 5 {
        return Err(bad());
    }
    Ok(h * 60 + m)
}

/// `+01:00`, `-05:30` as minutes.
fn offset_of(text: &str) -> Result<i16, String> {
    let bad = || format!("utc_offset = \"{text}\" is not an offset like +01:00 or -05:30");
    let (sign, rest) = match text.as_bytes().first() {
        Some(b'+') => (1, &text[1..]),
        Some(b'-') => (-1, &text[1..]),
        _ => return Err(bad()),
    };
    let m = minutes_of(rest, "utc_offset").map_err(|_| bad())?;
    if m > 14 * 60 {
        return Err(bad());
    }
    Ok(sign * m as i16)
}

impl Calendar {
    /// Validates the shifts of a topology and its offset.
    pub fn new(utc_offset: Option<&str>, raw: &[RawShift]) -> Result<Self, String> {
        let utc_offset_min = utc_offset.map(offset_of).transpose()?.unwrap_or(0);
        let mut shifts = Vec::new();
        for s in raw {
            let name = s.name.trim();
            if name.is_empty()
                || name.len() > 32
                || !name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
            {
                return Err(format!(
                    "shift name \"{}\": 1 to 32 letters, digits, - or _",
                    crate::ids::excerpt(&s.name)
                ));
            }
            if shifts.iter().any(|o: &Shift| o.name == name) {
                return Err(format!("shift `{name}` is defined twice"));
            }
            let start = minutes_of(&s.start, &format!("shift `{name}` start"))?;
            let end = minutes_of(&s.end, &format!("shift `{name}` end"))?;
            let length = (i32::from(end) - i32::from(start)).rem_euclid(1440);
            let length = if length == 0 { 1440 } else { length };
            let mut days = Vec::new();
            for d in &s.days {
                let i = WEEKDAYS
                    .iter()
                    .position(|w| w.eq_ignore_ascii_case(d))
                    .ok_or_else(|| {
                        format!(
                            "shift `{name}`: day \"{}\" is none of {}",
                            crate::ids::excerpt(d),
                            WEEKDAYS.join(", ")
                        )
                    })?;
                days.push(i as u8);
            }
            if days.is_empty() {
                days = (0..7).collect();
            }
            shifts.push(Shift {
                name: name.to_string(),
                start_min: start % 1440,
                length_min: length as u16,
                days,
            });
        }
        Ok(Self {
            utc_offset_min,
            shifts,
        })
    }

    /// Whether there is no shift (planned busy always).
    pub fn always(&self) -> bool {
        self.shifts.is_empty()
    }

    /// The planned busy periods within `[since, until)` (ms since the
    /// Unix epoch), in time order, each cut to the range, with a label:
    /// each shift as it falls (`2026-11-25 early`), or, with no shift,
    /// each local day (`2026-11-25`).
    pub fn periods(&self, since: i64, until: i64) -> Vec<(i64, i64, String)> {
        let offset = i64::from(self.utc_offset_min) * MINUTE_MS;
        // Local midnights, from the day before `since` (a night shift
        // that began then) to the day of `until`.
        let first_day = (since + offset).div_euclid(DAY_MS) - 1;
        let last_day = (until + offset).div_euclid(DAY_MS);
        let mut out = Vec::new();
        for day in first_day..=last_day {
            let midnight = day * DAY_MS - offset;
            let date = date_of(day);
            if self.always() {
                push_cut(&mut out, midnight, midnight + DAY_MS, since, until, date);
                continue;
            }
            // 1970-01-01 was a Thursday (3 with Monday = 0).
            let weekday = (day + 3).rem_euclid(7) as u8;
            for s in self.shifts.iter().filter(|s| s.days.contains(&weekday)) {
                let start = midnight + i64::from(s.start_min) * MINUTE_MS;
                let end = start + i64::from(s.length_min) * MINUTE_MS;
                push_cut(
                    &mut out,
                    start,
                    end,
                    since,
                    until,
                    format!("{date} {}", s.name),
                );
            }
        }
        out.sort_by_key(|p| p.0);
        out
    }
}

fn push_cut(
    out: &mut Vec<(i64, i64, String)>,
    start: i64,
    end: i64,
    since: i64,
    until: i64,
    label: String,
) {
    let (s, e) = (start.max(since), end.min(until));
    if s < e {
        out.push((s, e, label));
    }
}

/// Days since 1970-01-01 as `YYYY-MM-DD`.
fn date_of(days: i64) -> String {
    let text = crate::console::utc_text(days * DAY_MS);
    text[..10].to_string()
}

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

    fn shift(name: &str, start: &str, end: &str, days: &[&str]) -> RawShift {
        RawShift {
            name: name.into(),
            start: start.into(),
            end: end.into(),
            days: days.iter().map(|d| d.to_string()).collect(),
        }
    }

    #[test]
    fn shifts_fall_on_their_days_in_local_time_and_a_night_shift_crosses_midnight() {
        let c = Calendar::new(
            Some("+01:00"),
            &[
                shift(
                    "early",
                    "06:00",
                    "14:00",
                    &["mon", "tue", "wed", "thu", "fri"],
                ),
                shift("night", "22:00", "06:00", &["wed"]),
            ],
        )
        .expect("valid");
        // 2026-11-25 is a Wednesday; 00:00 UTC.
        let wed = 1_795_564_800_000;
        let p = c.periods(wed, wed + DAY_MS);
        let labels: Vec<&str> = p.iter().map(|x| x.2.as_str()).collect();
        assert_eq!(labels, vec!["2026-11-25 early", "2026-11-25 night"]);
        // 06:00 local is 05:00 UTC.
        assert_eq!(p[0].0 - wed, 5 * 3_600_000);
        assert_eq!(p[0].1 - p[0].0, 8 * 3_600_000);
        // The night shift runs to 06:00 local Thursday: cut at the range.
        assert_eq!(p[1].1, wed + DAY_MS);
        let whole = c.periods(wed, wed + 2 * DAY_MS);
        assert_eq!(whole[1].1 - whole[1].0, 8 * 3_600_000);
        assert_eq!(whole.len(), 3, "{whole:?}");
    }

    #[test]
    fn no_shift_is_always_by_day_and_bad_shifts_are_refused_by_name() {
        let always = Calendar::default();
        let p = always.periods(1_000, 1_000 + DAY_MS);
        assert_eq!(p.len(), 2);
        assert_eq!(p.iter().map(|x| x.1 - x.0).sum::<i64>(), DAY_MS);
        for (offset, s, what) in [
            (None, shift("a", "25:00", "06:00", &[]), "start"),
            (None, shift("a", "06:00", "6:00", &[]), "end"),
            (None, shift("a", "06:00", "07:00", &["mo"]), "day"),
            (
                Some("1:00"),
                shift("a", "06:00", "07:00", &[]),
                "utc_offset",
            ),
            (None, shift("", "06:00", "07:00", &[]), "shift name"),
        ] {
            let e = Calendar::new(offset, &[s]).expect_err("refused");
            assert!(e.contains(what), "{e}");
        }
        let twice = [
            shift("a", "06:00", "07:00", &[]),
            shift("a", "08:00", "09:00", &[]),
        ];
        assert!(Calendar::new(None, &twice).is_err());
    }

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
